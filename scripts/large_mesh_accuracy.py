"""The reduced force models' error against the full reference above the polynomial limit.

Usage: ``.venv/bin/python scripts/large_mesh_accuracy.py [--sizes H ...] [--steps N]
[--out-dir results]`` (default: the bar-cylinder scene's object at h = 0.0665 m, about
330 vertices, and h = 0.0185 m, about 6.7k vertices and 31.6k tetrahedra, 300 steps).

``reduced.forces = "auto"`` keeps the cubature for a mesh whose polynomial build exceeds
:data:`~lbshape.elastic.polynomial_forces.POLYNOMIAL_BUILD_FLOPS` (7 t P² multiply-adds,
P = r(r+1)/2): at r = 32 about 30.8k tetrahedra, so h = 0.0185 m is the first size of the
scaling sweep (``results/scaling.md``) where ``auto`` picks the cubature. At each size the
scene (:func:`lbshape.scene.variants.scaled_scene`, the bar-cylinder's examples, loads,
m, r, s) is precomputed twice from scratch, with the cubature and with the exact
polynomial forces (``reduced.forces`` asked explicitly; the same basis: the force stage
comes last), and run for ``steps`` steps with each and with the full-space reference.
Error: :func:`lbshape.pipeline.simulate.run_error` (Table 2's
``max_t ‖u − u_full‖_M / max_t ‖u_full‖_M`` and the final-frame ratio). The runs (not the
precomputes) hold an exclusive ``flock`` on ``--lock`` (default: none), the shared timing
lock, so that one timing runs at a time. Writes ``large_mesh_accuracy.md`` and
``large_mesh_accuracy.json``.
"""

from __future__ import annotations

import os

if __name__ == "__main__":  # single-threaded BLAS for the timings, set before numpy loads
    for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import argparse
import contextlib
import dataclasses
import datetime
import fcntl
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from lbshape.elastic.polynomial_forces import POLYNOMIAL_BUILD_FLOPS, polynomial_build_flops
from lbshape.io.atomic import write_json_atomic, write_text_atomic
from lbshape.io.machine import load_text, machine_description, machine_text
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import run_error, simulate
from lbshape.scene import load_scene
from lbshape.scene.variants import scaled_scene

SCENE = "bar-cylinder"
SIZES = (0.0665, 0.0185)
STEPS = 300
MODELS = ("cubature", "polynomial")


def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


