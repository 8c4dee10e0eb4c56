"""Speed against accuracy over the force model, r, s and m, per scene: the Pareto front
(``lbshape bench --sweep``).

For each scene the reduced method is run over a grid of settings —
:func:`lbshape.studies.sweep.speed_error_sweep` — and each configuration's median
per-step time is set against its trajectory error versus the ``full`` reference with
the same m (``max_t ‖u − u_full‖_M / max_t ‖u_full‖_M``, examples active in both).

The grid (:func:`sweep_scene`, at the scene's m unless said otherwise; the scene's own
r, s and m are added to the value lists, so its own setting is always in it):

* ``polynomial`` (the exact reduced StVK force over every element; StVK scenes only):
  r ∈ :data:`POLYNOMIAL_R_VALUES` at the scene's s (s only sizes the cubature trained
  beside the exact forces, so it is not swept) — 6 settings (7 with a scene r outside);
* ``cubature``: every (r, s) of :data:`R_VALUES` × :data:`S_VALUES` — 12 settings;
* m ∈ :data:`M_VALUES` at the scene's r, s and force choice — 2 more settings (not for
  a free body: each m needs two more ``full`` references, about 5 min each for the car).

A free body is judged on every part of its accuracy target: each of the whole-field
error with and without its examples, the centre-of-mass path and the body-frame
deformation (both runs) within :data:`FREE_BODY_TARGET_ERROR`; the rotation (degrees)
is reported beside them (:func:`judged_error`).

About 20 precomputes (≈ 1–3 s each) and 3 ``full`` references (one per m) per scene;
the default scenes (bar-cuboid, bar-cylinder, demo) take a few minutes in all on
2 cores with one thread.

* :func:`pareto_front` — the configurations no other one beats in both time and
  (judged) error;
* :func:`meeting` / :func:`closest_miss` — configurations within
  :data:`TARGET_ERROR` of full and under :data:`TARGET_MS` per step, or the one
  that misses by the least (largest ratio to the targets);
* :func:`write_pareto` — ``pareto.md`` (fronts, the scenes' own settings, the verdicts:
  which setting, if any, meets ≤ 2 % under 1 ms per step), ``pareto.json`` and
  ``pareto.png`` (one panel per scene: every configuration, the force models marked
  apart, the front, the scene's own setting, the target box).

Per-step times are wall clock on a shared machine; the conditions are written
next to them.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from lbshape.elastic.polynomial_forces import (
    FORCE_MODELS,
    check_force_choice,
    resolve_force_model,
)
from lbshape.errors import LbshapeError
from lbshape.io.atomic import write_json_atomic, write_text_atomic
from lbshape.io.machine import load_text, machine_description, threads_text
from lbshape.pipeline.meshes import build_mesh
from lbshape.report.plots import pyplot, save_figure
from lbshape.studies.bench import DEFAULT_OUT
from lbshape.studies.sweep import SweepPoint, speed_error_sweep

log = logging.getLogger(__name__)

#: the accuracy target: error vs full at most 2 %
TARGET_ERROR = 0.02
#: a free body's accuracy target: each judged error at most 5 %
FREE_BODY_TARGET_ERROR = 0.05
#: the speed target: at most 1 ms per reduced step
TARGET_MS = 1.0
#: scenes swept by default
DEFAULT_SCENES: tuple[str, ...] = ("bar-cuboid", "bar-cylinder", "demo")
#: default grid: the cubature's r × s
R_VALUES: tuple[int, ...] = (10, 20, 30, 40)
S_VALUES: tuple[int, ...] = (30, 60, 120)
#: the polynomial forces' r (s is not swept for them)
POLYNOMIAL_R_VALUES: tuple[int, ...] = (10, 20, 30, 40, 50, 60)
#: m at the scene's own r, s and force choice
M_VALUES: tuple[int, ...] = (6, 10, 14)
#: marker of each force model in the plot (polynomial filled, cubature open)
MARKERS = {"polynomial": "^", "cubature": "o"}


@dataclass(frozen=True)
class ParetoSweep:
    """The sweep of one scene.

    Attributes:
        scene: scene name.
        paper: the scene's own (m, r, s).
        steps: steps per run; ``dt`` the time step (s); ``repeats`` reduced runs
            per configuration (times are medians).
        points: every configuration measured.
        forces: the force model the scene's own setting resolves to ('' : any).
    """

    scene: str
    paper: tuple[int, int, int]
    steps: int
    dt: float
    repeats: int
    points: tuple[SweepPoint, ...]
    forces: str = ""

    @property
    def measured(self) -> tuple[SweepPoint, ...]:
        """The configurations with a judged error (every run finished)."""
        return tuple(p for p in self.points if judged_error(p) is not None)

    @property
    def free(self) -> bool:
        """Whether the scene is a free body (its points carry the free-body split)."""
        return any(p.free_body is not None for p in self.points)

    @property
    def target_error(self) -> float:
        """The error target its verdict uses: :data:`FREE_BODY_TARGET_ERROR` for a free
        body, else :data:`TARGET_ERROR`."""
        return FREE_BODY_TARGET_ERROR if self.free else TARGET_ERROR

    def is_paper(self, point: SweepPoint) -> bool:
        """Whether ``point`` is the scene's own setting (m, r and s asked, force model)."""
        return ((point.m, point.asked_r, point.s_max) == tuple(self.paper)
                and (not self.forces or point.forces == self.forces))

    def paper_point(self) -> SweepPoint | None:
        """The measurement of the scene's own setting (None if its run failed)."""
        return next((p for p in self.measured if self.is_paper(p)), None)


