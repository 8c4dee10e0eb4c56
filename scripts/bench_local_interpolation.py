"""Interpolation speed and target error of a local-examples scene (default teddy-local).

Usage: ``.venv/bin/python scripts/bench_local_interpolation.py [SCENE] [--label NAME]
[--steps N] [--repeats K] [--out-dir results]``.

Measures, in one process and one thread:

* ``full``, ``euclidean`` and ``reduced`` side by side
  (:func:`lbshape.studies.bench.bench_scene`, the measurement of ``lbshape bench``):
  per-step t_interp and t_total (medians over repeats, warm-up excluded), the
  interpolation speed-up euclidean / reduced and each method's error vs ``full``;
* the reduced method's **target error on every call** of a run: for each step's
  state q and each region, the target the run used (``solver.solve(w)`` of the
  region's runtime driver, at the weights of q) against the exact target (Newton on
  the region's exact example energies to 1e-12), ``‖Δc‖`` (= ``‖L_R Δc‖_{M_R}``,
  Φ_R being M_R-orthonormal) as a share of the region's example separation
  ``max_ij ‖c_i − c_j‖``; maximum and median over all calls and regions.

The numbers are stored under ``--label`` in ``local_interpolation.json`` (other labels
kept, so a run of the code before a change and one after sit side by side) and
``local_interpolation.md`` is written from all stored labels.
"""

from __future__ import annotations

import os

if __name__ == "__main__":  # single-threaded BLAS for the timings, set before numpy loads
    for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import argparse
import json
import logging
from pathlib import Path

import numpy as np

from lbshape.io.atomic import write_json_atomic, write_text_atomic
from lbshape.io.machine import load_text, machine_description, machine_text
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import WARMUP_STEPS, reduced_simulation
from lbshape.scene import load_scene
from lbshape.shapespace.interpolation import TargetSolver
from lbshape.shapespace.local_driver import region_energy_models
from lbshape.studies.bench import DEFAULT_OUT, bench_scene

log = logging.getLogger(__name__)

#: Newton settings of the exact targets the runtime targets are compared with
EXACT_TOLERANCE = 1e-12
EXACT_ITERATIONS = 100
#: the interpolation speed-up and target error aimed at
TARGET_SPEEDUP = 20.0
TARGET_ERROR = 0.02
#: a weight above this counts as non-zero (weights strictly inside a simplex face)
INTERIOR = 1e-9


_INTRO = (
    "Written by `scripts/bench_local_interpolation.py` (one row per stored measurement, "
    "e.g. the code before and after a change). Per-step times in ms are medians over "
    "repeats of the per-step means after the warm-up steps, `full`, `euclidean` and "
    "`reduced` interleaved in one process (`lbshape.studies.bench.bench_scene`, as "
    "`lbshape bench`); error vs full `max_t ‖u(t) − u_full(t)‖_M / max_t ‖u_full(t)‖_M`. "
    "Target error: on every step of a reduced run, per region, the target the run used "
    "against the exact target (Newton to 1e-12 on the region's exact example energies) at "
    "the same weights, `‖Δc‖` over the region's example separation `max_ij ‖c_i − c_j‖`. "
    "Where a region's weights sit at one example (a vertex of its simplex) a table returns "
    "the exact target of its node; the last column counts the calls between examples and "
    "their largest error, and the tables' own check at held-out interior weights is under "
    "Conditions."
)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", nargs="?", default="teddy-local")
    parser.add_argument("--label", default="current", help="name of this measurement")
    parser.add_argument("--steps", type=int, default=None, help="default: the scene's")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out-dir", type=Path, default=DEFAULT_OUT)
    return parser.parse_args(argv)


