"""``free_bodies.md`` and ``free_bodies.json``: the free bodies' evaluation written out
(:mod:`lbshape.studies.free_bodies`). Errors only, no timings."""

from __future__ import annotations

import subprocess
from collections.abc import Sequence
from pathlib import Path

from lbshape.io.atomic import write_json_atomic, write_text_atomic
from lbshape.io.machine import load_text, machine_description, threads_text
from lbshape.studies.free_bodies import (
    CLEAR_SAMPLES,
    IMPACT_BODY,
    IMPACT_FLIGHT,
    IMPACT_STEPS,
    PERTURBATIONS,
    PRE_STEPS,
    ImpactComparison,
    WholeRun,
    ratio_text,
)

#: the command that writes the files
COMMAND = "OMP_NUM_THREADS=1 lbshape bench --free-bodies"


def _pct(value) -> str:
    return "—" if value is None else f"{100 * value:.2f}%"


def _num(value, digits: int = 3) -> str:
    return "—" if value is None else f"{value:.{digits}f}"


def _sci(value) -> str:
    return "—" if value is None else f"{value:.1e}"


def _commit() -> str:
    try:
        done = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, cwd=Path(__file__).parent, check=False)
    except OSError:
        return "unknown"
    return done.stdout.strip() or "unknown"


def whole_lines(runs: Sequence[WholeRun]) -> list[str]:
    """The whole-trajectory table with the noise floor beside each error."""
    labels = [label for label, _, _ in PERTURBATIONS]
    lines = [
        "| model | examples | error (whole trajectory) | noise floor | error / floor | "
        "error before first contact | first contact (s) | rest pose Chamfer | "
        "rest pose Hausdorff | rest-pose floor | " + " | ".join(labels) + " |",
        "|---|---|---|---|---|---|---|---|---|---|" + "---|" * len(labels),
    ]
    for run in runs:
        keys, changes = run.keys, dict(run.floor.changes)
        lines.append(
            f"| {run.scene} | {'yes' if run.examples else 'no'} | {_pct(run.error)} | "
            f"{_pct(keys['noise_floor'])} | {ratio_text(run.error, keys['noise_floor'])} | "
            f"{_pct(keys['error_pre_contact'])} | {_num(keys['first_contact_s'])} | "
            f"{_pct(keys['rest_pose_chamfer'])} | {_pct(keys['rest_pose_hausdorff'])} | "
            f"{_pct(run.floor.rest_floor)} | "
            + " | ".join(_pct(changes.get(label)) for label in labels) + " |")
    return lines


