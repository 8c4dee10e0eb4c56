"""Measure the free-body step against real time and write ``free_body_step.md`` / ``.json``.

Usage: ``.venv/bin/python scripts/bench_free_body.py [SCENE ...] [--steps N] [--repeats K]
[--out-dir results]`` (default scenes: car, bar-s-cuboid, bar-s-cylinder, the paper's
free bodies, at their own m, r, s).

Per scene (:func:`lbshape.studies.bench.bench_scene`): ``full`` and ``reduced`` once for the
error vs ``full`` (both deterministic), then ``reduced`` alone ``--repeats`` times for the
times; writes, atomically (:func:`lbshape.studies.realtime.write_free_body_step`), the
reduced step's median wall time per step, its parts and the error. Single-threaded.
"""

from __future__ import annotations

import os

if __name__ == "__main__":  # single-threaded BLAS for the timings, set before numpy loads
    for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import argparse
import dataclasses
import logging
from pathlib import Path

from lbshape.pipeline.precompute import precompute
from lbshape.scene import load_scene
from lbshape.studies.bench import DEFAULT_OUT, bench_scene
from lbshape.studies.realtime import write_free_body_step

log = logging.getLogger(__name__)

#: the paper's free bodies (Figures 4 and 5)
FREE_SCENES = ("car", "bar-s-cuboid", "bar-s-cylinder")


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
    results = []
    for name in args.scenes:
        log.info("free-body step: %s", name)
        scene = load_scene(name)
        pre = precompute(scene)
        accuracy = bench_scene(scene, steps=args.steps, repeats=1, pre=pre,
                               methods=("full", "reduced"), influence=False)
        timed = bench_scene(scene, steps=args.steps, repeats=args.repeats, pre=pre,
                            methods=("reduced",), influence=False)
        results.append(dataclasses.replace(timed, rows=(accuracy.row("reduced"),)))
    return write_free_body_step(results, args.out_dir)


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    for path in main():
        print(path)
