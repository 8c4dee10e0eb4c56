"""Speed against accuracy: the methods side by side (the paper's Table 2) and sweeps.

* :func:`trajectory_error` — ``max_t ‖u(t) − u_full(t)‖_M / max_t ‖u_full(t)‖_M``
  with M the consistent elastic mass (kg), over the same sample times;
* :func:`bench_scene` — ``full``, ``euclidean`` and ``reduced`` runs of one scene in
  one process, repeated (interleaved, so that load from other processes spreads
  evenly over the methods); per-step times are the means after the simulation's
  warm-up steps (:data:`lbshape.pipeline.simulate.WARMUP_STEPS`), summarised by the median
  and the range over repeats; the error of each method against ``full``;
* :func:`write_table2` — ``table2.md`` (the paper's Table 2 layout, plus speed-ups,
  errors and the conditions of the measurement) and ``table2.json``;
* :func:`speed_error_sweep` + :func:`write_sweep` — the reduced method's per-step
  time against its error versus ``full`` while r, s (and optionally m) vary.

Every file is written atomically. Timings are wall clock; the thread settings and
the machine are stated next to them.
"""

from __future__ import annotations

import dataclasses
import io
import logging
import os
import platform
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lbshape.elastic.element_kernels import mass_matrix
from lbshape.errors import LbshapeError
from lbshape.io.atomic import write_json_atomic, write_text_atomic
from lbshape.io.paths import RESULTS_DIR
from lbshape.pipeline.meshes import build_mesh
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import METHODS, WARMUP_STEPS, simulate

log = logging.getLogger(__name__)

#: the keys of one ``lbshape bench --json`` row, in contract order
ROW_KEYS: tuple[str, ...] = (
    "scene", "method", "n_vertices", "n_tets", "example_vertices", "m", "r", "s",
    "t_interp_ms", "t_total_ms", "error_vs_full",
)
#: scenes benchmarked by default (the paper's first two Table 2 rows)
DEFAULT_SCENES: tuple[str, ...] = ("bar-cuboid", "bar-cylinder")
#: methods benchmarked by default
DEFAULT_METHODS: tuple[str, ...] = ("full", "euclidean", "reduced")
#: repository-relative default output folder
DEFAULT_OUT = RESULTS_DIR
#: the targets Table 2 reports against (never asserted)
TARGET_T_TOTAL_MS = 1.0
TARGET_INTERP_SPEEDUP = 20.0
TARGET_ERROR = 0.10
#: environment variables that set the BLAS / OpenMP thread counts
THREAD_VARIABLES: tuple[str, ...] = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


# ----------------------------------------------------------------------------- error
def m_norms(u: np.ndarray, mass) -> np.ndarray:
    """(k,) mass norms ``sqrt(u(t)ᵀ M u(t))`` of a trajectory.

    Args:
        u: (k, n, 3) or (k, 3n) displacements in m (node-major).
        mass: (3n, 3n) symmetric positive definite mass in kg (sparse or dense).

    Returns:
        (k,) norms in m·kg^½.
    """
    u = np.asarray(u, dtype=float)
    flat = u.reshape(u.shape[0], -1)
    if flat.shape[1] != mass.shape[0]:
        raise LbshapeError(
            f"displacements have {flat.shape[1]} components per sample, the mass matrix "
            f"has {mass.shape[0]} rows"
        )
    squares = np.einsum("ti,ti->t", flat, np.asarray((mass @ flat.T).T))
    return np.sqrt(np.maximum(squares, 0.0))