def impact_lines(impacts: Sequence[ImpactComparison]) -> list[str]:
    """The designed impacts' table, full against reduced."""
    lines = [
        "| hit | speed (m/s) | examples | restart error | restitution full / reduced | "
        "restitution error | Δp error | ΔL error | energy lost full / reduced | "
        "deepest penetration full / reduced (mm) | within 5 % / 10 % |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for impact in impacts:
        s = impact.stats()
        head = f"| {impact.kind} | {impact.speed:g} | {'yes' if impact.examples else 'no'} | "
        if impact.full is None:
            lines.append(head + f"{_sci(impact.restart_error)} | — | {impact.message} |"
                         + " — |" * 5)
            continue
        limit = 0.10 if impact.examples else 0.05
        met = max(s["restitution_error"], s["delta_p_error"], s["delta_L_error"]) <= limit
        lines.append(
            head + f"{_sci(impact.restart_error)} | {s['restitution_full']:.3f} / "
            f"{s['restitution_reduced']:.3f} | {_pct(s['restitution_error'])} | "
            f"{_pct(s['delta_p_error'])} | {_pct(s['delta_L_error'])} | "
            f"{_pct(s['energy_lost_full'])} / {_pct(s['energy_lost_reduced'])} | "
            f"{s['depth_full_mm']:.2f} / {s['depth_reduced_mm']:.2f} | "
            f"{'yes' if met else '**no**'} |")
    return lines


def write_free_bodies(runs: Sequence[WholeRun], impacts: Sequence[ImpactComparison],
                      out_dir: Path, *, command: str = COMMAND) -> tuple[Path, Path]:
    """Write ``free_bodies.md`` and ``free_bodies.json`` to ``out_dir``."""
    machine = machine_description()
    perturbations = ", ".join(label for label, _, _ in PERTURBATIONS)
    text = "\n".join([
        "# Free bodies: before contact, per impact, at rest, and the reference's noise floor",
        "",
        f"Command: `{command}` (commit {_commit()}). Errors only, no timings.",
        "",
        "## Whole trajectories beside the reference's noise floor",
        "",
        "Error: Table 2's `max_t ‖u − u_full‖_M / max_t ‖u_full‖_M` of the reduced run. "
        f"Noise floor: the largest change of the full reference under {perturbations} "
        "(each re-run measured against the unperturbed reference with the same norm, over "
        "the sample times both have); the per-perturbation changes are the last columns. "
        "Error / floor below about 1: the difference is inside what the reference itself "
        "does not determine. Error before first contact: the same norm over the samples "
        "before the first one at which a vertex of the reference is behind a plane. Rest "
        "pose: the symmetric Chamfer (mean) and Hausdorff (largest) distance between the "
        "final surfaces (each surface vertex to the other surface's triangles, both ways) "
        "over the rest shape's bounding-box diagonal, blind to which vertex is where (a "
        "square bar turned 90° about its long axis scores 0); the rest-pose floor: the "
        "largest Chamfer distance between the perturbed and the unperturbed reference.",
        "",
        *whole_lines(runs),
        "",
        "## Designed impacts from a synchronised pre-impact state",
        "",
        f"The {IMPACT_BODY} bar (long axis z, square section) thrown along −n at a plane of "
        "normal n — face hit n = x, edge hit n = (x + y)/√2, corner hit n = (x + y + z)/√3 "
        f"— without gravity (the impact alone), from {1e3 * IMPACT_FLIGHT:g} ms of flight away, "
        f"{IMPACT_STEPS} steps. The full run goes first; {PRE_STEPS} steps before its "
        "first contact its state (positions and central-difference velocities) is "
        "projected onto the reduced coordinates and frame (best mass-weighted rigid fit, "
        "momenta, q and its differences by least squares in M) and the reduced body "
        "restarts there (restart error: its displacement against the reference's at the "
        "restart, M-norm, relative). Both then run through the impact; the comparison "
        f"window ends at the first sample that starts {CLEAR_SAMPLES} samples without "
        "penetration in both runs. Restitution `−v_n(after)/v_n(before)` of the centre "
        "of mass (negative: the centre still moves towards the plane after a corner or "
        "edge hit turned the body); Δp: the contact's change of linear momentum "
        "(no other load acts), error `|Δp − Δp_full| / |Δp_full|`; ΔL: change of "
        "angular momentum about the centre of mass, error `|ΔL − ΔL_full| / "
        "max(|ΔL_full|, |Δp_full| × half diagonal)`; energy lost: kinetic energy lost over "
        "the centre's kinetic energy before (the vibration's elastic energy counts as lost). "
        "Target: restitution, Δp and ΔL within 5 % without examples, 10 % with.",
        "",
        *impact_lines(impacts),
        "",
        "## Conditions",
        "",
        f"- Machine: {machine['cpu']}, {machine['cores']} cores, Python {machine['python']},"
        f" numpy {machine['numpy']}; threads: {threads_text(machine)}.",
        f"- Load average (1, 5, 15 min) when written: {load_text(machine)} (no timings here).",
        "- Not measured: the reference under one mesh refinement (a refined mesh has other "
        "vertices, so its trajectory needs a transfer to be compared).",
        "",
    ])
    out_dir = Path(out_dir)
    md = write_text_atomic(out_dir / "free_bodies.md", text)
    js = write_json_atomic(out_dir / "free_bodies.json", {
        "command": command, "whole": [run.stats() for run in runs],
        "impacts": [impact.stats() for impact in impacts], "machine": machine})
    return md, js
