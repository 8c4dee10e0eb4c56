"""The reduced method at real-time step sizes (20, 50, 60 Hz) against the full method.

Real-time users step at the display rate, not at 1 ms. For each scene and step size
:func:`large_step_study` runs the ``full`` method (converged Newton, the reference at
that dt) and the ``reduced`` method (Newton to the real-time residual tolerance,
:data:`~lbshape.dynamics.reduced.REALTIME_RTOL`) over the same simulated time, and
reports the final displacement of each, their relative difference, the trajectory
error (``max_t ‖u(t) − u_full(t)‖_M / max_t ‖u_full(t)‖_M``), the Newton updates and
the per-step cost; beside it one unchecked Newton update per step (the step before the
residual was measured), to show what the tolerance prevents. :func:`large_steps_markdown`
writes ``large_steps.md`` and :func:`large_steps_plot` ``large_steps.png``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lbshape.analysis.norms import trajectory_error
from lbshape.dynamics.reduced import REALTIME_RTOL
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.io.machine import load_text, threads_text
from lbshape.pipeline.precomputed import Precomputed
from lbshape.pipeline.simulate import WARMUP_STEPS, full_simulation, reduced_simulation
from lbshape.report.plots import pyplot, save_figure
from lbshape.scene.schema import Scene
from lbshape.scene.variants import with_step

#: display rates of the study (Hz); 1000 Hz is the dt = 1 ms the scenes are tuned at
FREQUENCIES_HZ: tuple[float, ...] = (1000.0, 60.0, 50.0, 20.0)


@dataclass(frozen=True)
class LargeStepRow:
    """One scene at one step size.

    Attributes:
        scene: scene name.
        hz: steps per second (1/dt).
        dt: the step in s.
        steps: steps run (the same simulated time at every dt).
        full_final: the full method's largest vertex displacement at the end (m); where
            it stopped, at its last good step.
        reduced_final: the reduced method's, or None if it stopped (m).
        final_difference: ``|reduced_final − full_final| / full_final`` (None if either
            stopped).
        error_vs_full: the trajectory error in the mass norm (None if either stopped).
        mean_updates, max_updates: Newton updates per step of the reduced run.
        step_ms: median wall time of a reduced step after the warm-up (ms).
        reduced_message: why the reduced run stopped ('' if it finished).
        unchecked_final: one unchecked update per step: final largest displacement (m),
            None if that run stopped.
        unchecked_message: why the unchecked run stopped ('' if it finished).
    """

    scene: str
    hz: float
    dt: float
    steps: int
    full_final: float
    reduced_final: float | None
    final_difference: float | None
    error_vs_full: float | None
    mean_updates: float
    max_updates: int
    step_ms: float | None
    reduced_message: str
    unchecked_final: float | None
    unchecked_message: str
    full_message: str = ""  #: why the full run stopped ('' if it finished)


def _final_max(frames: np.ndarray) -> float:
    """Largest vertex displacement (m) of the last frame of (k, n, 3) displacements."""
    return float(np.linalg.norm(frames[-1], axis=1).max())


def large_step_study(scene: Scene, pre: Precomputed, *, duration: float,
                     frequencies: Sequence[float] = FREQUENCIES_HZ) -> list[LargeStepRow]:
    """The reduced method against the full one at each step rate (see the module docstring).

    Args:
        scene: a scene with a fixed region or a free body.
        pre: its precompute (independent of dt).
        duration: simulated time in s, the same at every rate.
        frequencies: step rates in Hz.
    """
    mass = mass_matrix(pre.mesh, pre.material.density)
    rows = []
    for hz in frequencies:
        stepped = with_step(scene, 1.0 / hz, duration)
        steps = stepped.simulation.steps
        stride = max(1, math.ceil(steps / 100))
        full_engine = full_simulation(stepped, pre)
        full = full_engine.run(steps, stride=stride)
        full_frames = full_engine.displacements(full)
        full_final = _final_max(full_frames)
        sim = reduced_simulation(stepped, pre)
        record = sim.run(steps, stride=stride)
        reduced_final = difference = error = None
        step_ms = None
        if record.stable:
            frames = sim.displacements(record)
            reduced_final = _final_max(frames)
        if record.stable and full.stable:
            difference = abs(reduced_final - full_final) / full_final
            error = trajectory_error(frames, full_frames, mass, times=record.times,
                                     times_full=full.times)
        totals = record.t_total_ms[WARMUP_STEPS:] if record.steps > WARMUP_STEPS \
            else record.t_total_ms
        if totals.size:
            step_ms = float(np.median(totals))
        unchecked = unchecked_frames = None
        if not scene.is_free:  # a free body's step has no unchecked variant
            unchecked_sim = reduced_simulation(stepped, pre, newton_iterations=1)
            unchecked = unchecked_sim.run(steps, stride=stride)
            unchecked_frames = unchecked_sim.displacements(unchecked)
        iterations = record.newton_iterations
        rows.append(LargeStepRow(
            scene=scene.name, hz=float(hz), dt=1.0 / hz, steps=steps, full_final=full_final,
            reduced_final=reduced_final, final_difference=difference, error_vs_full=error,
            mean_updates=float(iterations.mean()) if iterations.size else 0.0,
            max_updates=int(iterations.max()) if iterations.size else 0,
            step_ms=step_ms,
            reduced_message=record.message, full_message=full.message,
            unchecked_final=(_final_max(unchecked_frames)
                             if unchecked is not None and unchecked.stable else None),
            unchecked_message="" if unchecked is None or unchecked.stable
            else unchecked.message))
    return rows


def _fmt(value, spec: str) -> str:
    return "—" if value is None else format(value, spec)


def large_steps_markdown(rows: Sequence[LargeStepRow], *, duration: dict[str, float],
                         machine: dict, command: str) -> str:
    """``large_steps.md``: one row per scene and step rate."""
    lines = [
        "# The reduced method at real-time step sizes", "",
        f"Command: `{command}`.", "",
        "Each scene runs the same simulated time at each step rate with the `full` method "
        "(converged Newton: the reference at that dt) and the `reduced` method (Newton until "
        f"the relative residual is below {REALTIME_RTOL:g}, measured at every step's accepted "
        "state). Final: the largest vertex displacement at the end (m); difference: "
        "|reduced − full| / full of it; trajectory error: `max_t ‖u − u_full‖_M / max_t "
        "‖u_full‖_M`. Unchecked: one Newton update per step from the predictor without a "
        "residual check (the earlier real-time step), final displacement or where it stopped. "
        "vs full at 1 ms: the final displacement against the full method's at dt = 1 ms (the "
        "time-converged answer), for the full and the reduced run at this rate. "
        "Step: median wall time of a reduced step after the warm-up.", "",
        "| scene | rate (Hz) | dt (s) | steps | full final (m) | reduced final (m) | "
        "difference | trajectory error | full vs full at 1 ms | reduced vs full at 1 ms | "
        "Newton updates mean / max | step (ms) | unchecked: final (m) or stop |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    fine = {row.scene: row.full_final for row in rows
            if row.hz == 1000.0 and not row.full_message}
    for row in rows:
        reference = fine.get(row.scene)
        full_drift = (None if reference is None or row.full_message
                      else abs(row.full_final - reference) / reference)
        reduced_drift = (None if reference is None or row.reduced_final is None
                         else abs(row.reduced_final - reference) / reference)
        unchecked = (_fmt(row.unchecked_final, ".4f") if not row.unchecked_message
                     else "stopped: " + row.unchecked_message.split(":")[0])
        reduced = (_fmt(row.reduced_final, ".4f") if not row.reduced_message
                   else "stopped: " + row.reduced_message)
        full = (f"{row.full_final:.4f}" if not row.full_message
                 else "stopped: " + row.full_message)
        lines.append(
            f"| {row.scene} | {row.hz:g} | {row.dt:.4g} | {row.steps} | {full} "
            f"| {reduced} | {_fmt(row.final_difference, '.1%')} "
            f"| {_fmt(row.error_vs_full, '.1%')} | {_fmt(full_drift, '.1%')} "
            f"| {_fmt(reduced_drift, '.1%')} | {row.mean_updates:.2f} / {row.max_updates} "
            f"| {_fmt(row.step_ms, '.3f')} | {unchecked} |")
    large = [r for r in rows if r.hz < 1000]
    worst = max((r.final_difference for r in large if r.final_difference is not None),
                default=None)
    misses = [r for r in large if r.final_difference is not None and r.final_difference > 0.2]
    stopped = [r for r in rows if r.reduced_message]
    references = [r for r in rows if r.full_message]
    sixty = [r.step_ms for r in rows if r.hz == 60.0 and r.step_ms is not None]
    lines += [
        "", "## Verdict", "",
        f"- Target: final displacement within 20 % of the full method at 20, 50 and 60 Hz. "
        f"Largest difference measured: {_fmt(worst, '.1%')}; reduced runs that stopped: "
        f"{len(stopped)}; full runs that stopped (no difference measured): "
        + (", ".join(f"{r.scene} at {r.hz:g} Hz" for r in references) or "none")
        + "; rows over 20 %: "
        + (", ".join(f"{r.scene} at {r.hz:g} Hz ({r.final_difference:.1%}; the full method "
                     f"there is {abs(r.full_final - fine[r.scene]) / fine[r.scene]:.1%} from "
                     "its own 1 ms answer)" if r.scene in fine else
                     f"{r.scene} at {r.hz:g} Hz ({r.final_difference:.1%})" for r in misses)
           or "none") + ".",
        f"- Per-step cost at 60 Hz: {_fmt(min(sixty, default=None), '.3f')}–"
        f"{_fmt(max(sixty, default=None), '.3f')} ms.",
        "", "## Conditions", "",
        "- Simulated time per scene: " + ", ".join(f"{k} {v:g} s" for k, v in duration.items())
        + ".",
        f"- One process; threads: {threads_text(machine)}; {machine['cpu']}, "
        f"{machine['cores']} cores; load average (1, 5, 15 min) when written: "
        f"{load_text(machine)}.", ""]
    return "\n".join(lines)


def large_steps_payload(rows: Sequence[LargeStepRow]) -> dict:
    """``large_steps.json``."""
    return {"rtol": REALTIME_RTOL, "rows": [dataclasses.asdict(row) for row in rows]}


def large_steps_plot(rows: Sequence[LargeStepRow], path: str | Path) -> Path:
    """``large_steps.png``: per scene, the final largest displacement (m) at each step rate
    (Hz) for the full method, the reduced method and one unchecked update per step (a
    cross where a run stopped)."""
    plt = pyplot()
    scenes = list(dict.fromkeys(row.scene for row in rows))
    fig, axes = plt.subplots(1, len(scenes), figsize=(3.2 * len(scenes), 3.4), squeeze=False)
    for ax, scene in zip(axes[0], scenes, strict=True):
        mine = sorted((r for r in rows if r.scene == scene), key=lambda r: r.hz)
        hz = list(range(len(mine)))  # one slot per rate, labelled below
        ax.plot(hz, [np.nan if r.full_message else r.full_final for r in mine], "o-",
                color="black", label="full (a gap: it stopped)")
        ax.plot(hz, [np.nan if r.reduced_final is None else r.reduced_final for r in mine],
                "s--", color="tab:blue", label="reduced (a gap: it stopped)")
        top = max(r.full_final for r in mine) * 1.6
        label = "1 update, unchecked"
        for x, r in zip(hz, mine, strict=True):
            stopped = [name for name, gone in (("full", r.full_message),
                                               ("reduced", r.reduced_final is None)) if gone]
            if stopped:  # named at the bottom of the gap
                ax.annotate(" and ".join(stopped) + " stopped", (x, 0.0),
                            textcoords="offset points", xytext=(0, 4), ha="center",
                            fontsize=7, color="black")
            if r.unchecked_message:  # stopped: a cross at the top
                ax.plot([x], [top], "x", color="tab:red", markersize=9)
                ax.annotate("stopped", (x, top), textcoords="offset points",
                            xytext=(0, -12), ha="center", fontsize=7, color="tab:red")
            elif r.unchecked_final is not None:  # finished: off the axis shown by value
                value = min(r.unchecked_final, top)
                ax.plot([x], [value], "^", color="tab:red", label=label)
                label = None
                if r.unchecked_final > top:
                    ax.annotate(f"{r.unchecked_final:.2g} m", (x, value),
                                textcoords="offset points", xytext=(0, -12), ha="center",
                                fontsize=7, color="tab:red")
        ax.set_xticks(hz, [f"{r.hz:g}" for r in mine])
        ax.set_xlim(-0.5, len(mine) - 0.5)
        ax.set_ylim(0.0, top * 1.1)
        ax.set_title(scene, fontsize=10)
        ax.set_xlabel("step rate (Hz)")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("final largest displacement (m)")
    axes[0][0].legend(fontsize=7, loc="lower left")
    fig.suptitle("final displacement at real-time step sizes: reduced vs full; one unchecked "
                 "Newton update per step in red (its value where off the axis)", fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path)
