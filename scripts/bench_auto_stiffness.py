"""``stiffness = "auto"`` on the built-in fixed scenes and on a user's clamped object.

Usage: ``.venv/bin/python scripts/bench_auto_stiffness.py [--out-dir results]
[--scenes bar-cuboid demo ...] [--max-time 0.5]``.

Each scene is switched to ``stiffness = "auto"`` (its precompute sets k_ex,
:mod:`lbshape.shapespace.auto_stiffness`) and run with the reduced method (and once more
without examples for the visible change and the closest example,
:mod:`lbshape.pipeline.influence`) and with the full-space reference, for the scene's own
steps but at most ``--max-time`` s of simulated time. The target (issue 39): a visible
change of at least 5 % of the bounding-box diagonal, the final shape closest to an
example (every region's, for local examples), and the reduced run within 5 % of the full
one (``max_t ‖u − u_full‖_M / max_t ‖u_full‖_M``); beside it, how much of the full run
the reduced basis U holds (the same measure of ``u_full − U Uᵀ M u_full``, ``UᵀMU = I``):
a reduced run far beyond it is not limited by its basis. The user's object is a soft clamped
bar of one's own (``lbshape.geometry.primitives.structured_box``) bent by one example,
with no load. Writes ``auto_stiffness.md`` and ``auto_stiffness.json``.
"""

from __future__ import annotations

import os

if __name__ == "__main__":  # single-threaded BLAS, set before numpy loads
    for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import argparse
import dataclasses
import datetime
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import lbshape
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.geometry.primitives import structured_box
from lbshape.io.atomic import write_json_atomic, write_text_atomic
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import simulate
from lbshape.scene import load_scene

try:  # the machine record moves with the report package's restructuring
    from lbshape.io.machine import machine_description, machine_text
except ImportError:  # pragma: no cover - the older layout
    from lbshape.report.machine import machine_description, machine_text

ROOT = Path(__file__).resolve().parents[1]
#: the built-in fixed scenes of the target
SCENES = ("demo", "bar-cuboid", "bar-cylinder", "teddy-global", "teddy-local", "cross")
#: the user's clamped object without a load
USER = "clip"
#: the targets
VISIBLE = 0.05
ERROR = 0.05


def user_scene() -> lbshape.Scene:
    """A user's own clamped object with no load: a soft 0.4 m bar clamped at one end,
    bent by one example (the scene of tests/pipeline/test_auto_stiffness.py, with the
    m = 12, r = 20 a user would give it rather than the test's small m = 8, r = 12)."""
    box = structured_box((0.4, 0.05, 0.05), (16, 2, 2))
    return lbshape.Scene.from_mesh(
        box, name=USER, fixed="x < 1e-6", material={"young": 1e5, "density": 1000.0},
        reduced={"m": 12, "r": 20, "s": 30}, damping={"alpha": 0.5, "beta": 0.01},
        examples=[{"pose": "arc", "parameters": {"angle": 0.8, "axis": "x",
                                                 "direction": "z", "anchor": "min"}}],
        dt=0.002, steps=250)


def auto(scene: lbshape.Scene) -> lbshape.Scene:
    """The scene with ``stiffness = "auto"``."""
    return dataclasses.replace(scene, examples=dataclasses.replace(scene.examples,
                                                                   stiffness="auto"))


def closest_is_an_example(closest) -> bool:
    values = closest.values() if isinstance(closest, dict) else [closest]
    return all(value != "rest" for value in values)


def basis_residual(U: np.ndarray, u_full: np.ndarray, mass) -> float:
    """How much of the full run the basis misses: :func:`trajectory_error` of its
    M-orthogonal projection ``U Uᵀ M u`` on U ((3n, r), ``UᵀMU = I``)."""
    flat = u_full.reshape(u_full.shape[0], -1)
    projected = (U @ (U.T @ (mass @ flat.T))).T
    return trajectory_error(projected.reshape(u_full.shape), u_full, mass)


def trajectory_error(u: np.ndarray, u_full: np.ndarray, mass) -> float:
    """``max_t ‖u − u_full‖_M / max_t ‖u_full‖_M`` of (k, n, 3) trajectories."""
    def norms(v):
        flat = v.reshape(v.shape[0], -1)
        return np.sqrt(np.einsum("ti,ti->t", flat, (mass @ flat.T).T))
    return float(norms(u - u_full).max() / norms(u_full).max())


def measure(name: str, max_time: float) -> dict:
    given = user_scene() if name == USER else load_scene(name)
    scene = auto(given)
    steps = min(scene.simulation.steps, max(1, round(max_time / scene.simulation.dt)))
    started = time.perf_counter()
    pre = precompute(scene)
    chosen = pre.auto_stiffness
    reduced = simulate(scene, pre, method="reduced", steps=steps, influence=True)
    full = simulate(scene, pre, method="full", steps=steps)
    stats = reduced.stats
    error = held = None
    if reduced.stats["stable"] and full.stats["stable"]:
        mass = mass_matrix(pre.mesh, pre.material.density)
        error = trajectory_error(reduced.displacements, full.displacements, mass)
        held = basis_residual(pre.U, full.displacements, mass)
    return {
        "scene": name, "steps": steps, "dt": scene.simulation.dt,
        "k_ex_auto": chosen.k_ex, "k_ex_given": None if name == USER
        else float(given.examples.stiffness), "omega1_sq": chosen.omega1_sq,
        "k_over_omega1_sq": chosen.k_ex / chosen.omega1_sq, "governing": chosen.governing,
        "summary": chosen.summary(), "visible_change": stats.get("visible_change"),
        "closest_example": stats.get("closest_example"),
        "error_vs_full": error, "basis_residual": held, "r": int(stats["r"]),
        "forces": stats["forces"], "step_ms": reduced.step_median_ms,
        "stable": bool(stats["stable"] and full.stats["stable"]),
        "seconds": time.perf_counter() - started,
    }