def judged_error(point: SweepPoint) -> float | None:
    """The error a point is judged by (dimensionless; None if a run it needs failed).

    A fixed object: ``error_vs_full``. A free body: the largest of the whole-field error
    with and without its examples and, for both runs, the centre-of-mass path error and
    the body-frame deformation error (a ratio that is None because the reference never
    moves or never deforms does not count); the rotation is in degrees and not judged.
    """
    if point.free_body is None:
        return point.error_vs_full
    if None in (point.error_vs_full, point.error_no_examples, point.free_body_no_examples):
        return None
    values = [point.error_vs_full, point.error_no_examples]
    for split in (point.free_body, point.free_body_no_examples):
        values += [split[key] for key in ("com_path_error", "body_deformation_error")
                   if split[key] is not None]
    return max(values)


def pareto_front(points: Sequence[SweepPoint]) -> list[SweepPoint]:
    """The non-dominated points in (``t_total_ms``, :func:`judged_error`), fastest first.

    A point is dominated when another is at least as fast and at least as accurate
    and strictly better in one of the two. Points without an error are left out.
    """
    candidates = sorted((p for p in points if judged_error(p) is not None),
                        key=lambda p: (p.t_total_ms, judged_error(p)))
    front, best = [], float("inf")
    for point in candidates:
        if judged_error(point) < best:
            front.append(point)
            best = judged_error(point)
    return front


def meeting(points: Sequence[SweepPoint], *, error: float = TARGET_ERROR,
            ms: float = TARGET_MS) -> list[SweepPoint]:
    """Points with :func:`judged_error` ``≤ error`` and ``t_total_ms ≤ ms``, fastest first."""
    return sorted((p for p in points if judged_error(p) is not None
                   and judged_error(p) <= error and p.t_total_ms <= ms),
                  key=lambda p: p.t_total_ms)


def miss_factor(point: SweepPoint, *, error: float = TARGET_ERROR, ms: float = TARGET_MS
                ) -> float:
    """``max(judged error / target, time / target)``: ≤ 1 meets both targets."""
    return max(judged_error(point) / error, point.t_total_ms / ms)


