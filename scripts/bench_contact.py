"""Contact per area and friction that holds: writes results/contact.md.

1. A unit cube (E = 1e7 Pa, 1000 kg, 3 × 3 × 3 cells, 12 linear modes in the reduced
   method) dropped 1 mm onto a floor of 1e8 N/m³ with gravity tilted by atan(0.5), dt =
   1 ms: with μ = 0.7 > tan θ its travel along the slope over 0.5 s after the landing
   (:func:`landing_end`) and its creep speed against the regularised law; with μ = 0.3
   its acceleration (quadratic fit over 0.2-0.6 s) against g (sin θ − μ cos θ).
   Reduced and full.
2. The full reference of bar-s-cuboid (no examples) on its mesh and four refinements, each
   h/√2: the centre of mass's vertical velocity after its first floor contact, the
   changes between successive meshes, their ratio, the observed order in h and the
   Richardson estimate of the limit.

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python scripts/bench_contact.py [--out results/contact.md]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import platform
import subprocess
from pathlib import Path

import numpy as np
import scipy.linalg as sla

from lbshape.dynamics.contact import SLIP_SPEED, ContactPlane, PlaneContact
from lbshape.dynamics.contact_faces import FACING_FLOOR
from lbshape.dynamics.fictitious import frame_tensors
from lbshape.dynamics.free_body import FreeBodySimulation, FreeLoad
from lbshape.dynamics.full import FullSpaceContact, FullSpaceSimulator, rigid_velocity
from lbshape.dynamics.loads import TimedLoad, TimeProfile, gravity_pattern
from lbshape.elastic.element_kernels import FullSpaceElasticity, mass_matrix
from lbshape.elastic.materials import Material
from lbshape.elastic.reduced_forces import ReducedForceModel
from lbshape.geometry.primitives import structured_box
from lbshape.pipeline.meshes import build_mesh
from lbshape.scene import load_scene

G, DT = 9.81, 1e-3


def incline(method: str, mu: float, steps: int = 700) -> tuple[np.ndarray, np.ndarray]:
    """(times, travel along the slope (m)) of the dropped unit cube."""
    mesh = structured_box((1.0, 1.0, 1.0), (3, 3, 3))
    material = Material(model="stvk", young=1e7, poisson=0.3, density=1000.0)
    M = mass_matrix(mesh, material.density)
    theta = math.atan(0.5)
    pattern = gravity_pattern(M, G * np.array([math.sin(theta), 0.0, -math.cos(theta)]))
    plane = ContactPlane((0.0, 0.0, -0.001), (0.0, 0.0, 1.0), 1e8, mu)
    if method == "reduced":
        K = FullSpaceElasticity(mesh, material).tangent(np.zeros(3 * mesh.n_vertices))
        U = sla.eigh(K.toarray(), M.toarray())[1][:, 6:18]
        elastic = ReducedForceModel(mesh.points, mesh.tets, material, U,
                                    np.arange(mesh.n_tets), np.ones(mesh.n_tets))
        frame = frame_tensors(mesh.points, mesh.tets, M, U)
        contact = PlaneContact.for_mesh([plane], mesh.points, mesh.tets, U, center=frame.center)
        load = FreeLoad.from_pattern(pattern, U, mesh.points - frame.center, TimeProfile())
        record = FreeBodySimulation(elastic, frame, dt=DT, loads=[load], contact=contact,
                                    beta=1e-3).run(steps)
        return record.times, record.centers[:, 0] - record.centers[0, 0]
    weights = np.asarray(M[0::3, 0::3].sum(axis=1)).ravel()
    weights /= weights.sum()
    sim = FullSpaceSimulator(mesh, material, dt=DT, beta=1e-3,
                             loads=[TimedLoad(pattern, TimeProfile())],
                             contact=FullSpaceContact([plane], mesh.points, mesh.tets))
    states = [(0.0, 0.0)]
    sim.run(steps, on_step=lambda i, t, u: states.append((t, float(u[:, 0] @ weights))))
    times, x = (np.array(column) for column in zip(*states, strict=True))
    return times, x


#: the landing has ended once the block's travel along the slope, over every later
#: window of :data:`SETTLE_WINDOW`, is slower than this (m/s)
SETTLED_SPEED = 5e-3
SETTLE_WINDOW = 0.1  # s (the full cube rocks on the floor with a period of about 0.1 s)
HELD_STEPS = 1200  # 1.2 s: the landing, then a 0.5 s hold and the creep fit after it


def landing_end(t: np.ndarray, x: np.ndarray) -> float:
    """The time (s) from which every later :data:`SETTLE_WINDOW` moves the block slower
    than :data:`SETTLED_SPEED` along the slope: the landing's slide and bounces are over."""
    lag = int(round(SETTLE_WINDOW / DT))
    speed = np.abs(x[lag:] - x[:-lag]) / (t[lag:] - t[:-lag])  # over [t_i, t_i + window]
    fast = np.flatnonzero(speed > SETTLED_SPEED)
    return float(t[fast[-1] + 1]) if fast.size else 0.0


