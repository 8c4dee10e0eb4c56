"""Speed against accuracy over r, s and m, per scene: the Pareto front (``lbshape bench --sweep``).

For each scene the reduced method is run over a grid of (m, r, s) —
:func:`lbshape.report.bench.speed_error_sweep`: every (r, s) at the scene's m plus
each m at the scene's (r, s); the scene's own (paper) setting is always in the
grid — and each configuration's median per-step time is set against its
trajectory error versus the ``full`` reference with the same m
(``max_t ‖u − u_full‖_M / max_t ‖u_full‖_M``, examples active in both).

* :func:`pareto_front` — the configurations no other one beats in both time and
  error;
* :func:`meeting` / :func:`closest_miss` — configurations within
  :data:`TARGET_ERROR` of full and under :data:`TARGET_MS` per step, or the one
  that misses by the least (largest ratio to the targets);
* :func:`write_pareto` — ``pareto.md`` (fronts, the paper's settings, the verdicts),
  ``pareto.json`` and ``pareto.png`` (one panel per scene: every configuration, the
  front, the paper's setting, the target box).

Per-step times are wall clock on a shared machine; the conditions are written
next to them.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from lbshape.errors import LbshapeError
from lbshape.io.atomic import write_json_atomic, write_text_atomic
from lbshape.report.bench import DEFAULT_OUT, SweepPoint, speed_error_sweep
from lbshape.report.machine import load_text, machine_description, threads_text
from lbshape.report.plots import pyplot, save_figure

log = logging.getLogger(__name__)

#: the accuracy target: error vs full at most 2 %
TARGET_ERROR = 0.02
#: the speed target: at most 5 ms per reduced step
TARGET_MS = 5.0
#: scenes swept by default
DEFAULT_SCENES: tuple[str, ...] = ("bar-cuboid", "bar-cylinder", "demo")
#: default grid
R_VALUES: tuple[int, ...] = (10, 20, 30, 40)
S_VALUES: tuple[int, ...] = (30, 60, 120)
M_VALUES: tuple[int, ...] = (6, 10, 14)


@dataclass(frozen=True)
class ParetoSweep:
    """The sweep of one scene.

    Attributes:
        scene: scene name.
        paper: the scene's own (m, r, s).
        steps: steps per run; ``dt`` the time step (s); ``repeats`` reduced runs
            per configuration (times are medians).
        points: every configuration measured.
    """

    scene: str
    paper: tuple[int, int, int]
    steps: int
    dt: float
    repeats: int
    points: tuple[SweepPoint, ...]

    @property
    def measured(self) -> tuple[SweepPoint, ...]:
        """The configurations with an error (both runs finished)."""
        return tuple(p for p in self.points if p.error_vs_full is not None)

    def paper_point(self) -> SweepPoint | None:
        """The measurement of the scene's own setting (None if its run failed)."""
        m, r, s = self.paper
        return next((p for p in self.measured if (p.m, p.r, p.s_max) == (m, r, s)), None)


def pareto_front(points: Sequence[SweepPoint]) -> list[SweepPoint]:
    """The non-dominated points in (``t_total_ms``, ``error_vs_full``), fastest first.

    A point is dominated when another is at least as fast and at least as accurate
    and strictly better in one of the two. Points without an error are left out.
    """
    candidates = sorted((p for p in points if p.error_vs_full is not None),
                        key=lambda p: (p.t_total_ms, p.error_vs_full))
    front, best = [], float("inf")
    for point in candidates:
        if point.error_vs_full < best:
            front.append(point)
            best = point.error_vs_full
    return front


def meeting(points: Sequence[SweepPoint], *, error: float = TARGET_ERROR,
            ms: float = TARGET_MS) -> list[SweepPoint]:
    """Points with ``error_vs_full ≤ error`` and ``t_total_ms ≤ ms``, fastest first."""
    return sorted((p for p in points if p.error_vs_full is not None
                   and p.error_vs_full <= error and p.t_total_ms <= ms),
                  key=lambda p: p.t_total_ms)


