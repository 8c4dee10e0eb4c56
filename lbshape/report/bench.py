"""Speed against accuracy: measuring the methods side by side (the paper's Table 2) and sweeps.

* :func:`trajectory_error` — ``max_t ‖u(t) − u_full(t)‖_M / max_t ‖u_full(t)‖_M``
  with M the consistent elastic mass (kg), over the same sample times;
* :func:`bench_scene` — ``full``, ``euclidean`` and ``reduced`` runs of one scene in
  one process, repeated (interleaved, so that load from other processes spreads
  evenly over the methods); per-step times are the means after the simulation's
  warm-up steps (:data:`lbshape.pipeline.simulate.WARMUP_STEPS`), summarised by the median
  and the range over repeats; the error of each method against ``full``;
* :func:`speed_error_sweep` — the reduced method's per-step time against its error
  versus ``full`` while r, s (and optionally m) vary.

Timings are wall clock. The tables are written by :mod:`lbshape.report.tables`, the
plots drawn by :mod:`lbshape.report.plots`, the machine described by
:mod:`lbshape.report.machine`.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from lbshape.elastic.element_kernels import mass_matrix
from lbshape.errors import LbshapeError
from lbshape.io.paths import RESULTS_DIR
from lbshape.pipeline.influence import has_example_force
from lbshape.pipeline.meshes import build_mesh
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import METHODS, WARMUP_STEPS, example_influence, simulate

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
        phase_ms: reduced methods: per repeat, the median time per step of each part of
            the step (ms; the one phase record,
            :func:`~lbshape.pipeline.simulate.phase_medians`: a fixed object's
            :data:`~lbshape.dynamics.reduced.PHASES`, a free body's
            :data:`~lbshape.dynamics.free_body.PHASES`).
        step_median_ms: (repeats,) per run, the median wall time of a step after the
            warm-up (ms).
    """

    method: str
    t_interp_ms: tuple[float, ...]
    t_total_ms: tuple[float, ...]
    stable: bool
    message: str = ""
    phase_ms: tuple[dict, ...] = ()
    step_median_ms: tuple[float, ...] = ()

    def phase_summary(self) -> dict | None:
        """Per part of the step, the median over the repeats (ms); None without phases."""
        if not self.phase_ms:
            return None
        return {name: float(np.median([p[name] for p in self.phase_ms]))
                for name in self.phase_ms[0]}

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
        influence: ``(method, stats)`` pairs: the example influence keys
            (:data:`lbshape.pipeline.influence.STATS_KEYS`) of the ``reduced`` and
            ``full`` runs against the same scene without examples (empty without
            examples).
        force_model: the reduced elastic force of the reduced methods (``"polynomial"``:
            s counts every element; ``"cubature"``).
    """

    scene: str
    dt: float
    steps: int
    repeats: int
    warmup: int
    rows: tuple[dict, ...]
    timings: tuple[MethodTiming, ...]
    influence: tuple[tuple[str, dict], ...] = ()
    force_model: str = "cubature"

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
    influence: bool = True,
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
        influence: with examples, also run ``reduced`` and ``full`` once without
            examples and record the example influence.

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
    outputs, timings = _run_interleaved(scene, pre, methods, steps=steps, repeats=repeats)
    mass = mass_matrix(pre.mesh, pre.material.density)
    examples = example_vertex_count(scene)
    rows = tuple(
        _row(scene.name, outputs[timing.method], timing, examples,
             error=_error_vs_full(outputs[timing.method], outputs.get("full"), mass))
        for timing in timings
    )
    effects = _influence(scene, pre, outputs, steps=steps) if influence else ()
    return SceneBenchmark(scene.name, float(scene.simulation.dt), steps, repeats, WARMUP_STEPS,
                          rows, timings, effects, force_model=pre.force_model)


def _influence(scene, pre, outputs: dict, *, steps: int) -> tuple[tuple[str, dict], ...]:
    """Example influence of the finished ``reduced`` and ``full`` runs (stable ones only)."""
    if not has_example_force(scene, pre):
        return ()
    effects = []
    for method in ("reduced", "full"):
        output = outputs.get(method)
        if output is None or not output.stats["stable"]:
            continue
        try:
            effect, _ = example_influence(scene, pre, output, method=method, steps=steps)
        except LbshapeError as exc:
            log.error("bench %s: no example influence for %s: %s", scene.name, method, exc)
            continue
        effects.append((method, effect.stats()))
    return tuple(effects)


def _run_interleaved(scene, pre, methods: tuple[str, ...], *, steps: int, repeats: int):
    """Each method ``repeats`` times, interleaved (a failed method is not run again).

    Returns:
        ``({method: its first SimulationOutput}, (MethodTiming per method, in order))``.
    """
    outputs: dict[str, object] = {}
    interp: dict[str, list[float]] = {m: [] for m in methods}
    total: dict[str, list[float]] = {m: [] for m in methods}
    phases: dict[str, list[dict]] = {m: [] for m in methods}
    medians: dict[str, list[float]] = {m: [] for m in methods}
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
            if output.phase_ms:
                phases[method].append(output.phase_ms)
            if output.step_median_ms is not None:
                medians[method].append(output.step_median_ms)
            outputs.setdefault(method, output)
            if output.message:
                log.error("bench %s: method %s stopped: %s", scene.name, method, output.message)
    timings = tuple(
        MethodTiming(m, tuple(interp[m]), tuple(total[m]), bool(outputs[m].stats["stable"]),
                     outputs[m].message, tuple(phases[m]), tuple(medians[m]))
        for m in methods
    )
    return outputs, timings


def _error_vs_full(output, full, mass) -> float | None:
    """:func:`trajectory_error` of a run against ``full`` (None if either is missing or
    stopped early)."""
    if full is None or not (full.stats["stable"] and output.stats["stable"]):
        return None
    return trajectory_error(output.displacements, full.displacements, mass,
                            times=output.times, times_full=full.times)


def _row(scene: str, output, timing: MethodTiming, examples: int, *,
         error: float | None) -> dict:
    """The contract row (keys :data:`ROW_KEYS`) of one method: sizes, median times, error."""
    stats = output.stats
    return {
        "scene": scene, "method": timing.method,
        "n_vertices": int(stats["n_vertices"]), "n_tets": int(stats["n_tets"]),
        "example_vertices": examples, "m": int(stats["m"]),
        "r": int(stats["r"]), "s": int(stats["s"]),
        "t_interp_ms": timing.summary("t_interp_ms")["median"],
        "t_total_ms": timing.summary("t_total_ms")["median"],
        "error_vs_full": error,
    }


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
        forces: the reduced elastic force the runs used (``"polynomial"``: exact, every
            element, so s only sizes the cubature trained beside it; ``"cubature"``).
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
    forces: str = "cubature"


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
        outputs, (timing,) = _run_interleaved(variant, pre, ("reduced",), steps=steps,
                                              repeats=repeats)
        error = _error_vs_full(outputs["reduced"], references[m],
                               mass_matrix(pre.mesh, pre.material.density))
        holdout = pre.cubature_errors.get("holdout")
        total = timing.summary("t_total_ms")
        points.append(SweepPoint(
            m=m, r=pre.r, s_max=s, s=int(pre.cubature_elements.size),
            t_interp_ms=timing.summary("t_interp_ms")["median"], t_total_ms=total["median"],
            t_total_min_ms=total["min"], t_total_max_ms=total["max"], error_vs_full=error,
            cubature_holdout_error=None if holdout is None else float(holdout),
            forces=pre.force_model,
        ))
        log.info("sweep %s: %s", scene.name, points[-1])
    return tuple(points)