def calibrate(name: str, factors: list[float], max_time: float) -> list[dict]:
    """The calibration of the rule's constant: reduced runs of the ``auto`` scene's
    precompute with k_ex = c · ω_e² (ω_e² of the example that sets auto's k_ex) for each
    factor c, each with its run without examples (visible change, closest example)."""
    from lbshape.scene.variants import with_stiffness

    scene = auto(user_scene() if name == USER else load_scene(name))
    steps = min(scene.simulation.steps, max(1, round(max_time / scene.simulation.dt)))
    pre = precompute(scene)
    omega2 = pre.auto_stiffness.example_omega2[pre.auto_stiffness.example]
    rows = []
    for factor in factors:
        stats = simulate(with_stiffness(scene, factor * omega2), pre, steps=steps,
                         influence=True).stats
        rows.append({"scene": name, "factor": factor, "k_ex": factor * omega2,
                     "visible_change": stats.get("visible_change"),
                     "closest_example": stats.get("closest_example"),
                     "example_distances": stats.get("example_distances")})
        print(rows[-1], flush=True)
    return rows


def passes(row: dict) -> bool:
    return bool(row["stable"] and (row["visible_change"] or 0.0) >= VISIBLE
                and closest_is_an_example(row["closest_example"])
                and row["error_vs_full"] is not None and row["error_vs_full"] <= ERROR)


def markdown(rows: list[dict], *, command: str, commit: str, date: str,
             machine: dict) -> str:
    lines = [
        "# `stiffness = \"auto\"`: visible change, closest example, reduced vs full", "",
        f"- command: `{command}`", f"- commit: {commit}", f"- date: {date}",
        f"- machine: {machine_text(machine)}",
        f"- load average when written: {machine.get('load_average')}", "",
        "Each built-in fixed scene with its `stiffness` switched to `\"auto\"`, and a user's "
        "clamped bar with one bent example and no load; the reduced run (with and without "
        "examples) and the full-space reference, the scene's steps but at most the time "
        "shown. Target: visible change ≥ 5 % of the bounding-box diagonal, closest to an "
        "example (every region), reduced within 5 % of full. \"Basis misses\": the part of the "
        "full run outside the reduced basis (the same measure as reduced vs full). The "
        "reduced step time is the median over the run's steps after warm-up, with the load "
        "average above (not a benchmark of its own: `results/table2.md` times the scenes' own "
        "settings).", "",
        "| scene | steps × dt | k_ex auto (1/s²) | × ω₁² | set by | scene's own k_ex | "
        "visible change | closest | reduced vs full | basis misses | r, forces | "
        "reduced ms / step | target |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        closest = row["closest_example"]
        if isinstance(closest, dict):
            closest = ", ".join(f"{k} → {v}" for k, v in closest.items())
        error = "—" if row["error_vs_full"] is None else f"{100 * row['error_vs_full']:.1f} %"
        held = ("—" if row.get("basis_residual") is None
                else f"{100 * row['basis_residual']:.1f} %")
        visible = ("—" if row["visible_change"] is None
                   else f"{100 * row['visible_change']:.1f} %")
        given = "—" if row["k_ex_given"] is None else f"{row['k_ex_given']:g}"
        lines.append(
            f"| {row['scene']} | {row['steps']} × {row['dt']:g} s | {row['k_ex_auto']:.4g} | "
            f"{row['k_over_omega1_sq']:.0f} | {row['governing']} | {given} | {visible} | "
            f"{closest} | {error} | {held} | {row['r']}, {row['forces']} | "
            f"{row['step_ms']:.2f} | {'met' if passes(row) else 'missed'} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> list[Path]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out-dir", type=Path, default=ROOT / "results")
    parser.add_argument("--scenes", nargs="+", default=[USER, *SCENES])
    parser.add_argument("--max-time", type=float, default=0.5,
                        help="most simulated time per run (s)")
    parser.add_argument("--calibrate", type=float, nargs="+", default=None,
                        metavar="C", help="only print reduced runs at k_ex = C × ω_e² "
                        "(the calibration of the rule's constant; writes nothing)")
    args = parser.parse_args(argv)
    if args.calibrate:
        for name in args.scenes:
            calibrate(name, args.calibrate, args.max_time)
        return []
    command = ("python scripts/bench_auto_stiffness.py " + " ".join(
        sys.argv[1:] if argv is None else argv)).strip()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                            capture_output=True, text=True).stdout.strip() or "unknown"
    rows, written = [], []
    for name in args.scenes:  # the files after each scene: a stopped run keeps its rows
        rows.append(measure(name, args.max_time))
        print(f"{name}: {rows[-1]}", flush=True)
        date = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
        machine = machine_description()
        payload = {"command": command, "commit": commit, "date": date, "machine": machine,
                   "targets": {"visible_change": VISIBLE, "error_vs_full": ERROR},
                   "rows": [{**row, "target_met": passes(row)} for row in rows]}
        written = [
            write_text_atomic(args.out_dir / "auto_stiffness.md",
                              markdown(rows, command=command, commit=commit, date=date,
                                       machine=machine)),
            write_json_atomic(args.out_dir / "auto_stiffness.json", payload),
        ]
    return written


if __name__ == "__main__":
    for path in main():
        print(path)