def incline_rows() -> list[str]:
    """The incline table's rows: μ = 0.7 (held) travel over 0.5 s after the landing and
    creep speed against the regularisation's ``ε s / √(1 − s²)``; μ = 0.3 acceleration."""
    theta = math.atan(0.5)
    s = math.tan(theta) / 0.7
    creep = SLIP_SPEED * s / math.sqrt(1 - s * s)
    rows = []
    for method in ("reduced", "full"):
        t, x = incline(method, 0.7, steps=HELD_STEPS)
        settled = landing_end(t, x)
        held = x[np.searchsorted(t, settled + 0.5)] - x[np.searchsorted(t, settled)]
        late = t >= t[-1] - 0.5
        speed = np.polyfit(t[late], x[late], 1)[0]
        t3, x3 = incline(method, 0.3)
        fit = (t3 >= 0.2) & (t3 <= 0.6)
        accel = 2.0 * np.polyfit(t3[fit], x3[fit], 2)[0]
        expected = G * (math.sin(theta) - 0.3 * math.cos(theta))
        rows.append(f"| {method} | {settled:.3f} | {1e3 * held:.3f} | "
                    f"{'met' if abs(held) < 1e-3 else 'missed'} | {1e3 * speed:.3f} | "
                    f"{1e3 * creep:.3f} | {accel:.4f} | {expected:.4f} | "
                    f"{100 * (accel / expected - 1):+.3f} % |")
    return rows