def closest_miss(points: Sequence[SweepPoint], *, error: float = TARGET_ERROR,
                 ms: float = TARGET_MS) -> SweepPoint | None:
    """The measured point with the smallest :func:`miss_factor` (None if none measured)."""
    measured = [p for p in points if judged_error(p) is not None]
    return min(measured, key=lambda p: miss_factor(p, error=error, ms=ms), default=None)


def sweep_forces(scene, forces: Sequence[str] | None = None) -> tuple[str, ...]:
    """The force models swept: ``forces`` (checked against the material), by default both
    for StVK and the cubature alone otherwise."""
    if forces is None:
        return FORCE_MODELS if scene.material.model == "stvk" else ("cubature",)
    for model in forces:
        if model not in FORCE_MODELS:
            raise LbshapeError(f"force models must be among {FORCE_MODELS}, got {model!r}")
        check_force_choice(model, scene.material.model)
    return tuple(dict.fromkeys(forces))


def sweep_scene(scene, *, r_values: Sequence[int] = R_VALUES, s_values: Sequence[int] = S_VALUES,
                m_values: Sequence[int] = M_VALUES,
                polynomial_r_values: Sequence[int] = POLYNOMIAL_R_VALUES,
                forces: Sequence[str] | None = None, steps: int | None = None,
                repeats: int = 2, progress: bool = False) -> ParetoSweep:
    """Sweep one scene over the grid of the module docstring (its own r, s and m added).

    Args:
        forces: force models swept (default: :func:`sweep_forces`).
        m_values: ignored for a free body (its m stays the scene's).
    """
    red = scene.reduced
    models = sweep_forces(scene, forces)
    r_values = tuple(sorted({*map(int, r_values), red.r}))
    polynomial_r_values = tuple(sorted({*map(int, polynomial_r_values), red.r}))
    s_values = tuple(sorted({*map(int, s_values), red.s}))
    m_values = (red.m,) if scene.is_free else tuple(sorted({*map(int, m_values), red.m}))
    steps = scene.simulation.steps if steps is None else int(steps)
    own = resolve_force_model(red.forces, scene.material.model,
                              build_mesh(scene.object).n_tets, red.r)
    points = speed_error_sweep(scene, r_values=r_values, s_values=s_values, m_values=m_values,
                               steps=steps, repeats=repeats, progress=progress,
                               forces=models, polynomial_r_values=polynomial_r_values)
    return ParetoSweep(scene.name, (red.m, red.r, red.s), steps, float(scene.simulation.dt),
                       int(repeats), points, own)


# ------------------------------------------------------------------------------ output
def _setting(point: SweepPoint) -> str:
    s = "" if point.forces == "polynomial" else f" s={point.s}"
    return f"{point.forces} m={point.m} r={point.r}{s}"


def _describe(point: SweepPoint) -> str:
    text = f"{_setting(point)}: {point.t_total_ms:.3f} ms/step, error {point.error_vs_full:.2%}"
    if point.free_body is not None:
        text += f" (worst judged {judged_error(point):.2%})"
    return text


def verdict(sweep: ParetoSweep) -> str:
    """Whether any setting meets both targets (the fastest that does, and the most
    accurate within the time target), else the closest miss and by how much."""
    target = sweep.target_error
    good = meeting(sweep.points, error=target)
    if good:
        text = f"**met** by {len(good)} setting(s); fastest {_describe(good[0])}"
        accurate = min(good, key=judged_error)
        if accurate is not good[0]:
            text += f"; most accurate {_describe(accurate)}"
        return text
    near = closest_miss(sweep.points, error=target)
    if near is None:
        return "**no configuration finished**"
    over = []
    worst = judged_error(near)
    if worst > target:
        what = "worst judged error" if sweep.free else "error"
        over.append(f"{what} {worst / target:.2f}× the {target:.0%} target")
    if near.t_total_ms > TARGET_MS:
        over.append(f"time {near.t_total_ms / TARGET_MS:.2f}× the {TARGET_MS:g} ms target")
    return f"**NOT met**; closest {_describe(near)} ({', '.join(over)})"