def trajectory_error(
    u: np.ndarray,
    u_full: np.ndarray,
    mass,
    *,
    times: np.ndarray | None = None,
    times_full: np.ndarray | None = None,
) -> float:
    """Relative trajectory error ``max_t ‖u(t) − u_full(t)‖_M / max_t ‖u_full(t)‖_M``.

    Args:
        u: (k, n, 3) or (k, 3n) displacements in m.
        u_full: the reference, same shape and same sample times.
        mass: (3n, 3n) consistent elastic mass in kg.
        times: (k,) sample times of ``u`` in s (checked against ``times_full``).
        times_full: (k,) sample times of ``u_full`` in s.

    Returns:
        The dimensionless error (0 for identical trajectories).

    Raises:
        LbshapeError: different shapes or sample times, or a reference that never
            moves (the relative error is undefined).
    """
    u, u_full = np.asarray(u, dtype=float), np.asarray(u_full, dtype=float)
    if u.shape != u_full.shape or u.ndim not in (2, 3) or u.shape[0] == 0:
        raise LbshapeError(
            f"trajectories must have the same non-empty (k, n, 3) or (k, 3n) shape, "
            f"got {u.shape} and {u_full.shape}"
        )
    if (times is None) != (times_full is None):
        raise LbshapeError("give the sample times of both trajectories or of neither")
    if times is not None:
        times, times_full = np.asarray(times, dtype=float), np.asarray(times_full, dtype=float)
        if times.shape != (u.shape[0],) or times_full.shape != (u.shape[0],):
            raise LbshapeError(
                f"sample times must have shape ({u.shape[0]},), got {times.shape} and "
                f"{times_full.shape}"
            )
        scale = max(float(np.max(np.abs(times_full))), 1.0)
        worst = float(np.max(np.abs(times - times_full)))
        if worst > 1e-9 * scale:
            raise LbshapeError(
                f"trajectories are sampled at different times (largest difference {worst:.3g} s)"
            )
    reference = float(m_norms(u_full, mass).max())
    if not reference > 0.0:
        raise LbshapeError("the reference trajectory never moves: relative error undefined")
    return float(m_norms(u - u_full, mass).max()) / reference


# ------------------------------------------------------------------------ benchmark
@dataclass(frozen=True)
class MethodTiming:
    """Per-step times of one method over the repeats.

    Attributes:
        method: ``full``, ``euclidean`` or ``reduced``.
        t_interp_ms: (repeats,) per-step mean interpolation time of each run (ms).
        t_total_ms: (repeats,) per-step mean total time of each run (ms).
        stable: False if a run stopped on a solver failure.
        message: the failure message ('' if stable).
    """

    method: str
    t_interp_ms: tuple[float, ...]
    t_total_ms: tuple[float, ...]
    stable: bool
    message: str = ""

    def summary(self, which: str) -> dict:
        """``{"median", "min", "max"}`` of ``t_interp_ms`` or ``t_total_ms`` (ms)."""
        values = np.asarray(getattr(self, which), dtype=float)
        return {"median": float(np.median(values)), "min": float(values.min()),
                "max": float(values.max())}


@dataclass(frozen=True)
class SceneBenchmark:
    """The benchmark of one scene.

    Attributes:
        scene: scene name.
        dt: time step (s).
        steps: steps per run.
        repeats: runs per method.
        warmup: steps per run left out of the timings.
        rows: one dict per method with exactly the keys :data:`ROW_KEYS`
            (times: medians over repeats; ``error_vs_full`` None when undefined).
        timings: the spread of the times, one per method (same order as ``rows``).
    """

    scene: str
    dt: float
    steps: int
    repeats: int
    warmup: int
    rows: tuple[dict, ...]
    timings: tuple[MethodTiming, ...]

    def row(self, method: str) -> dict | None:
        """The row of ``method`` (None if it was not run)."""
        return next((row for row in self.rows if row["method"] == method), None)


def example_vertex_count(scene) -> int:
    """Vertex count of the scene's last example mesh (0 without examples)."""
    if scene.examples is None or not scene.examples.poses:
        return 0
    return int(build_mesh(scene.examples.poses[-1].source).n_vertices)


