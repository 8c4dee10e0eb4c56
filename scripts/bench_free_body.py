"""Measure the free-body step against real time and write ``free_body_step.md`` / ``.json``.

Usage: ``.venv/bin/python scripts/bench_free_body.py [SCENE ...] [--steps N] [--repeats K]
[--out-dir results]`` (default scenes: car, bar-s-cuboid, bar-s-cylinder, the paper's
free bodies, at their own m, r, s).

Per scene (:func:`lbshape.studies.bench.bench_scene`): ``full`` and ``reduced`` once for the
error vs ``full`` (both deterministic), then ``reduced`` alone ``--repeats`` times for the
times; then, ``--repeats`` times, the body on the floor after its bounces
(:func:`resting_step`: the steps from 1.5 s to 2.5 s, each timed). Writes, atomically
(:func:`lbshape.studies.realtime.write_free_body_step`), the reduced step's median wall
time per step, its parts, the error and the resting step. Single-threaded.
"""

from __future__ import annotations

import os

if __name__ == "__main__":  # single-threaded BLAS for the timings, set before numpy loads
    for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import argparse
import dataclasses
import logging
import time
from pathlib import Path

import numpy as np

from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulation import simulation
from lbshape.scene import load_scene
from lbshape.studies.bench import DEFAULT_OUT, bench_scene
from lbshape.studies.realtime import write_free_body_step

log = logging.getLogger(__name__)

#: the paper's free bodies (Figures 4 and 5)
FREE_SCENES = ("car", "bar-s-cuboid", "bar-s-cylinder")
#: the resting window (s): every built-in free body is on the floor after its bounces
REST_WINDOW = (1.5, 2.5)


def resting_step(scene, pre, repeats: int) -> dict:
    """The reduced step of the body on the floor: ``repeats`` runs to the start of
    :data:`REST_WINDOW`, then its steps timed one by one. Returns the median over the runs
    of the median and the mean ms per step, the sweeps and passes per step, the share of
    steps that end touching a plane and the centre's drift (m/s): the distance between
    the window's ends over its length."""
    medians, means, sweeps, passes, touching, drift = [], [], [], [], [], []
    for _ in range(repeats):
        sim = simulation(scene, pre, method="reduced")
        engine = sim.engine
        first, last = (round(t / sim.dt) for t in REST_WINDOW)
        for _ in range(first):
            sim.step()
        start_center, start_sweeps = engine.rigid.center.copy(), engine.total_sweeps
        times, substeps, contact = np.empty(last - first), 0, 0
        for k in range(last - first):
            started = time.perf_counter()
            sim.step()
            times[k] = time.perf_counter() - started
            substeps += engine.substeps
            contact += engine.contact.scalars[1] > 0
        medians.append(1e3 * float(np.median(times)))
        means.append(1e3 * float(times.mean()))
        sweeps.append((engine.total_sweeps - start_sweeps) / times.size)
        passes.append(substeps / times.size)
        touching.append(contact / times.size)
        drift.append(float(np.linalg.norm(engine.rigid.center - start_center))
                     / (REST_WINDOW[1] - REST_WINDOW[0]))
    return {"scene": scene.name, "window_s": list(REST_WINDOW), "repeats": repeats,
            "median_ms": float(np.median(medians)), "median_ms_range": [min(medians),
                                                                      max(medians)],
            "mean_ms": float(np.median(means)), "sweeps_per_step": float(np.median(sweeps)),
            "passes_per_step": float(np.median(passes)),
            "touching_share": float(np.median(touching)),
            "center_drift": float(np.median(drift))}


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="*", default=list(FREE_SCENES))
    parser.add_argument("--steps", type=int, default=None, help="default: each scene's")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out-dir", type=Path, default=DEFAULT_OUT)
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> tuple[Path, Path]:
    """Run the measurement; return the two paths written."""
    args = parse_args(argv)
    results, resting = [], []
    for name in args.scenes:
        log.info("free-body step: %s", name)
        scene = load_scene(name)
        pre = precompute(scene)
        accuracy = bench_scene(scene, steps=args.steps, repeats=1, pre=pre,
                               methods=("full", "reduced"), influence=False)
        timed = bench_scene(scene, steps=args.steps, repeats=args.repeats, pre=pre,
                            methods=("reduced",), influence=False)
        results.append(dataclasses.replace(timed, rows=(accuracy.row("reduced"),)))
        resting.append(resting_step(scene, pre, args.repeats))
    return write_free_body_step(results, args.out_dir, resting=resting)


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    for path in main():
        print(path)
