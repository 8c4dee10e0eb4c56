"""The reduced method against the full-space reference: relative error over time, plotted.

    python docs/examples/reduced_vs_full.py [OUT_DIR] [--scene demo] [--steps 300]

Writes OUT_DIR/reduced_vs_full.png (default: a new temporary folder) and prints its path.
"""

import argparse
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only, no window
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import lbshape  # noqa: E402

parser = argparse.ArgumentParser(description="Reduced vs full: error over time.")
parser.add_argument("out", nargs="?", type=Path, default=None, help="folder for the PNG")
parser.add_argument("--scene", default="demo")
parser.add_argument("--steps", type=int, default=None, help="default: the scene's own")
args = parser.parse_args()
out = args.out or Path(tempfile.mkdtemp(prefix="lbshape-example-"))
out.mkdir(parents=True, exist_ok=True)

# 1. One scene, one precompute, two methods.
scene = lbshape.load_scene(args.scene)
pre = lbshape.precompute(scene)
steps = args.steps or scene.simulation.steps

# 2. Each method's run: a RunRecord (times (f,) s), its sampled displacements (f, n, 3) m.
runs = {}
for method in ("reduced", "full"):
    sim = lbshape.simulation(scene, pre, method=method)
    record = sim.run(steps)
    if not record.stable:
        raise SystemExit(f"{method} stopped: {record.message}")
    runs[method] = (record.times, sim.displacements(record))

# 3. The relative error at each time: |u_reduced - u_full| / max over time of |u_full|
#    (2-norms over all vertices; the largest full displacement sets the scale).
times, full = runs["full"]
_, reduced = runs["reduced"]
scale = np.linalg.norm(full.reshape(len(times), -1), axis=1).max()
error = np.linalg.norm((reduced - full).reshape(len(times), -1), axis=1) / scale
print(f"{scene.name}: {steps} steps, r = {pre.r}; relative error at the end {error[-1]:.2%}, "
      f"largest {error.max():.2%}")

# 4. The plot.
fig, ax = plt.subplots(figsize=(6, 3.5))
ax.plot(times, 100 * error, color="tab:blue")
ax.set_xlabel("time (s)")
ax.set_ylabel("|u_reduced - u_full| / max |u_full| (%)")
ax.set_title(f"{scene.name}: reduced (r = {pre.r}) against full ({pre.mesh.n_vertices} vertices)")
ax.grid(alpha=0.3)
fig.tight_layout()
png = out / "reduced_vs_full.png"
fig.savefig(png, dpi=120)
print(png)