def _s_cell(point: SweepPoint) -> str:
    if point.forces == "polynomial":
        return f"exact ({point.s_max})"
    return f"{point.s} ({point.s_max})"


def pareto_markdown(sweeps: Sequence[ParetoSweep], machine: dict) -> str:
    """The Markdown of ``pareto.md``."""
    repeats = sorted({sweep.repeats for sweep in sweeps})
    lines = [
        "# Speed against accuracy: Pareto fronts over the force model, r, s and m",
        "",
        f"Command: `lbshape bench --sweep {' '.join(sweep.scene for sweep in sweeps)} "
        f"--repeats {'/'.join(map(str, repeats))}`.",
        "",
        "Reduced method, per-step time (median over repeats, warm-up excluded) against the "
        "trajectory error versus the full-space reference with the same m and the examples "
        "active, `max_t ‖u − u_full‖_M / max_t ‖u_full‖_M`. Grid per scene, at the scene's "
        "m: the exact polynomial StVK forces (`polynomial`, every element; StVK scenes) at "
        f"r ∈ {{{', '.join(map(str, POLYNOMIAL_R_VALUES))}}} (s not swept: it only sizes "
        "the cubature trained beside them; shown as `exact (s asked)`), the cubature at "
        f"every r ∈ {{{', '.join(map(str, R_VALUES))}}} × s ∈ "
        f"{{{', '.join(map(str, S_VALUES))}}} (s: the cubature elements selected, training "
        "may stop at its tolerance before the s asked for), and every m ∈ "
        f"{{{', '.join(map(str, M_VALUES))}}} at the scene's (r, s) and force choice; the "
        "scene's own values are added; r: the basis's columns (more than asked where the "
        "scene's static responses are appended). "
        f"Target: error ≤ {TARGET_ERROR:.0%} at ≤ {TARGET_MS:g} ms per step.",
        "",
    ]
    free = any(sweep.free for sweep in sweeps)
    if free:
        lines += [
            "A free body (no m sweep) is measured as Table 2 measures it: also without its "
            "examples (`k_ex = 0` in both methods), and split into the centre-of-mass path, "
            "the rotation (degrees) and the body-frame deformation "
            "(`lbshape.analysis.free_body`). Its target is each of the whole-field errors "
            "with and without examples, the centre path and the deformation of both runs "
            f"≤ {FREE_BODY_TARGET_ERROR:.0%} at ≤ {TARGET_MS:g} ms per step; the largest of "
            "them is its *worst judged error*, which its front, verdict and plot use (the "
            "rotation is reported, not judged).",
            "",
        ]
    target = (f"≤ {TARGET_ERROR:.0%} (free bodies: ≤ {FREE_BODY_TARGET_ERROR:.0%}, worst "
              "judged)" if free else f"≤ {TARGET_ERROR:.0%}")
    lines += [
        "The scene's own (m, r, s) is the paper's for the bar scenes; its force model is "
        "what the scene's `forces` resolves to.",
        "",
        f"| scene | scene's (m, r, s), forces | its time, error | {target} under "
        f"{TARGET_MS:g} ms? |",
        "|---|---|---|---|",
    ]
    for sweep in sweeps:
        paper = sweep.paper_point()
        measured = "—" if paper is None else (f"{paper.t_total_ms:.3f} ms, "
                                             f"{paper.error_vs_full:.2%}")
        if paper is not None and sweep.free:
            measured += f", worst judged {judged_error(paper):.2%}"
        lines.append(f"| {sweep.scene} | {sweep.paper}, {sweep.forces or '—'} | {measured} "
                     f"| {verdict(sweep)} |")
    for sweep in sweeps:
        lines += _sweep_lines(sweep)
    lines += [
        "",
        "## Conditions",
        "",
        f"- Machine: {machine['cpu']}, {machine['cores']} cores; threads: "
        f"{threads_text(machine)}; one process, wall clock.",
        f"- Load average (1, 5, 15 min) when written: {load_text(machine)} — other processes "
        "shared the cores, so times are upper bounds of an unloaded run.",
    ]
    return "\n".join(lines) + "\n"