def miss_factor(point: SweepPoint, *, error: float = TARGET_ERROR, ms: float = TARGET_MS
                ) -> float:
    """``max(error / target, time / target)``: ≤ 1 meets both targets."""
    return max(point.error_vs_full / error, point.t_total_ms / ms)


def closest_miss(points: Sequence[SweepPoint], *, error: float = TARGET_ERROR,
                 ms: float = TARGET_MS) -> SweepPoint | None:
    """The measured point with the smallest :func:`miss_factor` (None if none measured)."""
    measured = [p for p in points if p.error_vs_full is not None]
    return min(measured, key=lambda p: miss_factor(p, error=error, ms=ms), default=None)


def sweep_scene(scene, *, r_values: Sequence[int] = R_VALUES, s_values: Sequence[int] = S_VALUES,
                m_values: Sequence[int] = M_VALUES, steps: int | None = None, repeats: int = 2,
                progress: bool = False) -> ParetoSweep:
    """Sweep one scene (its own r, s and m are added to the grid)."""
    red = scene.reduced
    r_values = tuple(sorted({*map(int, r_values), red.r}))
    s_values = tuple(sorted({*map(int, s_values), red.s}))
    m_values = tuple(sorted({*map(int, m_values), red.m}))
    steps = scene.simulation.steps if steps is None else int(steps)
    points = speed_error_sweep(scene, r_values=r_values, s_values=s_values, m_values=m_values,
                               steps=steps, repeats=repeats, progress=progress)
    return ParetoSweep(scene.name, (red.m, red.r, red.s), steps, float(scene.simulation.dt),
                       int(repeats), points)


# ------------------------------------------------------------------------------ output
def _describe(point: SweepPoint) -> str:
    return (f"m={point.m} r={point.r} s={point.s}: {point.t_total_ms:.2f} ms/step, "
            f"error {point.error_vs_full:.2%}")


def verdict(sweep: ParetoSweep) -> str:
    """Whether any setting meets both targets, else the closest miss and by how much."""
    good = meeting(sweep.points)
    if good:
        return (f"**met** by {len(good)} setting(s); fastest {_describe(good[0])}")
    near = closest_miss(sweep.points)
    if near is None:
        return "**no configuration finished**"
    over = []
    if near.error_vs_full > TARGET_ERROR:
        over.append(f"error {near.error_vs_full / TARGET_ERROR:.2f}× the {TARGET_ERROR:.0%} "
                    "target")
    if near.t_total_ms > TARGET_MS:
        over.append(f"time {near.t_total_ms / TARGET_MS:.2f}× the {TARGET_MS:g} ms target")
    return f"**NOT met**; closest {_describe(near)} ({', '.join(over)})"


