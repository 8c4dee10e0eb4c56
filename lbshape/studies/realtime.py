"""Real time at dt = 1 ms: the paper's Table 2 figures, the step breakdown and its floor.

* :data:`PAPER_TABLE2` — the per-step times the paper reports (its Table 2, ms), next
  to which ``table2.md`` puts ours;
* :func:`newton_flops` — the floating-point operations of one reduced step with one
  Newton iteration at (r, s): displacement gradients, element stresses and tangents,
  the reduced force and tangent, the Newton matrix and its Cholesky solve, the
  weights and the tabulated target;
* :func:`gemm_rate` — the single-thread rate (GFlop/s) this machine reaches on the
  step's largest product (an (r × 9s) · (9s × r) matrix product), so that the floor
  ``flops / rate`` states how close each part is to the limit;
* :func:`breakdown_lines` — the Markdown of the step breakdown for ``table2.md``;
* :func:`newton_study` — the reduced method with one unchecked Newton update per step,
  with the real-time residual tolerance and converged: error vs full, difference to
  converged, cost (``step_breakdown.md``);
* :func:`write_free_body_step` — the free-body step against the 1 ms target: median
  per step, its parts and the error vs full (``free_body_step.md`` and ``.json``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lbshape.analysis.norms import trajectory_error
from lbshape.dynamics.engine import NewtonSettings
from lbshape.dynamics.free_body import PHASES as FREE_BODY_PHASES
from lbshape.dynamics.reduced import PHASES, REALTIME_NEWTON, REALTIME_RTOL
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.io.atomic import write_json_atomic, write_text_atomic
from lbshape.io.machine import load_text, machine_description, threads_text
from lbshape.pipeline.simulate import (
    MAX_FRAMES,
    WARMUP_STEPS,
    phase_medians,
    reduced_simulation,
    simulate,
)
from lbshape.studies.bench import TARGET_T_TOTAL_MS, SceneBenchmark

#: the paper's Table 2 (Zhu et al. [2] and the paper's method), ms per step, by our scene
#: names: (DOFs, tets, example vertices, m, r, s, [2] t_interp, [2] t_total, ours
#: t_interp, ours t_total)
PAPER_TABLE2: dict[str, tuple] = {
    "bar-cuboid": (981, 1053, 327, 10, 30, 60, 51.2, 55.5, 35.1, 41.5),
    "bar-cylinder": (981, 1053, 2478, 10, 30, 60, 266.8, 271.6, 32.7, 39.4),
    "cross": (4683, 4912, 3172, 10, 42, 21, 564.1, 592.4, 11.9, 18.3),
    "car": (2181, 2369, 1019, 6, 20, 23, 207.7, 221.6, 16.7, 21.2),
    "teddy-global": (1773, 1755, 11193, 6, 30, 30, 70.3, 83.5, 28.7, 33.4),
    "teddy-local": (1773, 1755, 11193, 6, 30, 30, 302.8, 313.7, 33.2, 38.4),
}
#: flops per element of the StVK stress and stress derivative (closed forms, counted)
_ELEMENT_FLOPS = 700


def newton_flops(r: int, s: int, *, k: int = 2, m: int = 10,
                 forces: str = "cubature") -> dict[str, int]:
    """Floating-point operations of one reduced step with one Newton iteration.

    Args:
        r: reduced coordinates; s: cubature elements; k: examples; m: LB modes.
        forces: ``"cubature"`` (s elements) or ``"polynomial"`` (the exact polynomial
            force: two matrix-vector products with P = r(r+1)/2 rows, s unused).

    Returns:
        Flops per part (keys as :data:`~lbshape.dynamics.reduced.PHASES` where they
        apply) and ``"total"``.
    """
    weights = 2 * k * r + (2**k - 1) * 2 * k * k
    target = 2 * 10 * r
    example_force = 2 * r
    gradients = 2 * 9 * s * r
    element = _ELEMENT_FLOPS * s
    projected = 2 * 81 * s * r  # T_e = A_e (BU)_e
    force = 2 * 9 * s * r
    tangent = 2 * 9 * s * r * r  # K = (W BU)ᵀ T
    solve = r * r * r // 3 + 2 * r * r + 12 * r
    internal = gradients + element + projected + force + tangent
    if forces == "polynomial":
        pairs = r * (r + 1) // 2
        internal = 2 * pairs * pairs + 2 * pairs * r + 2 * r * r + 8 * pairs
    parts = {
        "weights": weights, "target": target, "example_force": example_force,
        "internal_force_tangent": internal,
        "solve": solve,
    }
    parts["total"] = sum(parts.values())
    return parts


def gemm_rate(r: int, s: int, *, repeats: int = 200) -> float:
    """GFlop/s of the (r × 9s) · (9s × r) product on this machine (best of ``repeats``)."""
    rng = np.random.default_rng(0)
    a = np.ascontiguousarray(rng.standard_normal((r, 9 * s)))
    b = np.ascontiguousarray(rng.standard_normal((9 * s, r)))
    out = np.empty((r, r))
    best = np.inf
    for _ in range(repeats):
        started = time.perf_counter()
        np.dot(a, b, out=out)
        best = min(best, time.perf_counter() - started)
    return 2.0 * 9 * s * r * r / best / 1e9


def breakdown_lines(results: Sequence[SceneBenchmark], *, rate: float | None = None
                    ) -> list[str]:
    """Markdown sections for ``table2.md``: the paper's figures beside ours, and the step
    breakdown with the physical floor."""
    lines = ["", "## Beside the paper's Table 2 (ms per step; the paper: dt = 1 ms, its "
             "machine)", "",
             "| model | paper [2] t_interp | paper [2] t_total | paper t_interp "
             "| paper t_total | ours euclidean t_interp | ours euclidean t_total "
             "| ours reduced t_interp | ours reduced t_total | ours / paper t_total |",
             "|---|" + "---|" * 9]
    for result in results:
        paper = PAPER_TABLE2.get(result.scene)
        euclid, reduced = result.row("euclidean") or {}, result.row("reduced") or {}
        if paper is None:
            continue
        ours = reduced.get("t_total_ms")
        lines.append(
            f"| {result.scene} | {paper[6]:.1f} | {paper[7]:.1f} | {paper[8]:.1f} "
            f"| {paper[9]:.1f} | {_fmt(euclid.get('t_interp_ms'))} "
            f"| {_fmt(euclid.get('t_total_ms'))} | {_fmt(reduced.get('t_interp_ms'), '.4f')} "
            f"| {_fmt(ours, '.4f')} | {_fmt(None if ours is None else ours / paper[9], '.4f')} |")
    measured = [(result, t) for result in results for t in result.timings
                if t.method == "reduced" and t.phase_summary()]
    if not measured:
        return lines
    first = measured[0][0].row("reduced")
    rate = gemm_rate(first["r"], first["s"]) if rate is None else rate
    columns = phase_columns([timing.phase_summary() for _, timing in measured])
    lines += ["", "## Breakdown of a reduced step (µs, median over steps after warm-up, "
              "median over repeats) and its floor", "",
              "Floor: the flops of one Newton iteration at (r, s) (gradients, element "
              "stresses and tangents, reduced force and tangent, Newton matrix and Cholesky "
              "solve, weights, tabulated target; with the exact polynomial forces, s = every "
              "element, the force and tangent are two matrix-vector products with "
              f"r(r+1)/2 rows instead) at {rate:.1f} GFlop/s, the best "
              "single-thread rate of this machine on the step's largest matrix product "
              "(r × 9s by 9s × r), measured in the same process. A free body with impact "
              "columns: at its plain basis r₀ (r (r₀)), which every step solves for; a step "
              "on a set of columns solves for a few more.", "",
              "| model | r | s | " + " | ".join(columns) + " | total | floor total "
              "| flops (one iteration) |",
              "|---|---|---|" + "---|" * (len(columns) + 3)]
    for result, timing in measured:
        phases = timing.phase_summary()
        row = result.row("reduced")
        r, s, m = row["r"], row["s"], row["m"]
        flops = newton_flops(result.plain_r or r, s, m=m, forces=result.force_model)
        floor = {name: 1e6 * value / (rate * 1e9) for name, value in flops.items()}
        cells = ["—" if name not in phases
                 else f"{1e3 * phases[name]:.1f} (≥ {floor[name]:.2f})" if name in floor
                 else f"{1e3 * phases[name]:.1f}" for name in columns]
        total = 1e3 * sum(phases.values())
        sizes = f"{r} ({result.plain_r})" if result.plain_r else f"{r}"
        lines.append(f"| {result.scene} | {sizes} | {s} | " + " | ".join(cells)
                     + f" | {total:.1f} | {floor['total']:.1f} | {flops['total']:,} |")
    lines += ["", "In parentheses: that part's floor (µs). Overhead: the rest of the step "
              "(predictor, state swap, checks, Python). Free bodies (rigid and contact "
              "columns) iterate Newton to convergence, so their floor of one iteration is "
              "a lower bound. The parts are medians over steps; "
              "t_total in the tables above is the contract's per-step mean, which also "
              "counts the rare slow steps (other processes taking the core, garbage "
              "collection)."]
    return lines


def phase_columns(summaries: Sequence[dict | None]) -> list[str]:
    """The phase names present in any of the phase records, in step order (a fixed
    object's :data:`~lbshape.dynamics.reduced.PHASES` are a subsequence of a free body's
    :data:`~lbshape.dynamics.free_body.PHASES`)."""
    present = {name for summary in summaries if summary for name in summary}
    order = list(FREE_BODY_PHASES) + [name for name in PHASES if name not in FREE_BODY_PHASES]
    return [name for name in order if name in present]


def _fmt(value: float | None, spec: str = ".3f") -> str:
    return "—" if value is None else format(value, spec)


# ------------------------------------------------------------------ Newton study
#: (label, Newton updates per step or None, relative residual tolerance) of the study:
#: one unchecked update from the predictor (the step before the residual was measured),
#: the real-time tolerance, and converged Newton
NEWTON_VARIANTS: tuple[tuple[str, int | None, float], ...] = (
    ("1 update, unchecked", 1, REALTIME_RTOL),
    (f"residual <= {REALTIME_RTOL:g} (real time)", None, REALTIME_RTOL),
    ("residual <= 1e-10 (converged)", None, 1e-10),
)


@dataclass(frozen=True)
class NewtonVariant:
    """The reduced method with one Newton policy per step (:data:`NEWTON_VARIANTS`).

    Attributes:
        label: the policy.
        error_vs_full: trajectory error against ``full`` (None if a run failed).
        difference: ``max_t ‖u(t) − u_conv(t)‖_M / max_t ‖u_conv(t)‖_M`` against the
            converged variant (None if a run failed).
        mean_iterations: mean Newton updates per step.
        t_total_ms: (repeats,) per-step mean of each run (ms).
        phase_ms: median per part of the step (ms) over steps and repeats.
        message: why a run stopped ('' if it finished).
    """

    label: str
    error_vs_full: float | None
    difference: float | None
    mean_iterations: float
    t_total_ms: tuple[float, ...]
    phase_ms: dict
    message: str = ""


def newton_study(scene, pre, *, steps: int, repeats: int = 3,
                 variants: Sequence[tuple[str, int | None, float]] = NEWTON_VARIANTS
                 ) -> list[NewtonVariant]:
    """Error and cost of the reduced method for each Newton policy per step.

    The variants run interleaved ``repeats`` times; the full-space reference once. The
    last variant is the converged one the others are compared with.
    """
    full = simulate(scene, pre, method="full", steps=steps)
    mass = mass_matrix(pre.mesh, pre.material.density)
    labels = [label for label, _, _ in variants]
    times: dict = {label: [] for label in labels}
    phases: dict = {label: [] for label in labels}
    first: dict = {}
    for _ in range(repeats):
        for label, iterations, rtol in variants:
            newton = NewtonSettings(rtol, REALTIME_NEWTON.max_iterations)
            sim = reduced_simulation(scene, pre, newton_iterations=iterations, newton=newton)
            record = sim.run(steps, stride=max(1, math.ceil(steps / MAX_FRAMES)))
            times[label].append(record.mean_ms(warmup=WARMUP_STEPS)[1])
            phases[label].append(phase_medians(sim))
            first.setdefault(label, (sim, record))
    converged_sim, converged = first[labels[-1]]
    out = []
    for label in labels:
        sim, record = first[label]
        u = sim.displacements(record)
        stable = record.stable and full.message == ""
        error = trajectory_error(u, full.displacements, mass, times=record.times,
                                 times_full=full.times) if stable else None
        difference = None
        if record.stable and converged.stable:
            difference = trajectory_error(u, converged_sim.displacements(converged), mass)
        measured = [p for p in phases[label] if p is not None]
        out.append(NewtonVariant(
            label=label, error_vs_full=error, difference=difference,
            mean_iterations=float(np.mean(record.newton_iterations))
            if record.newton_iterations.size else 0.0,
            t_total_ms=tuple(times[label]),
            phase_ms={name: float(np.median([p[name] for p in measured]))
                      for name in (measured[0] if measured else {})},
            message=record.message))
    return out


def newton_study_markdown(studies: dict[str, list[NewtonVariant]], *, steps: int,
                          repeats: int, machine: dict) -> str:
    """``step_breakdown.md``: per scene, the Newton policies of :data:`NEWTON_VARIANTS`."""
    columns = phase_columns([v.phase_ms for variants in studies.values() for v in variants])
    lines = ["# The reduced step: Newton updates per step and the breakdown of a step", "",
             "Each variant is the `reduced` method (tabulated target) with one Newton policy "
             "per time step: one update from the predictor with its residual unchecked, "
             f"updates until the relative residual is below {REALTIME_RTOL:g} (the real-time "
             "step, whose first update uses the force and tangent of the previous step's last "
             "evaluation), or converged Newton (1e-10). "
             "Error vs full: `max_t ‖u(t) − u_full(t)‖_M / max_t ‖u_full(t)‖_M`; difference: "
             "the same against the converged variant. Times: per-step mean after "
             f"{WARMUP_STEPS} warm-up steps, median over {repeats} interleaved repeats "
             f"[min, max]; parts of a step: medians (µs).", "",
             "| model | Newton policy | mean updates | error vs full | difference to "
             "converged | t_total ms | " + " | ".join(columns) + " |",
             "|---|---|---|---|---|---|" + "---|" * len(columns)]
    for scene, variants in studies.items():
        for v in variants:
            t = np.asarray(v.t_total_ms)
            lines.append(
                f"| {scene} | {v.label} "
                f"| {v.mean_iterations:.3f} | {_fmt(v.error_vs_full, '.3%')} "
                f"| {_fmt(v.difference, '.2e')} | {np.median(t):.4f} [{t.min():.4f}, "
                f"{t.max():.4f}] | "
                + " | ".join(f"{1e3 * v.phase_ms[p]:.1f}" if p in v.phase_ms else "—"
                             for p in columns) + " |")
    chosen = [v for variants in studies.values() for v in variants
              if v.label == NEWTON_VARIANTS[1][0]]
    worst = max((v.difference for v in chosen if v.difference is not None), default=None)
    most = max((v.mean_iterations for v in chosen), default=None)
    lines += ["", "## Choice", "",
              f"The real-time step iterates Newton until the relative residual is below "
              f"{REALTIME_RTOL:g} (`lbshape.dynamics.reduced.REALTIME_RTOL`), measured at the "
              "accepted state of every step: its trajectories differ from converged Newton by "
              f"at most {_fmt(worst, '.2e')} (relative, mass norm) with at most "
              f"{_fmt(most, '.2f')} updates per step on average. One unchecked update is as "
              "accurate at dt = 1 ms but runs away at real-time step sizes "
              "(`large_steps.md`).",
              "", "## Conditions", "",
              f"- {steps} steps of dt = 1 ms per run; one process; threads: "
              f"{threads_text(machine)}; {machine['cpu']}, {machine['cores']} cores.",
              f"- Load average (1, 5, 15 min) when written: {load_text(machine)} — other "
              "processes shared the cores.", ""]
    return "\n".join(lines)


def newton_study_payload(studies: dict[str, list[NewtonVariant]]) -> dict:
    """``step_breakdown.json``."""
    return {scene: [dataclasses.asdict(v) for v in variants]
            for scene, variants in studies.items()}


# ------------------------------------------------------------------ free-body step
def free_body_step_payload(results: Sequence[SceneBenchmark], machine: dict) -> dict:
    """The document of ``free_body_step.json``: per scene, the ``reduced`` step's median
    wall time per step (median over repeats, with min and max), its mean, the phase
    record (median ms per phase) and the error vs ``full``."""
    rows = []
    for result in results:
        row = result.row("reduced")
        timing = next((t for t in result.timings if t.method == "reduced"), None)
        if row is None or timing is None or not timing.step_median_ms:
            continue
        medians = np.asarray(timing.step_median_ms)
        rows.append({
            "scene": result.scene, "n_vertices": row["n_vertices"], "m": row["m"],
            "r": row["r"], "s": row["s"], "steps": result.steps, "repeats": result.repeats,
            "warmup_steps": result.warmup, "dt": result.dt,
            "step_median_ms": {"median": float(np.median(medians)),
                               "min": float(medians.min()), "max": float(medians.max())},
            "t_total_ms": timing.summary("t_total_ms"),
            "phase_ms": timing.phase_summary(),
            "error_vs_full": row["error_vs_full"], "stable": timing.stable,
            "target_ms": TARGET_T_TOTAL_MS,
            "meets_target": bool(np.median(medians) <= TARGET_T_TOTAL_MS),
        })
    return {"rows": rows, "machine": machine}


def free_body_step_markdown(payload: dict) -> str:
    """The Markdown of ``free_body_step.md`` from :func:`free_body_step_payload`."""
    rows, machine = payload["rows"], payload["machine"]
    columns = phase_columns([row["phase_ms"] for row in rows])
    lines = ["# The free-body step against real time (dt = 1 ms)", "",
             "The `reduced` method on free bodies (rigid frame, fictitious forces, plane "
             "contact, Newton to convergence). Median per step: the median wall time of a "
             "step after the warm-up, median over the repeats [min, max]; mean: the "
             "contract's per-step mean (it also counts the rare slow steps); parts of a "
             "step: median µs per phase; error vs full: "
             "`max_t ‖u(t) − u_full(t)‖_M / max_t ‖u_full(t)‖_M`. Target: "
             f"≤ {TARGET_T_TOTAL_MS:g} ms median per step.", "",
             "| model | vertices | m | r | s | steps | median per step (ms) | mean (ms) "
             "| target met | error vs full |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        median, mean = row["step_median_ms"], row["t_total_ms"]["median"]
        lines.append(
            f"| {row['scene']} | {row['n_vertices']} | {row['m']} | {row['r']} | {row['s']} "
            f"| {row['steps']} | {median['median']:.3f} [{median['min']:.3f}, "
            f"{median['max']:.3f}] | {mean:.3f} | {'yes' if row['meets_target'] else 'no'} "
            f"| {_fmt(row['error_vs_full'], '.2%')} |")
    lines += ["", "## Parts of a step (µs, median over steps, median over repeats)", "",
              "| model | " + " | ".join(columns) + " |",
              "|---|" + "---|" * len(columns)]
    for row in rows:
        phases = row["phase_ms"] or {}
        lines.append(f"| {row['scene']} | " + " | ".join(
            f"{1e3 * phases[name]:.1f}" if name in phases else "—" for name in columns) + " |")
    lines += _resting_markdown(payload.get("resting") or [])
    repeats = sorted({row["repeats"] for row in rows})
    lines += ["", "## Conditions", "",
              f"- dt = 1 ms, the scenes' own (m, r, s); {', '.join(map(str, repeats))} "
              "runs of `reduced` per scene for the times, the error from a run against "
              f"`full`; one process; threads: {threads_text(machine)}; {machine['cpu']}, "
              f"{machine['cores']} cores.",
              f"- Load average (1, 5, 15 min) when written: {load_text(machine)} — other "
              "processes shared the cores.", ""]
    return "\n".join(lines)


def _resting_markdown(resting: Sequence[dict]) -> list[str]:
    """The section on the step of a body resting on the floor (rows of
    ``scripts/bench_free_body.py``'s ``resting_step``); none without rows."""
    if not resting:
        return []
    first, last = resting[0]["window_s"]
    lines = ["", f"## On the floor ({first:g}-{last:g} s, after the bounces)", "",
             "Each step timed alone, median over the runs of the median [min, max] and of "
             f"the mean (≤ {TARGET_T_TOTAL_MS:g} ms: the mean, every step counted); sweeps "
             "and passes per step; the share of steps that end touching a plane; the "
             "centre's drift, the distance between the window's ends over its length "
             "(it slides and rocks).", "",
             "| model | runs | median per step (ms) | mean (ms) | ≤ 1 ms | sweeps / passes "
             "per step | touching | centre drift (m/s) |",
             "|---|---|---|---|---|---|---|---|"]
    for row in resting:
        low, high = row["median_ms_range"]
        met = "yes" if row["mean_ms"] <= TARGET_T_TOTAL_MS else "**no**"
        lines.append(
            f"| {row['scene']} | {row['repeats']} | {row['median_ms']:.3f} [{low:.3f}, "
            f"{high:.3f}] | {row['mean_ms']:.3f} | {met} | {row['sweeps_per_step']:.2f} / "
            f"{row['passes_per_step']:.2f} | {row['touching_share']:.0%} | "
            f"{row['center_drift']:.3f} |")
    return lines


def write_free_body_step(results: Sequence[SceneBenchmark], out_dir: str | Path, *,
                         resting: Sequence[dict] = ()) -> tuple[Path, Path]:
    """Write ``free_body_step.md`` and ``free_body_step.json`` to ``out_dir`` atomically
    (``resting``: the rows of the step on the floor, a section of their own); their
    paths."""
    out_dir = Path(out_dir)
    payload = free_body_step_payload(results, machine_description())
    payload["resting"] = list(resting)
    md = write_text_atomic(out_dir / "free_body_step.md", free_body_step_markdown(payload))
    js = write_json_atomic(out_dir / "free_body_step.json", payload)
    return md, js