def _check_methods(methods: Sequence[str]) -> tuple[str, ...]:
    methods = tuple(methods)
    if not methods:
        raise LbshapeError("give at least one method")
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise LbshapeError(f"unknown method(s) {unknown}; methods are {METHODS}")
    if len(set(methods)) != len(methods):
        raise LbshapeError(f"methods must be unique, got {list(methods)}")
    return methods


def _check_steps_repeats(steps: int, repeats: int) -> None:
    if isinstance(steps, bool) or int(steps) != steps or steps <= WARMUP_STEPS:
        raise LbshapeError(
            f"steps must be an integer > {WARMUP_STEPS} (the warm-up steps left out of the "
            f"timings), got {steps}"
        )
    if isinstance(repeats, bool) or int(repeats) != repeats or repeats < 1:
        raise LbshapeError(f"repeats must be an integer >= 1, got {repeats}")


def bench_scene(
    scene,
    *,
    steps: int | None = None,
    methods: Sequence[str] = DEFAULT_METHODS,
    repeats: int = 3,
    pre=None,
    progress: bool = False,
) -> SceneBenchmark:
    """Run the methods side by side on one scene (see the module docstring).

    Args:
        scene: the :class:`~lbshape.scene.schema.Scene`.
        steps: steps per run (default: the scene's), > the warm-up steps.
        methods: which of ``full``, ``euclidean``, ``reduced`` to run.
        repeats: runs per method (interleaved); times are medians over them.
        pre: the scene's :class:`~lbshape.pipeline.precompute.Precomputed` (default: built or
            loaded from the cache).
        progress: show the precompute's progress bars on stderr.

    Returns:
        The :class:`SceneBenchmark`. A run that stops on a solver failure is kept
        (``stable`` False in its timing, ``error_vs_full`` None) and logged.
    """
    methods = _check_methods(methods)
    steps = scene.simulation.steps if steps is None else steps
    _check_steps_repeats(steps, repeats)
    steps, repeats = int(steps), int(repeats)
    if pre is None:
        pre = precompute(scene, progress=progress)
    examples = example_vertex_count(scene)

    outputs: dict[str, object] = {}
    interp: dict[str, list[float]] = {m: [] for m in methods}
    total: dict[str, list[float]] = {m: [] for m in methods}
    for repeat in range(repeats):
        for method in methods:
            first = outputs.get(method)
            if first is not None and not first.stats["stable"]:
                continue  # deterministic: a failed run fails again
            output = simulate(scene, pre, method=method, steps=steps)
            log.info("bench %s %s repeat %d: t_interp %.3f ms, t_total %.3f ms", scene.name,
                     method, repeat + 1, output.stats["t_interp_ms"], output.stats["t_total_ms"])
            interp[method].append(float(output.stats["t_interp_ms"]))
            total[method].append(float(output.stats["t_total_ms"]))
            if first is None:
                outputs[method] = output
            if output.message:
                log.error("bench %s: method %s stopped: %s", scene.name, method, output.message)

    mass = mass_matrix(pre.mesh, pre.material.density)
    full = outputs.get("full")
    rows, timings = [], []
    for method in methods:
        output = outputs[method]
        stats = output.stats
        error = None
        if full is not None and full.stats["stable"] and stats["stable"]:
            error = trajectory_error(output.displacements, full.displacements, mass,
                                     times=output.times, times_full=full.times)
        timing = MethodTiming(method, tuple(interp[method]), tuple(total[method]),
                              bool(stats["stable"]), output.message)
        rows.append({
            "scene": scene.name, "method": method,
            "n_vertices": int(stats["n_vertices"]), "n_tets": int(stats["n_tets"]),
            "example_vertices": examples, "m": int(stats["m"]),
            "r": int(stats["r"]), "s": int(stats["s"]),
            "t_interp_ms": timing.summary("t_interp_ms")["median"],
            "t_total_ms": timing.summary("t_total_ms")["median"],
            "error_vs_full": error,
        })
        timings.append(timing)
    return SceneBenchmark(scene.name, float(scene.simulation.dt), steps, repeats, WARMUP_STEPS,
                          tuple(rows), tuple(timings))