def _sweep_lines(sweep: ParetoSweep) -> list[str]:
    """The section of ``pareto.md`` of one scene's sweep: every configuration's row."""
    lines = []
    lines += ["", f"## {sweep.scene}: {sweep.steps} steps of {sweep.dt:g} s, "
              f"{sweep.repeats} reduced runs per configuration", ""]
    free_head = free_rule = ""
    if sweep.free:
        lines.append("Centre path / rotation / deformation: the free-body split of the "
                     "run with examples, then of the run without them.")
        lines.append("")
        free_head = ("| error, no examples | centre path / rotation / deformation "
                     "| same, no examples | worst judged ")
        free_rule = "|---|---|---|---"
    lines += ["| forces | m | r (asked) | s (asked) | t_total ms [min, max] | t_interp ms "
              f"| error vs full {free_head}| Pareto | meets target | scene's |",
              f"|---|---|---|---|---|---|---{free_rule}|---|---|---|"]
    front = {id(p) for p in pareto_front(sweep.points)}
    good = {id(p) for p in meeting(sweep.points, error=sweep.target_error)}
    for p in sorted(sweep.points, key=lambda p: (p.forces, p.m, p.r, p.s_max)):
        error = "failed" if p.error_vs_full is None else f"{p.error_vs_full:.2%}"
        free = ""
        if sweep.free:
            worst = judged_error(p)
            free = (f"| {_percent(p.error_no_examples)} | {_split(p.free_body)} "
                    f"| {_split(p.free_body_no_examples)} "
                    f"| {'—' if worst is None else f'{worst:.2%}'} ")
        lines.append(
            f"| {p.forces} | {p.m} | {p.r} ({p.asked_r}) | {_s_cell(p)} | {p.t_total_ms:.3f} "
            f"[{p.t_total_min_ms:.3f}, {p.t_total_max_ms:.3f}] | {p.t_interp_ms:.3f} "
            f"| {error} {free}| {'yes' if id(p) in front else ''} "
            f"| {'yes' if id(p) in good else ''} "
            f"| {'yes' if sweep.is_paper(p) else ''} |")
    return lines


def _percent(value: float | None) -> str:
    return "—" if value is None else f"{value:.2%}"


def _split(stats: dict | None) -> str:
    """``centre path / rotation / deformation`` of a free-body split, or —."""
    if stats is None:
        return "—"
    return (f"{_percent(stats['com_path_error'])} / {stats['rotation_error_deg']:.1f}° / "
            f"{_percent(stats['body_deformation_error'])}")


def _label(point: SweepPoint) -> str:
    s = "" if point.forces == "polynomial" else f" s{point.s}"
    return f"{'poly' if point.forces == 'polynomial' else 'cub'} r{point.r}{s} m{point.m}"


