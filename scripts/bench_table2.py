"""Regenerate Table 2 and the speed-versus-error sweep.

Usage: ``.venv/bin/python scripts/bench_table2.py [SCENE ...] [--steps N] [--repeats K]
[--sweep-scene NAME] [--sweep-r 10,20,30] [--sweep-s 20,60,120] [--sweep-m 6,14]
[--sweep-steps N] [--no-sweep] [--out-dir results]``.

Writes (atomically, via :mod:`lbshape.studies.tables`):

* ``table2.md`` and ``table2.json``: ``full``, ``euclidean`` and ``reduced`` side by
  side on each scene (default: bar-cuboid, bar-cylinder) — per-step times (median
  and range over repeats, warm-up excluded), speed-ups, error vs ``full``;
* ``step_breakdown.md`` and ``.json``: the reduced method with 1, 2 and converged
  Newton updates per step (error vs full, difference to converged, time and the
  parts of a step);
* ``speed_vs_error.csv`` and ``.png``: the reduced method's per-step time against
  its error vs ``full`` on the sweep scene (default bar-cuboid) for r × s (and m).
"""

from __future__ import annotations

import os

if __name__ == "__main__":  # single-threaded BLAS for the timings, set before numpy loads
    for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import argparse
import logging
from pathlib import Path

from lbshape.io.atomic import write_json_atomic, write_text_atomic
from lbshape.io.machine import machine_description
from lbshape.pipeline.precompute import precompute
from lbshape.scene import load_scene
from lbshape.studies.bench import (
    DEFAULT_OUT,
    DEFAULT_SCENES,
    bench_scene,
    paper_setting,
)
from lbshape.studies.realtime import (
    PAPER_TABLE2,
    newton_study,
    newton_study_markdown,
    newton_study_payload,
)
from lbshape.studies.sweep import speed_error_sweep
from lbshape.studies.tables import write_sweep, write_table2

log = logging.getLogger(__name__)

#: steps of the sweep runs (0.5 s at dt = 1 ms: the 0.3 s torque ramp and its response)
SWEEP_STEPS = 500


def _integers(text: str) -> tuple[int, ...]:
    return tuple(int(v) for v in text.split(",") if v.strip())


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="*", default=list(DEFAULT_SCENES))
    parser.add_argument("--steps", type=int, default=None, help="default: each scene's")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--sweep-scene", default="bar-cuboid")
    parser.add_argument("--sweep-r", type=_integers, default=(10, 20, 30))
    parser.add_argument("--sweep-s", type=_integers, default=(20, 60, 120))
    parser.add_argument("--sweep-m", type=_integers, default=(6, 14))
    parser.add_argument("--sweep-steps", type=int, default=SWEEP_STEPS)
    parser.add_argument("--sweep-repeats", type=int, default=3)
    parser.add_argument("--no-sweep", action="store_true")
    parser.add_argument("--newton-steps", type=int, default=None,
                        help="steps of the Newton-updates study (default: --steps)")
    parser.add_argument("--no-newton", action="store_true",
                        help="skip the Newton-updates study (step_breakdown.md)")
    parser.add_argument("--out-dir", type=Path, default=DEFAULT_OUT)
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> list[Path]:
    """Run the benchmark and the sweep; return the paths written."""
    args = parse_args(argv)
    results = []
    for name in args.scenes:
        scene = load_scene(name)
        log.info("table 2: %s", name)
        results.append(bench_scene(scene, steps=args.steps, repeats=args.repeats,
                                   paper=paper_setting(scene, PAPER_TABLE2)))
    paths = list(write_table2(results, args.out_dir))
    if not args.no_newton:
        studies = {}
        for name in args.scenes:
            scene = load_scene(name)
            steps = args.newton_steps or args.steps or scene.simulation.steps
            log.info("Newton updates per step: %s", name)
            studies[scene.name] = newton_study(scene, precompute(scene), steps=steps,
                                               repeats=args.repeats)
        paths.append(write_text_atomic(
            args.out_dir / "step_breakdown.md",
            newton_study_markdown(studies, steps=steps, repeats=args.repeats,
                                  machine=machine_description())))
        paths.append(write_json_atomic(args.out_dir / "step_breakdown.json",
                                       newton_study_payload(studies)))
    if not args.no_sweep:
        scene = load_scene(args.sweep_scene)
        log.info("sweep: %s", scene.name)
        points = speed_error_sweep(
            scene, r_values=args.sweep_r, s_values=args.sweep_s, m_values=args.sweep_m,
            steps=args.sweep_steps, repeats=args.sweep_repeats,
            forces=("polynomial", "cubature"),
        )
        paths += write_sweep(points, args.out_dir, scene=scene.name, steps=args.sweep_steps,
                             repeats=args.sweep_repeats, dt=scene.simulation.dt)
    return paths


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(message)s", force=True)
    for noisy in ("ffcx", "UFL", "FFCx"):
        logging.getLogger(noisy).setLevel(logging.WARNING)
    for path in main():
        print(path)