def bounce(size: float | None) -> tuple[int, float]:
    """(vertices, vertical centre-of-mass velocity after the first floor contact (m/s))
    of bar-s-cuboid's full reference without examples on its mesh at ``size``."""
    scene = load_scene("bar-s-cuboid")
    obj = scene.object if size is None else dataclasses.replace(scene.object, size=size)
    mesh = build_mesh(obj)
    M = mass_matrix(mesh, scene.material.density)
    weights = np.asarray(M[0::3, 0::3].sum(axis=1)).ravel()
    weights /= weights.sum()
    loads = [TimedLoad(gravity_pattern(M, np.array(load.vector)), TimeProfile())
             for load in scene.loads]
    sim = FullSpaceSimulator(
        mesh, scene.material, dt=scene.simulation.dt, beta=scene.damping.beta,
        alpha=scene.damping.alpha, loads=loads,
        contact=FullSpaceContact(list(scene.planes), mesh.points, mesh.tets),
        initial_velocity=rigid_velocity(mesh, scene.material.density, scene.initial.velocity,
                                        scene.initial.angular_velocity))
    floor = scene.planes[0].point[2]
    n = mesh.n_vertices
    rows: list[tuple[float, bool]] = []
    sim.run(450, on_step=lambda i, t, u: rows.append(
        (float(sim.stepper.v.reshape(n, 3)[:, 2] @ weights),
         bool((mesh.points[:, 2] + u[:, 2] < floor).any()))))
    first = next(i for i, row in enumerate(rows) if row[1])
    end = next(i for i in range(first, len(rows)) if not rows[i][1])
    return n, rows[end][0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="results/contact.md")
    args = parser.parse_args()
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True, check=False).stdout.strip()
    load = os.getloadavg()[0]
    cpu = next((line.split(":", 1)[1].strip() for line in
                Path("/proc/cpuinfo").read_text().splitlines() if line.startswith("model name")),
               platform.processor() or platform.machine())
    lines = ["# Contact per area and friction that holds", "",
             "Command: `PYTHONPATH=$PWD OMP_NUM_THREADS=1 python scripts/bench_contact.py`; "
             f"commit {commit}; machine {cpu}, "
             f"{os.cpu_count()} cores; threads OMP_NUM_THREADS="
             f"{os.environ.get('OMP_NUM_THREADS', 'unset')}; load {load:.2f} at the start. "
             f"No timings. Slip speed ε = {SLIP_SPEED:g} m/s, facing floor β = {FACING_FLOOR}.",
             "", "## Unit cube on an incline (tan θ = 0.5), dropped 1 mm, dt = 1 ms", "",
             f"μ = 0.7 > tan θ holds the block: the landing ends when every later "
             f"{1e3 * SETTLE_WINDOW:.0f} ms moves it slower than {1e3 * SETTLED_SPEED:g} mm/s "
             f"along the slope; then its travel over 0.5 s (target < 1 mm), and its creep "
             f"speed (a line fitted over the last 0.5 s of {HELD_STEPS * DT:g} s) beside the "
             "regularised law's ε s / √(1 − s²), s = tan θ / μ. μ = 0.3 < tan θ: the "
             "sliding acceleration (quadratic fit over 0.2-0.6 s) against the closed form.",
             "", "| method | μ = 0.7 landing ends (s) | travel over the next 0.5 s (mm) | "
             "< 1 mm | creep (mm/s) | ε s / √(1 − s²) (mm/s) | μ = 0.3 acceleration "
             "(m/s²) | g (sin θ − μ cos θ) | deviation |",
             "|---|---|---|---|---|---|---|---|---|"]
    lines += incline_rows()
    lines += bounce_lines()
    Path(args.out).write_text("\n".join(lines) + "\n")


#: the refinements of the bounce study: the scene's h = 0.0665 m over √2, 2, 2√2, 4
BOUNCE_SIZES = (0.0665, 0.047, 0.033, 0.0235, 0.0166)


def bounce_lines() -> list[str]:
    """The bounce under refinement: v_z per mesh, the change from the previous mesh, the
    ratio of successive changes (constant for a converging sequence), the observed order
    p = log(ratio) / log(√2), and the Richardson limit from the last three meshes."""
    lines = ["", "## bar-s-cuboid full reference (no examples): first bounce under refinement",
             "", "Each mesh h/√2 of the previous one. Change: v_z minus the previous mesh's; "
             "ratio: the previous change over this one (a sequence converging at order p in "
             "h has ratio √2^p); limit: Richardson's from the last three meshes, "
             "v + change / (ratio − 1).", "",
             "| mesh size (m) | vertices | v_z after the first contact (m/s) | change | "
             "ratio of changes | order p | off the limit |", "|---|---|---|---|---|---|---|"]
    results = [bounce(size) for size in BOUNCE_SIZES]
    velocities = [v for _, v in results]
    changes = [None] + [b - a for a, b in zip(velocities, velocities[1:], strict=False)]
    ratios = [None, None] + [changes[i - 1] / changes[i] for i in range(2, len(changes))]
    last = ratios[-1]
    limit = velocities[-1] + changes[-1] / (last - 1.0) if last and last > 1.0 else None
    for size, (n, v), change, ratio in zip(BOUNCE_SIZES, results, changes, ratios,
                                           strict=True):
        order = (f"{math.log(ratio) / math.log(math.sqrt(2.0)):.2f}"
                 if ratio and ratio > 0 else "—")
        off = "—" if limit is None else f"{100 * abs(v - limit) / abs(limit):.1f} %"
        lines.append(f"| {size:g} | {n} | {v:.4f} | "
                     f"{'—' if change is None else f'{change:+.4f}'} | "
                     f"{'—' if ratio is None else f'{ratio:.2f}'} | {order} | {off} |")
    lines += ["", "Richardson limit: " + ("— (the changes do not shrink)" if limit is None
                                          else f"{limit:.4f} m/s") + "."]
    return lines


if __name__ == "__main__":
    main()
