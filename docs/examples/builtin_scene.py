"""A built-in scene through the public API: load it, precompute it, run it, read it.

    python docs/examples/builtin_scene.py            # the demo scene, its own 300 steps
    python docs/examples/builtin_scene.py --scene bar-cuboid --steps 100
"""

import argparse

import numpy as np

import lbshape

parser = argparse.ArgumentParser(description="Run a built-in scene with the reduced method.")
parser.add_argument("--scene", default="demo", help="a built-in scene name or a .toml path")
parser.add_argument("--steps", type=int, default=None, help="default: the scene's own")
args = parser.parse_args()

# 1. The scene: everything about the object (mesh, material, fixed region), its examples,
#    loads and time step, validated. Built-in names: lbshape.scene.builtin_scene_names().
scene = lbshape.load_scene(args.scene)
print(f"{scene.name}: {scene.description}")

# 2. The precompute: LB spectrum, reduced basis U (3n, r), reduced forces and examples.
#    The first call computes it (seconds for the demo) and stores it in the cache
#    ($LBSHAPE_CACHE, else ~/.cache/lbshape); later calls read it back.
pre = lbshape.precompute(scene)
print(f"mesh: {pre.mesh.n_vertices} vertices, {pre.mesh.n_tets} tets; basis r = {pre.r}"
      f" ({'from the cache' if pre.stages.from_cache else 'computed'})")

# 3. A simulation with the paper's reduced method ("euclidean" and "full" drive the same way).
sim = lbshape.simulation(scene, pre, method="reduced")
steps = args.steps or scene.simulation.steps
for _ in range(steps):
    sim.step()  # one step of dt; returns its Newton iterations

# 4. The result: the (n, 3) world displacement of every vertex, in metres.
u = sim.displacement()
size = np.linalg.norm(u, axis=1)
tip = int(size.argmax())
print(f"t = {sim.time:.3f} s after {steps} steps of {sim.dt:g} s")
print(f"largest displacement: {1e3 * size[tip]:.2f} mm at vertex {tip} "
      f"(rest {np.round(pre.mesh.points[tip], 3).tolist()} m)")
print(f"mean displacement: {1e3 * size.mean():.2f} mm")