@contextlib.contextmanager
def _held(lock: str | None):
    """An exclusive ``flock`` on ``lock`` (the shared timing lock) while the body runs."""
    if lock is None:
        yield
        return
    with open(lock, "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def measure_size(size: float, steps: int, folder: Path, lock: str | None) -> dict:
    """Precompute one size with both force models, run both and the full reference."""
    base = load_scene(scaled_scene(SCENE, size, folder))
    pres, builds = {}, {}
    for model in MODELS:
        scene = dataclasses.replace(base, reduced=dataclasses.replace(base.reduced,
                                                                      forces=model))
        started = time.perf_counter()
        pres[model] = precompute(scene, force=True, save=False)
        builds[model] = time.perf_counter() - started
        print(f"h={size:g}: precompute ({model}) {builds[model]:.1f} s", file=sys.stderr)
    pre = pres["cubature"]
    basis_gap = float(np.max(np.abs(pres["polynomial"].U - pre.U)))
    runs = {}
    with _held(lock):
        for model in MODELS:
            scene = dataclasses.replace(base, reduced=dataclasses.replace(base.reduced,
                                                                          forces=model))
            runs[model] = simulate(scene, pres[model], steps=steps)
        full = simulate(base, pre, method="full", steps=steps)
        load = machine_description()["load_average"]
    row = {"size_m": size, "n_vertices": pre.mesh.n_vertices, "n_tets": pre.mesh.n_tets,
           "r": int(pre.r), "m": base.reduced.m,
           "s": int(pre.elastic.cubature_elements.size), "steps": steps,
           "dt": base.simulation.dt, "basis_max_difference": basis_gap,
           "auto_picks": "polynomial" if polynomial_build_flops(pre.mesh.n_tets, pre.r)
           <= POLYNOMIAL_BUILD_FLOPS else "cubature",
           "polynomial_build_flops": polynomial_build_flops(pre.mesh.n_tets, pre.r),
           "full_t_total_ms": full.stats["t_total_ms"], "load_after_runs": load}
    for model in MODELS:
        error = run_error(runs[model], full, pre) or {}
        row[model] = {
            "error_vs_full": error.get("error_vs_full"),
            "final_error_vs_full": error.get("final_error_vs_full"),
            "t_total_ms": runs[model].stats["t_total_ms"],
            "precompute_s": builds[model],
            "forces_stage_s": pres[model].stages.seconds.get("forces"),
            "cubature_stage_s": pres[model].stages.seconds.get("cubature")}
    return row


def _pct(value) -> str:
    return "—" if value is None else f"{100 * value:.2f} %"


def markdown(rows: list[dict], info: dict) -> str:
    lines = [
        "# Reduced force models against the full reference above the polynomial limit",
        "",
        f"Scene: the built-in {SCENE} (its examples, material, gravity and the ramped "
        "torque of 100 N m over 0.3 s; m, r, s of each size's precompute) with "
        "`[object] size` = h; each size precomputed from scratch twice, with "
        "`reduced.forces = \"cubature\"` and `\"polynomial\"` (the same basis: max |ΔU| in "
        "the table), and run for the steps shown with each and with the full-space "
        "reference (modified Newton, one Cholesky factor reused). `auto` picks the "
        f"polynomials while 7 t P² ≤ {POLYNOMIAL_BUILD_FLOPS:.0e} multiply-adds "
        "(P = r(r+1)/2). Error: Table 2's `max_t ‖u − u_full‖_M / max_t ‖u_full‖_M`; "
        "final: the same ratio at the last frame. ms per step: mean after the warm-up, "
        "all runs of a size one after another in one process.",
        "",
        f"Command: `{info['command']}`  ",
        f"Commit: `{info['commit']}`, {info['date']}  ",
        f"Machine: {machine_text(info['machine'])}; load average "
        f"{load_text(info['machine'])} at the end",
        "",
        "| h (m) | vertices | tets | r | s | steps | auto picks | error, cubature | "
        "error, polynomial | final error, cubature / polynomial | ms/step cubature / "
        "polynomial / full | forces stage (s) | max \\|ΔU\\| |",
        "|---|---:|---:|---:|---:|---:|---|---:|---:|---|---|---:|---:|",
    ]
    for row in rows:
        cub, poly = row["cubature"], row["polynomial"]
        lines.append(
            f"| {row['size_m']:g} | {row['n_vertices']} | {row['n_tets']} | {row['r']} "
            f"| {row['s']} | {row['steps']} | {row['auto_picks']} "
            f"| {_pct(cub['error_vs_full'])} | {_pct(poly['error_vs_full'])} "
            f"| {_pct(cub['final_error_vs_full'])} / {_pct(poly['final_error_vs_full'])} "
            f"| {cub['t_total_ms']:.3f} / {poly['t_total_ms']:.3f} / "
            f"{row['full_t_total_ms']:.1f} | {poly['forces_stage_s'] or 0.0:.1f} "
            f"| {row['basis_max_difference']:.1e} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=float, nargs="+", default=list(SIZES))
    parser.add_argument("--steps", type=int, default=STEPS)
    parser.add_argument("--out-dir", type=Path, default=Path("results"))
    parser.add_argument("--lock", default=None,
                        help="a file to hold an exclusive flock on during the timed runs")
    args = parser.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory(prefix="lbshape-large-mesh-") as folder:
        for size in args.sizes:
            rows.append(measure_size(size, args.steps, Path(folder), args.lock))
            print(rows[-1], file=sys.stderr)
    command = "python scripts/large_mesh_accuracy.py " + " ".join(
        sys.argv[1:] if argv is None else argv)
    info = {"command": command.strip(), "commit": _commit(), "machine": machine_description(),
            "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")}
    args.out_dir.mkdir(parents=True, exist_ok=True)
    write_json_atomic(args.out_dir / "large_mesh_accuracy.json", {**info, "rows": rows})
    write_text_atomic(args.out_dir / "large_mesh_accuracy.md", markdown(rows, info))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
