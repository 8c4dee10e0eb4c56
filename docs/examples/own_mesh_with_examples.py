"""Your own mesh, built in code, with two example poses given in code: examples on vs off.

    python docs/examples/own_mesh_with_examples.py [--steps 200]

No file is read or written apart from the precompute's cache.
"""

import argparse

import numpy as np

import lbshape
from lbshape.geometry.primitives import structured_box

parser = argparse.ArgumentParser(description="A bar built in code, examples on and off.")
parser.add_argument("--steps", type=int, default=200)
args = parser.parse_args()

# 1. The mesh: any TetMesh, or (points (n, 3) m, tets (t, 4)) arrays. Here a 20 cm bar
#    along x made of 10 x 2 x 2 cubes of 6 tetrahedra each.
bar = structured_box(size=(0.2, 0.04, 0.04), divisions=(10, 2, 2))
points, tets = bar.points, bar.tets

# 2. Two example poses from code: an analytic twist of the bar's own mesh (poses of
#    lbshape.geometry.poses: twist, arc, s-bend), and a posed copy of it (its points bent
#    by hand, the same tetrahedra).
bent = points.copy()
bent[:, 2] -= 1.5 * points[:, 0] ** 2  # the free end 6 cm down
examples = [{"pose": "twist", "parameters": {"angle": 1.0, "axis": "x", "anchor": "min"}},
            bent]

# 3. The scene: the end x = 0 held, gravity, the example force k_ex (1/s^2).
scene = lbshape.Scene.from_mesh(
    (points, tets), name="my-bar", fixed="x < 1e-6",
    material={"young": 2e5, "poisson": 0.3, "density": 1000.0},
    damping={"beta": 0.01}, reduced={"m": 6, "r": 12, "s": 30},
    examples=examples, example_stiffness=500.0,
    loads=[{"type": "gravity", "vector": [0.0, 0.0, -9.81]}], dt=0.005)
pre = lbshape.precompute(scene)  # computed once, then read from the cache

# 4. The same run twice: with the example force, then without it from the same start.
sim = lbshape.simulation(scene, pre)
start = sim.state
sim.run(args.steps)
with_examples = sim.displacement()
sim.reset(start)
sim.set_examples(False)
sim.run(args.steps)
without = sim.displacement()

# 5. The visible change: how far the examples moved the bar, against how far it moved.
tip = np.flatnonzero(points[:, 0] > 0.2 - 1e-6)
change = np.linalg.norm(with_examples - without, axis=1)
print(f"t = {sim.time:.3f} s, {pre.mesh.n_vertices} vertices, r = {pre.r}")
print(f"tip sag without examples: {1e3 * -without[tip, 2].mean():.2f} mm, "
      f"with examples: {1e3 * -with_examples[tip, 2].mean():.2f} mm")
print(f"examples move the bar by up to {1e3 * change.max():.2f} mm "
      f"({change.max() / np.linalg.norm(without, axis=1).max():.0%} of its largest displacement)")
