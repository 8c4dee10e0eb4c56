"""Where the Figure 4 bar's face hit with its example loses accuracy (issue 41, item 5).

Usage: ``OMP_NUM_THREADS=1 LBSHAPE_CACHE=<empty folder> .venv/bin/python
scripts/study_face_impact_oracle.py [--speed 1.5]`` (an empty cache: the ``impact-basis``
stage must run with the replaced throw, not come from the cache).

The impact columns (``reduced.impact_columns``) come from throws of the body (under its
example pull; the study was first run when the throws were of the straight bar without
it). This study replaces the face throw's frames (direction +x) by the frames in contact
of the designed face hit *with* the example (the full reference,
:func:`lbshape.studies.free_bodies.designed_impact`'s scene), builds the 26 columns, and
prints the face hits at ``--speed`` and 3 m/s with and without the
example: restitution of both methods, its relative error, the errors of the change of
linear and angular momentum and the deepest penetration.
An oracle (the hit's own frames), not a method: it locates the limit.
"""

from __future__ import annotations

import argparse

import numpy as np

import lbshape.pipeline.impact_columns as impact_columns
from lbshape.analysis.free_body_eval import penetration
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulation import Simulation
from lbshape.scene import load_scene
from lbshape.scene.variants import impact_scene, with_impact_columns
from lbshape.studies.free_bodies import IMPACT_BODY, IMPACT_FLIGHT, IMPACT_NORMALS, designed_impact

#: the columns built, as in results/impact_columns.md
COLUMNS = 26


def designed_face_frames(base, pre, speed: float) -> np.ndarray:
    """(k, n, 3) the full reference's displacements in contact in the designed face hit
    with the scene's example at ``speed`` m/s."""
    rest = pre.mesh.points
    scene = impact_scene(base, rest, IMPACT_NORMALS["face"], speed, speed * IMPACT_FLIGHT,
                         "face-oracle")
    full = Simulation(scene, pre, method="full")
    u = full.displacements(full.run(200))
    return u[penetration(rest[None] + u, scene.planes) > 0.0]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--speed", type=float, default=1.5)
    args = parser.parse_args(argv)
    base = load_scene(IMPACT_BODY)
    frames = designed_face_frames(base, precompute(base), args.speed)
    face = np.asarray(IMPACT_NORMALS["face"], dtype=float)
    face /= np.linalg.norm(face)
    original = impact_columns.throw

    def throw(scene, mesh, direction, speed, examples=None):
        if np.allclose(np.asarray(direction, dtype=float), face, atol=1e-6):
            return frames
        return original(scene, mesh, direction, speed, examples)

    impact_columns.throw = throw
    scene = with_impact_columns(base, COLUMNS)
    pre = precompute(scene)
    print(f"face throw replaced by {frames.shape[0]} frames of the designed hit with the "
          f"example at {args.speed:g} m/s")
    for speed in sorted({args.speed, 3.0}):
        for examples in (True, False):
            row = designed_impact(scene, pre, "face", speed, examples=examples).stats()
            print(f"face {speed:g} m/s, examples {examples}: restitution full "
                  f"{row['restitution_full']:.4f} reduced {row['restitution_reduced']:.4f} "
                  f"(error {100 * row['restitution_error']:.1f} %), Δp error "
                  f"{100 * row['delta_p_error']:.1f} %, ΔL error "
                  f"{100 * row['delta_L_error']:.1f} %, deepest "
                  f"{row['depth_full_mm']:.2f} / {row['depth_reduced_mm']:.2f} mm")


if __name__ == "__main__":
    main()