def target_errors(scene, pre, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Along a reduced run, per call and region: the runtime target's error over the example
    separation (calls, regions), and whether the weights lay inside the simplex (not at
    an example, where a table holds the exact target at its node)."""
    sim = reduced_simulation(scene, pre)
    driver = sim.driver
    states = np.asarray(sim.run(steps).states)[:-1]  # the state each step started from
    exact, separations = [], []
    for region in pre.local.regions:
        k = region.example_coefficients.shape[0]
        offsets = region.example_coefficients.reshape(k, -1)
        models = region_energy_models(pre.mesh, pre.material, region, route="lb-exact")
        exact.append(TargetSolver(models, offsets, tolerance=EXACT_TOLERANCE,
                                  max_iterations=EXACT_ITERATIONS))
        separations.append(max(np.linalg.norm(a - b) for a in offsets for b in offsets))
    errors = np.zeros((len(states), len(exact)))
    interior = np.zeros(errors.shape, dtype=bool)
    for i, q in enumerate(states):
        for j, (region_driver, solver) in enumerate(zip(driver.drivers, exact, strict=True)):
            w = region_driver.weights(q)
            interior[i, j] = np.count_nonzero(w > INTERIOR) > 1
            used = region_driver.solver.solve(w).z
            result = solver.solve(w, start=used)
            if not result.converged:
                raise RuntimeError(f"exact target of region {j} did not converge at w={w}")
            errors[i, j] = np.linalg.norm(used - result.z) / separations[j]
    return errors, interior


def measure(scene_name: str, *, steps: int | None, repeats: int) -> dict:
    scene = load_scene(scene_name)
    pre = precompute(scene)
    steps = scene.simulation.steps if steps is None else steps
    bench = bench_scene(scene, steps=steps, repeats=repeats, pre=pre, influence=False,
                        methods=("full", "euclidean", "reduced"))
    rows = {method: bench.row(method) for method in ("full", "euclidean", "reduced")}
    errors, interior = target_errors(scene, pre, steps)
    tables = [None if region.table is None or region.table.check is None
              else region.table.check.max_error
              for region in pre.local.regions] if hasattr(
                  pre.local.regions[0], "table") else []
    return {
        "scene": scene.name, "steps": steps, "repeats": repeats, "warmup_steps": WARMUP_STEPS,
        "methods": {method: {key: row[key] for key in ("t_interp_ms", "t_total_ms",
                                                        "error_vs_full")}
                    for method, row in rows.items()},
        "speedup_interp": rows["euclidean"]["t_interp_ms"] / rows["reduced"]["t_interp_ms"],
        "speedup_total": rows["euclidean"]["t_total_ms"] / rows["reduced"]["t_total_ms"],
        "target_error_max": float(errors.max()),
        "target_error_median": float(np.median(errors)),
        "target_error_calls": int(errors.size),
        "target_error_interior_calls": int(interior.sum()),
        "target_error_interior_max": float(errors[interior].max()) if interior.any() else None,
        "target_error_max_per_region": dict(zip(
            (region.name for region in pre.local.regions), errors.max(axis=0).tolist(),
            strict=True)),
        "precompute_table_errors": tables,
        "machine": machine_description(),
    }


def markdown(entries: dict) -> str:
    """``local_interpolation.md`` from the stored measurements (label -> entry)."""
    lines = [
        "# Local examples: interpolation speed and target error", "",
        _INTRO, "",
        "| label | scene | steps × repeats | euclidean t_interp (ms) | reduced t_interp (ms) "
        "| speed-up interp | euclidean t_total (ms) | reduced t_total (ms) | full t_total (ms) "
        "| reduced error vs full | euclidean error vs full | target error max / median "
        "(share of separation, calls) | calls between examples, their max error |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for label, e in entries.items():
        m = e["methods"]
        lines.append(
            f"| {label} | {e['scene']} | {e['steps']} × {e['repeats']} "
            f"| {m['euclidean']['t_interp_ms']:.3f} | {m['reduced']['t_interp_ms']:.4f} "
            f"| {e['speedup_interp']:.1f}× | {m['euclidean']['t_total_ms']:.3f} "
            f"| {m['reduced']['t_total_ms']:.3f} | {m['full']['t_total_ms']:.2f} "
            f"| {_percent(m['reduced']['error_vs_full'])} "
            f"| {_percent(m['euclidean']['error_vs_full'])} "
            f"| {100 * e['target_error_max']:.2g} % / {100 * e['target_error_median']:.2g} % "
            f"({e['target_error_calls']}) | {e['target_error_interior_calls']}, "
            f"{_share(e['target_error_interior_max'])} |")
    lines += ["", "## Targets (reported, not enforced)", ""]
    for label, e in entries.items():
        speed, error = e["speedup_interp"], e["target_error_max"]
        lines.append(
            f"- {label}: interpolation speed-up {speed:.1f}× "
            f"({'met' if speed >= TARGET_SPEEDUP else 'missed'}, target ≥ {TARGET_SPEEDUP:g}×); "
            f"largest target error {100 * error:.2g} % of the example separation "
            f"({'met' if error <= TARGET_ERROR else 'missed'}, target ≤ {100 * TARGET_ERROR:g} %).")
    lines += ["", "## Conditions", ""]
    for label, e in entries.items():
        per_region = ", ".join(f"{name} {100 * v:.2g} %"
                               for name, v in e["target_error_max_per_region"].items())
        tables = e["precompute_table_errors"]
        checked = ("no per-region tables" if not tables or all(t is None for t in tables) else
                   "precompute table check (max, share of separation): " + ", ".join(
                       "—" if t is None else f"{100 * t:.2g} %" for t in tables))
        lines.append(f"- {label}: {machine_text(e['machine'])}; load average "
                     f"{load_text(e['machine'])}; largest target error per region "
                     f"{per_region}; {checked}.")
    return "\n".join(lines) + "\n"


def _share(value) -> str:
    return "—" if value is None else f"{100 * value:.2g} %"


def _percent(value) -> str:
    return "—" if value is None else f"{100 * value:.1f} %"


def main(argv: list[str] | None = None) -> list[Path]:
    args = parse_args(argv)
    entry = measure(args.scene, steps=args.steps, repeats=args.repeats)
    path_json = args.out_dir / "local_interpolation.json"
    entries = json.loads(path_json.read_text()) if path_json.exists() else {}
    entries[args.label] = entry
    return [write_json_atomic(path_json, entries),
            write_text_atomic(args.out_dir / "local_interpolation.md", markdown(entries))]


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(message)s", force=True)
    for noisy in ("ffcx", "UFL", "FFCx"):
        logging.getLogger(noisy).setLevel(logging.WARNING)
    for path in main():
        print(path)