def pareto_plot(sweeps: Sequence[ParetoSweep], path: str | Path) -> Path:
    """One panel per scene: every configuration (marker: force model, colour: m), its
    Pareto front, the scene's own setting and the target box (error ≤ 2 %, a free body's
    worst judged error ≤ 5 %; ≤ 1 ms)."""
    plt = pyplot()
    fig, axes = plt.subplots(1, len(sweeps), figsize=(4.6 * len(sweeps), 4.2), dpi=110,
                             squeeze=False)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, sweep in zip(axes[0], sweeps, strict=True):
        measured = sweep.measured
        if not measured:
            ax.set_title(f"{sweep.scene}: no configuration finished", fontsize=9)
            continue
        ms = sorted({p.m for p in measured})
        for forces in sorted({p.forces for p in measured}):
            for i, m in enumerate(ms):
                group = [p for p in measured if p.m == m and p.forces == forces]
                if group:  # force model: marker, filled (polynomial) or open; m: colour
                    colour = colours[i % len(colours)]
                    ax.scatter([p.t_total_ms for p in group],
                               [100 * judged_error(p) for p in group], s=22,
                               marker=MARKERS.get(forces, "s"), edgecolors=colour,
                               facecolors=colour if forces == "polynomial" else "none",
                               linewidths=1.0, label=f"{forces}, m = {m}", alpha=0.85)
        front = pareto_front(measured)
        ax.plot([p.t_total_ms for p in front], [100 * judged_error(p) for p in front], "k-",
                lw=1.0, drawstyle="steps-post", label="Pareto front")
        for p in front:
            ax.annotate(_label(p), (p.t_total_ms, 100 * judged_error(p)),
                        fontsize=6, xytext=(3, 3), textcoords="offset points")
        paper = sweep.paper_point()
        if paper is not None:
            ax.scatter([paper.t_total_ms], [100 * judged_error(paper)], marker="*", s=160,
                       facecolors="none", edgecolors="red", linewidths=1.2,
                       label=f"scene's (m, r, s) = {sweep.paper}")
        target = sweep.target_error
        ax.axhline(100 * target, color="0.5", lw=0.8, ls=":")
        ax.axvline(TARGET_MS, color="0.5", lw=0.8, ls="--")
        left = 0.5 * min(TARGET_MS, min(p.t_total_ms for p in measured))
        right = 2.0 * max(TARGET_MS, max(p.t_total_ms for p in measured))
        lowest = min(100 * judged_error(p) for p in measured)
        ax.fill_between([left, TARGET_MS], 1e-6 * lowest, 100 * target, color="green",
                        alpha=0.08, label=f"target: ≤ {target:.0%}, ≤ {TARGET_MS:g} ms")
        ax.set_xscale("log")  # the settings span two decades of per-step time
        ax.set_xlim(left, right)
        ax.set_yscale("log")
        ax.set_ylim(bottom=min(0.5 * lowest, 0.5 * 100 * target))
        ax.set_xlabel("reduced time per step (ms, median)")
        ax.set_ylabel("worst judged error vs full (%)" if sweep.free else "error vs full (%)")
        ax.set_title(f"{sweep.scene} ({sweep.steps} steps)", fontsize=10)
        ax.grid(True, alpha=0.3, which="both")
        ax.legend(fontsize=6)
    fig.tight_layout()
    return save_figure(fig, path)


def pareto_payload(sweeps: Sequence[ParetoSweep], machine: dict) -> dict:
    """The document of ``pareto.json``."""
    return {
        "target": {"error_vs_full": TARGET_ERROR, "t_total_ms": TARGET_MS},
        "scenes": [
            {"scene": s.scene, "paper": list(s.paper), "steps": s.steps, "dt": s.dt,
             "repeats": s.repeats, "points": [dataclasses.asdict(p) for p in s.points],
             "target_error": s.target_error,
             "pareto": [dataclasses.asdict(p) for p in pareto_front(s.points)],
             "meeting_target": [dataclasses.asdict(p)
                                for p in meeting(s.points, error=s.target_error)],
             "closest": (None if closest_miss(s.points, error=s.target_error) is None
                         else dataclasses.asdict(closest_miss(s.points,
                                                              error=s.target_error))),
             "paper_forces": s.forces or None}
            for s in sweeps
        ],
        "machine": machine,
    }


def write_pareto(sweeps: Sequence[ParetoSweep], out_dir: str | Path = DEFAULT_OUT
                 ) -> tuple[Path, Path, Path]:
    """Write ``pareto.md``, ``pareto.json`` and ``pareto.png`` to ``out_dir``; their paths."""
    if not sweeps:
        raise LbshapeError("no sweeps to write")
    out_dir = Path(out_dir)
    machine = machine_description()
    md = write_text_atomic(out_dir / "pareto.md", pareto_markdown(sweeps, machine))
    js = write_json_atomic(out_dir / "pareto.json", pareto_payload(sweeps, machine))
    png = pareto_plot(sweeps, out_dir / "pareto.png")
    return md, js, png