def pareto_markdown(sweeps: Sequence[ParetoSweep], machine: dict) -> str:
    """The Markdown of ``pareto.md``."""
    lines = [
        "# Speed against accuracy: Pareto fronts over r, s and m",
        "",
        "Reduced method, per-step time (median over repeats, warm-up excluded) against the "
        "trajectory error versus the full-space reference with the same m and the examples "
        "active, `max_t ‖u − u_full‖_M / max_t ‖u_full‖_M`. Grid per scene: every (r, s) at "
        "the scene's m, and every m at the scene's (r, s); s is the number of cubature "
        "elements selected (training may stop at its tolerance before the s asked for). "
        f"Target: error ≤ {TARGET_ERROR:.0%} and ≤ {TARGET_MS:g} ms per step.",
        "",
        "The scene's own (m, r, s) is the paper's for the bar scenes.",
        "",
        "| scene | scene's (m, r, s) | its time, error | target met? |",
        "|---|---|---|---|",
    ]
    for sweep in sweeps:
        paper = sweep.paper_point()
        measured = "—" if paper is None else (f"{paper.t_total_ms:.2f} ms, "
                                             f"{paper.error_vs_full:.2%}")
        lines.append(f"| {sweep.scene} | {sweep.paper} | {measured} | {verdict(sweep)} |")
    for sweep in sweeps:
        lines += ["", f"## {sweep.scene}: {sweep.steps} steps of {sweep.dt:g} s, "
                  f"{sweep.repeats} reduced runs per configuration", "",
                  "| m | r | s (asked) | t_total ms [min, max] | t_interp ms | error vs full "
                  "| Pareto | scene's |",
                  "|---|---|---|---|---|---|---|---|"]
        front = {id(p) for p in pareto_front(sweep.points)}
        for p in sorted(sweep.points, key=lambda p: (p.m, p.r, p.s_max)):
            error = "failed" if p.error_vs_full is None else f"{p.error_vs_full:.2%}"
            lines.append(
                f"| {p.m} | {p.r} | {p.s} ({p.s_max}) | {p.t_total_ms:.2f} "
                f"[{p.t_total_min_ms:.2f}, {p.t_total_max_ms:.2f}] | {p.t_interp_ms:.2f} "
                f"| {error} | {'yes' if id(p) in front else ''} "
                f"| {'yes' if (p.m, p.r, p.s_max) == sweep.paper else ''} |")
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


def pareto_plot(sweeps: Sequence[ParetoSweep], path: str | Path) -> Path:
    """One panel per scene: every configuration, its Pareto front, the paper's setting and
    the target box (error ≤ 2 %, ≤ 5 ms)."""
    plt = pyplot()
    fig, axes = plt.subplots(1, len(sweeps), figsize=(4.6 * len(sweeps), 4.2), dpi=110,
                             squeeze=False)
    for ax, sweep in zip(axes[0], sweeps, strict=True):
        measured = sweep.measured
        if not measured:
            ax.set_title(f"{sweep.scene}: no configuration finished", fontsize=9)
            continue
        for m in sorted({p.m for p in measured}):
            group = [p for p in measured if p.m == m]
            ax.scatter([p.t_total_ms for p in group], [100 * p.error_vs_full for p in group],
                       s=18, label=f"m = {m}", alpha=0.8)
        front = pareto_front(measured)
        ax.plot([p.t_total_ms for p in front], [100 * p.error_vs_full for p in front], "k-",
                lw=1.0, drawstyle="steps-post", label="Pareto front")
        for p in front:
            ax.annotate(f"r{p.r} s{p.s} m{p.m}", (p.t_total_ms, 100 * p.error_vs_full),
                        fontsize=6, xytext=(3, 3), textcoords="offset points")
        paper = sweep.paper_point()
        if paper is not None:
            ax.scatter([paper.t_total_ms], [100 * paper.error_vs_full], marker="*", s=160,
                       facecolors="none", edgecolors="red", linewidths=1.2,
                       label=f"scene's (m, r, s) = {sweep.paper}")
        ax.axhline(100 * TARGET_ERROR, color="0.5", lw=0.8, ls=":")
        ax.axvline(TARGET_MS, color="0.5", lw=0.8, ls="--")
        ax.fill_between([0.0, TARGET_MS], 0.0, 100 * TARGET_ERROR, color="green", alpha=0.08,
                        label=f"target: ≤ {TARGET_ERROR:.0%}, ≤ {TARGET_MS:g} ms")
        ax.set_xlim(left=0.0)
        ax.set_yscale("log")
        lowest = min(100 * p.error_vs_full for p in measured)
        ax.set_ylim(bottom=min(0.5 * lowest, 0.5 * 100 * TARGET_ERROR))
        ax.set_xlabel("reduced time per step (ms, median)")
        ax.set_ylabel("error vs full (%)")
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
             "pareto": [dataclasses.asdict(p) for p in pareto_front(s.points)],
             "meeting_target": [dataclasses.asdict(p) for p in meeting(s.points)],
             "closest": (None if closest_miss(s.points) is None
                         else dataclasses.asdict(closest_miss(s.points)))}
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
