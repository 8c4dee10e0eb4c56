"""The car's free-body evaluation (:func:`lbshape.studies.free_bodies.evaluate_scene`: the
error before the first contact, the whole-trajectory error and the reference's noise floor)
with a given example ramp and floor height; JSON on stdout.

    OMP_NUM_THREADS=1 python scripts/car_start_eval.py [--ramp S] [--floor Z] [--steps N]
"""

from __future__ import annotations

import argparse
import json

from car_start import _scene, floor_height

from lbshape import precompute
from lbshape.studies.free_bodies import evaluate_scene


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ramp", type=float, default=None)
    parser.add_argument("--floor", type=float, default=None)
    parser.add_argument("--steps", type=int, default=None)
    args = parser.parse_args()
    scene = _scene(args.ramp, args.floor)
    runs = evaluate_scene(scene, precompute(scene), steps=args.steps)
    print(json.dumps({"ramp_s": scene.examples.ramp, "floor_z_m": floor_height(scene),
                      "runs": [run.stats() for run in runs]}, indent=1))


if __name__ == "__main__":
    main()
