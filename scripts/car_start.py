"""The car's start with its example pull: first floor contact and the error, reduced vs full.

    OMP_NUM_THREADS=1 python scripts/car_start.py [--ramp S] [--floor Z] [--steps N] [--json]

``--ramp``: ``[examples] ramp`` in s, ``--floor``: the floor's height z in m (each the
scene's own value if omitted; the car's wheels stand on z = 0). Prints, per method, the first
step with a vertex behind a plane (time, s), the deepest penetration over the first
50 ms and over the run (mm), and the trajectory errors of the reduced run against the
full one: the whole run (every step both reached), before the reference's first contact and up
to the wall (t < 0.138 s).
"""

from __future__ import annotations

import argparse
import dataclasses
import json

import numpy as np

from lbshape import load_scene, precompute
from lbshape.analysis.free_body_eval import first_contact, penetration, window_error
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.pipeline.simulate import full_simulation, reduced_simulation

WALL_S = 0.138


def _scene(ramp: float | None, floor: float | None):
    scene = load_scene("car")
    if ramp is not None:
        scene = dataclasses.replace(scene, examples=dataclasses.replace(scene.examples,
                                                                        ramp=ramp))
    if floor is not None:
        planes = tuple(dataclasses.replace(p, point=(p.point[0], p.point[1], floor))
                       if p.normal[2] > 0.5 else p for p in scene.planes)
        scene = dataclasses.replace(scene, planes=planes)
    return scene


def _run(scene, pre, method: str, steps: int):
    """(times (k,), displacements (k, n, 3), stable) of every step."""
    engine = (full_simulation(scene, pre) if method == "full"
              else reduced_simulation(scene, pre, method=method))
    record = engine.run(steps, stride=1)
    return np.asarray(record.times), engine.displacements(record), bool(record.stable)


def floor_height(scene) -> float:
    """The floor's height z (m)."""
    return next(p.point[2] for p in scene.planes if p.normal[2] > 0.5)


def _contact(scene, pre, run) -> dict:
    times, u, stable = run
    points = pre.mesh.points + u
    depth = penetration(points, scene.planes)
    first = first_contact(points, scene.planes)
    early = times <= 0.05 + 1e-12
    return {"stable": stable, "samples": int(times.size),
            "first_contact_s": None if first is None else float(times[first]),
            "max_penetration_50ms_mm": 1e3 * float(depth[early].max()),
            "max_penetration_mm": 1e3 * float(depth.max())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ramp", type=float, default=None)
    parser.add_argument("--floor", type=float, default=None)
    parser.add_argument("--steps", type=int, default=None)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    scene = _scene(args.ramp, args.floor)
    pre = precompute(scene)
    steps = scene.simulation.steps if args.steps is None else args.steps
    mass = mass_matrix(pre.mesh, pre.material.density)
    runs = {m: _run(scene, pre, m, steps) for m in ("reduced", "full")}
    out = {"ramp_s": getattr(scene.examples, "ramp", 0.0), "floor_z_m": floor_height(scene),
           "steps": steps, "dt": scene.simulation.dt}
    for method, output in runs.items():
        out[method] = _contact(scene, pre, output)
    (times, u, _), (_, uf, _) = runs["reduced"], runs["full"]
    n = min(len(u), len(uf))
    u, uf, times = u[:n], uf[:n], times[:n]
    first = first_contact(pre.mesh.points + uf, scene.planes)
    out["error_whole"] = window_error(u, uf, mass, n)
    out["error_pre_contact"] = None if first is None else window_error(u, uf, mass, first)
    out["error_to_wall"] = window_error(u, uf, mass, int(np.sum(times < WALL_S)))
    print(json.dumps(out, indent=None if args.json else 1))


if __name__ == "__main__":
    main()