# ---------------------------------------------------------------------- conditions
def machine_description() -> dict:
    """Machine, thread settings and load: the conditions of a timing."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        load = [round(value, 2) for value in os.getloadavg()]
    except OSError:
        load = None
    return {
        "cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(),
        "numpy": np.__version__,
        "threads": {name: os.environ.get(name, "unset") for name in THREAD_VARIABLES},
        "load_average": load,
    }


# -------------------------------------------------------------------------- Table 2
def _fmt(value: float | None, spec: str = ".3f") -> str:
    return "—" if value is None else format(value, spec)


def _ratio(numerator: float | None, denominator: float | None) -> float | None:
    if numerator is None or not denominator:
        return None
    return numerator / denominator


def table2_markdown(results: Sequence[SceneBenchmark], machine: dict) -> str:
    """The Markdown of ``table2.md`` (see :func:`write_table2`)."""
    lines = [
        "# Table 2: per-step cost and accuracy",
        "",
        "Columns as in the paper's Table 2: DOFs (3 × vertices) and tetrahedra of the "
        "object, vertices of the last example, m LB eigenfunctions, r reduced "
        "coordinates, s cubature elements; per-step times in ms for the Euclidean "
        "baseline (Zhu et al. 2015: target found in LB space with the energy over all "
        "elements, reduced dynamics) and the reduced method (the paper's); speed-ups "
        "euclidean / reduced; the full-space reference's per-step time; and the error "
        "of each method against it, `max_t ‖u(t) − u_full(t)‖_M / max_t ‖u_full(t)‖_M` "
        "(M the consistent elastic mass).",
        "",
        "| model | DOFs | tets | ex. | m | r | s | euclidean t_interp | euclidean t_total "
        "| reduced t_interp | reduced t_total | speed-up interp | speed-up total "
        "| full t_total | error reduced | error euclidean |",
        "|---|" + "---|" * 15,
    ]
    for result in results:
        any_row = result.rows[0]
        euclid, reduced, full = (result.row(m) or {} for m in ("euclidean", "reduced", "full"))
        r = reduced.get("r", euclid.get("r"))
        s = reduced.get("s", euclid.get("s"))
        lines.append(
            f"| {result.scene} | {3 * any_row['n_vertices']} | {any_row['n_tets']} "
            f"| {any_row['example_vertices']} | {any_row['m']} | {_fmt(r, 'd')} | {_fmt(s, 'd')} "
            f"| {_fmt(euclid.get('t_interp_ms'))} | {_fmt(euclid.get('t_total_ms'))} "
            f"| {_fmt(reduced.get('t_interp_ms'))} | {_fmt(reduced.get('t_total_ms'))} "
            f"| {_fmt(_ratio(euclid.get('t_interp_ms'), reduced.get('t_interp_ms')), '.1f')}× "
            f"| {_fmt(_ratio(euclid.get('t_total_ms'), reduced.get('t_total_ms')), '.1f')}× "
            f"| {_fmt(full.get('t_total_ms'), '.2f')} "
            f"| {_fmt(reduced.get('error_vs_full'), '.2%')} "
            f"| {_fmt(euclid.get('error_vs_full'), '.2%')} |"
        )
    lines += [
        "",
        "## Spread of the per-step times (ms): median [min, max] over repeats",
        "",
        "| model | method | repeats | t_interp | t_total | stable |",
        "|---|---|---|---|---|---|",
    ]
    for result in results:
        for timing in result.timings:
            ti, tt = timing.summary("t_interp_ms"), timing.summary("t_total_ms")
            status = "yes" if timing.stable else f"no: {timing.message}"
            lines.append(
                f"| {result.scene} | {timing.method} | {len(timing.t_total_ms)} "
                f"| {ti['median']:.3f} [{ti['min']:.3f}, {ti['max']:.3f}] "
                f"| {tt['median']:.3f} [{tt['min']:.3f}, {tt['max']:.3f}] | {status} |"
            )
    threads = ", ".join(f"{k}={v}" for k, v in machine["threads"].items())
    load = machine.get("load_average")
    lines += [
        "",
        "## Conditions",
        "",
    ]
    for result in results:
        lines.append(
            f"- {result.scene}: dt = {result.dt:g} s, {result.steps} steps per run, "
            f"{result.repeats} repeats per method (methods interleaved), the first "
            f"{result.warmup} steps of each run left out of the per-step means."
        )
    lines += [
        f"- Machine: {machine['cpu']}, {machine['cores']} cores, Python {machine['python']}, "
        f"numpy {machine['numpy']}; threads: {threads}; one process, wall clock.",
        f"- Load average (1, 5, 15 min) when written: "
        f"{', '.join(str(v) for v in load) if load else 'unknown'} — other processes may "
        "have shared the cores; the min is the closest to an unloaded machine.",
        "",
        "## Targets (reported, not enforced)",
        "",
    ]
    for result in results:
        reduced, euclid = result.row("reduced"), result.row("euclidean")
        if reduced is None:
            continue
        checks = [_verdict(f"reduced t_total ≤ {TARGET_T_TOTAL_MS:g} ms per step",
                           reduced["t_total_ms"], reduced["t_total_ms"] <= TARGET_T_TOTAL_MS,
                           ".3f", " ms")]
        if euclid is not None:
            speedup = _ratio(euclid["t_interp_ms"], reduced["t_interp_ms"])
            checks.append(_verdict(
                f"interpolation speed-up ≥ {TARGET_INTERP_SPEEDUP:g}×", speedup,
                speedup is not None and speedup >= TARGET_INTERP_SPEEDUP, ".1f", "×"))
        error = reduced["error_vs_full"]
        checks.append(_verdict(f"reduced error vs full ≤ {TARGET_ERROR:.0%}", error,
                               error is not None and error <= TARGET_ERROR, ".2%", ""))
        lines.append(f"- {result.scene}: " + "; ".join(checks) + ".")
    return "\n".join(lines) + "\n"


def _verdict(label: str, value: float | None, met: bool, spec: str, unit: str) -> str:
    return f"{label}: {_fmt(value, spec)}{unit if value is not None else ''} " \
           f"**{'met' if met else 'NOT met'}**"


def table2_payload(results: Sequence[SceneBenchmark], machine: dict) -> dict:
    """The document of ``table2.json``: the contract rows plus spreads and conditions."""
    return {
        "rows": [row for result in results for row in result.rows],
        "timings": [
            {"scene": result.scene, "method": t.method, "repeats": len(t.t_total_ms),
             "t_interp_ms": t.summary("t_interp_ms"), "t_total_ms": t.summary("t_total_ms"),
             "stable": t.stable, "message": t.message}
            for result in results for t in result.timings
        ],
        "settings": [
            {"scene": result.scene, "dt": result.dt, "steps": result.steps,
             "repeats": result.repeats, "warmup_steps": result.warmup}
            for result in results
        ],
        "machine": machine,
    }


def write_table2(results: Sequence[SceneBenchmark], out_dir: str | Path = DEFAULT_OUT
                 ) -> tuple[Path, Path]:
    """Write ``table2.md`` and ``table2.json`` to ``out_dir`` atomically; their paths."""
    if not results:
        raise LbshapeError("no benchmark results to write")
    out_dir = Path(out_dir)
    machine = machine_description()
    md = write_text_atomic(out_dir / "table2.md", table2_markdown(results, machine))
    js = write_json_atomic(out_dir / "table2.json", table2_payload(results, machine))
    return md, js


# ---------------------------------------------------------------------------- sweep
@dataclass(frozen=True)
class SweepPoint:
    """One configuration of the speed-versus-error sweep (reduced method).

    Attributes:
        m, r: LB eigenfunctions and reduced coordinates.
        s_max: cubature elements asked for; ``s``: selected (training may stop at
            its tolerance first).
        t_interp_ms, t_total_ms: per-step medians over repeats (ms).
        t_total_min_ms, t_total_max_ms: range of the per-step total over repeats (ms).
        error_vs_full: trajectory error against ``full`` with the same m (None if a
            run failed).
        cubature_holdout_error: relative reduced-force error on held-out poses.
    """

    m: int
    r: int
    s_max: int
    s: int
    t_interp_ms: float
    t_total_ms: float
    t_total_min_ms: float
    t_total_max_ms: float
    error_vs_full: float | None
    cubature_holdout_error: float | None


def _variant(scene, *, m: int, r: int, s: int):
    red = scene.reduced
    linear = red.linear_modes if red.linear_modes <= r else 0
    return dataclasses.replace(
        scene, reduced=dataclasses.replace(red, m=int(m), r=int(r), s=int(s),
                                           linear_modes=linear))


def speed_error_sweep(
    scene,
    *,
    r_values: Sequence[int] = (10, 20, 30),
    s_values: Sequence[int] = (20, 60, 120),
    m_values: Sequence[int] = (),
    steps: int | None = None,
    repeats: int = 3,
    progress: bool = False,
) -> tuple[SweepPoint, ...]:
    """Per-step time and error of the reduced method while r, s (and m) vary.

    The grid is every (r, s) of ``r_values × s_values`` at the scene's m, plus
    (m, scene r, scene s) for each m of ``m_values``. Each configuration is its own
    precompute (cached); the ``full`` reference is run once per m.

    Args:
        scene: the base scene.
        r_values, s_values, m_values: the values swept.
        steps: steps per run (default: the scene's), > the warm-up steps.
        repeats: reduced runs per configuration.
        progress: precompute progress bars on stderr.
    """
    steps = scene.simulation.steps if steps is None else steps
    _check_steps_repeats(steps, repeats)
    steps, repeats = int(steps), int(repeats)
    base = scene.reduced
    grid = [(base.m, int(r), int(s)) for r in r_values for s in s_values]
    grid += [(int(m), base.r, base.s) for m in m_values if int(m) != base.m]
    if not grid:
        raise LbshapeError("the sweep is empty: give r and s values (or m values)")
    for value in {v for point in grid for v in point}:
        if value < 1:
            raise LbshapeError(f"m, r and s must be >= 1, got {value}")
    references: dict[int, object] = {}
    points = []
    for m, r, s in grid:
        variant = _variant(scene, m=m, r=r, s=s)
        pre = precompute(variant, progress=progress)
        if m not in references:
            references[m] = simulate(variant, pre, method="full", steps=steps)
            if references[m].message:
                log.error("sweep: full reference (m=%d) stopped: %s", m, references[m].message)
        full = references[m]
        interp, total, output = [], [], None
        for _ in range(repeats):
            output = simulate(variant, pre, method="reduced", steps=steps)
            interp.append(output.stats["t_interp_ms"])
            total.append(output.stats["t_total_ms"])
            if output.message:
                log.error("sweep: m=%d r=%d s=%d stopped: %s", m, r, s, output.message)
                break
        error = None
        if output.stats["stable"] and full.stats["stable"]:
            mass = mass_matrix(pre.mesh, pre.material.density)
            error = trajectory_error(output.displacements, full.displacements, mass,
                                     times=output.times, times_full=full.times)
        holdout = pre.cubature_errors.get("holdout")
        points.append(SweepPoint(
            m=m, r=pre.r, s_max=s, s=int(pre.cubature_elements.size),
            t_interp_ms=float(np.median(interp)), t_total_ms=float(np.median(total)),
            t_total_min_ms=float(np.min(total)), t_total_max_ms=float(np.max(total)),
            error_vs_full=error,
            cubature_holdout_error=None if holdout is None else float(holdout),
        ))
        log.info("sweep %s: %s", scene.name, points[-1])
    return tuple(points)


def sweep_csv(points: Sequence[SweepPoint], *, scene: str, steps: int, repeats: int,
              dt: float) -> str:
    """The text of ``speed_vs_error.csv`` (one comment line, a header, one row per point)."""
    import csv

    machine = machine_description()
    threads = ", ".join(f"{k}={v}" for k, v in machine["threads"].items())
    text = io.StringIO()
    text.write(f"# scene {scene}, reduced method, dt = {dt:g} s, {steps} steps, median of "
               f"{repeats} runs; error vs full with the same m; {machine['cpu']}, {threads}\n")
    fields = [f.name for f in dataclasses.fields(SweepPoint)]
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(fields)
    for point in points:
        writer.writerow(["" if v is None else (f"{v:.6g}" if isinstance(v, float) else v)
                         for v in dataclasses.astuple(point)])
    return text.getvalue()


def write_sweep(points: Sequence[SweepPoint], out_dir: str | Path = DEFAULT_OUT, *,
                scene: str, steps: int, repeats: int, dt: float) -> tuple[Path, Path]:
    """Write ``speed_vs_error.csv`` and ``.png`` (matplotlib, Agg) atomically; their paths."""
    import tempfile

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not points:
        raise LbshapeError("no sweep points to write")
    out_dir = Path(out_dir)
    csv_path = write_text_atomic(out_dir / "speed_vs_error.csv",
                                 sweep_csv(points, scene=scene, steps=steps, repeats=repeats,
                                           dt=dt))
    base_m = points[0].m  # the grid lists the scene's m first
    fig, ax = plt.subplots(figsize=(6.0, 4.2), dpi=120)
    markers = "osD^v<>ph*"
    for index, r in enumerate(sorted({p.r for p in points if p.m == base_m})):
        unique = {p.s: p for p in points if p.m == base_m and p.r == r
                  and p.error_vs_full is not None}  # s_max past the tolerance: same s
        group = [unique[s] for s in sorted(unique)]
        if not group:
            continue
        x = [p.t_total_ms for p in group]
        ax.plot(x, [100 * p.error_vs_full for p in group], marker=markers[index % len(markers)],
                label=f"r = {r} (m = {base_m})")
        for p in group:
            ax.annotate(f"s={p.s}", (p.t_total_ms, 100 * p.error_vs_full), fontsize=7,
                        xytext=(3, 3), textcoords="offset points")
    m_points = [p for p in points if p.m != base_m and p.error_vs_full is not None]
    if m_points:
        ax.plot([p.t_total_ms for p in m_points], [100 * p.error_vs_full for p in m_points],
                "k^", label="other m")
        for p in m_points:
            ax.annotate(f"m={p.m}", (p.t_total_ms, 100 * p.error_vs_full), fontsize=7,
                        xytext=(3, -9), textcoords="offset points")
    ax.axhline(100 * TARGET_ERROR, color="0.6", lw=0.8, ls=":", label="10% error")
    ax.axvline(TARGET_T_TOTAL_MS, color="0.6", lw=0.8, ls="--", label="1 ms per step")
    ax.set_xlabel("reduced method: time per step (ms, median)")
    ax.set_yscale("log")
    ax.set_ylabel("trajectory error vs full (%)")
    ax.set_title(f"{scene}: speed against error ({steps} steps of {dt:g} s)", fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    png_path = out_dir / "speed_vs_error.png"
    png_path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".speed_vs_error.", suffix=".png", dir=png_path.parent)
    os.close(fd)
    try:
        fig.savefig(tmp, format="png")
        os.replace(tmp, png_path)
    finally:
        plt.close(fig)
        if os.path.exists(tmp):
            os.unlink(tmp)
    return csv_path, png_path
