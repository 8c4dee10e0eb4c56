"""Run a scene with one of the three methods and write its outputs.

* ``reduced`` — the paper's method: reduced dynamics, target found in a reduced
  space with no n-sized work (the scene's ``reduced.interpolation`` route, see
  :mod:`lbshape.pipeline.routes`: by default the exact polynomial StVK energy
  in LB space, else a cubature on the LB subspace or the paper's modal route);
* ``euclidean`` — the Zhu et al. 2015 baseline: the same reduced dynamics, but the
  target is found in LB space with the energy summed over all elements;
* ``full`` — full-space FEM with full-space interpolation: the accuracy reference.

Outputs in ``DIR``: ``stats.json`` (keys fixed by the command-line contract),
``trajectory.pvd`` + ``trajectory_*.vtu`` (ParaView), and ``states.npz`` (the
sampled full-space displacements, for error measurements).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lbshape.errors import LbshapeError
from lbshape.pipeline.precompute import Precomputed
from lbshape.scene.schema import Scene

log = logging.getLogger(__name__)

METHODS = ("reduced", "euclidean", "full")
#: steps excluded from the per-step timing means
WARMUP_STEPS = 10
#: most trajectory frames written per run
MAX_FRAMES = 100


@dataclass(frozen=True)
class SimulationOutput:
    """A finished (or stopped) run.

    Attributes:
        stats: the ``stats.json`` payload.
        times: (k,) sample times (s).
        displacements: (k, n, 3) sampled full-space displacements (m).
        message: solver failure message ('' if stable).
    """

    stats: dict
    times: np.ndarray
    displacements: np.ndarray
    message: str = ""


def load_patterns(scene: Scene, pre: Precomputed, mass) -> list[tuple[np.ndarray, object]]:
    """Full-space load patterns (3n,) with their time profiles."""
    from lbshape.dynamics.loads import gravity_pattern, region_force_pattern, region_torque_pattern

    mesh = pre.mesh
    patterns = []
    for index, load in enumerate(scene.loads):
        what = f"loads[{index}] region"
        if load.type == "gravity":
            pattern = gravity_pattern(mass, load.vector)
        elif load.type == "region_force":
            pattern = region_force_pattern(mass, load.selection.vertices(mesh, what=what),
                                           load.vector)
        elif load.type == "region_torque":
            pattern = region_torque_pattern(mass, mesh.points,
                                            load.selection.vertices(mesh, what=what), load.vector)
        else:  # the scene schema only admits the types above
            raise LbshapeError(f"unsupported load type {load.type!r}")
        patterns.append((pattern, load.profile))
    return patterns


def reduced_simulation(scene: Scene, pre: Precomputed, *, method: str = "reduced",
                       newton_iterations: int | None | str = "realtime"):
    """The :class:`~lbshape.dynamics.reduced.ReducedSimulation` of a scene (Newton updates
    per step: the real-time default, a number, or ``None`` for converged Newton)."""
    from lbshape.dynamics.reduced import (
        REALTIME_NEWTON_ITERATIONS,
        ReducedLoad,
        ReducedSimulation,
    )
    from lbshape.elastic.element_kernels import mass_matrix
    from lbshape.elastic.reduced_forces import ReducedForceModel

    if newton_iterations == "realtime":
        newton_iterations = REALTIME_NEWTON_ITERATIONS
    elastic = ReducedForceModel(pre.mesh.points, pre.mesh.tets, pre.material, pre.U,
                                pre.cubature_elements, pre.cubature_weights)
    loads = []
    if scene.loads:
        mass = mass_matrix(pre.mesh, pre.material.density)
        loads = [ReducedLoad(pre.U.T @ p, profile) for p, profile in
                 load_patterns(scene, pre, mass)]
    k_ex = scene.examples.stiffness if scene.examples is not None else 0.0
    driver = None
    if pre.has_examples and k_ex > 0:
        from lbshape.pipeline.routes import example_driver

        route = (scene.reduced.route(scene.material.model) if method == "reduced"
                 else "euclidean")
        driver = example_driver(pre, route=route)
    return ReducedSimulation(
        elastic, r=pre.r, dt=scene.simulation.dt, integrator=scene.simulation.integrator,
        alpha=scene.damping.alpha, beta=scene.damping.beta, loads=loads, driver=driver,
        k_ex=k_ex, newton_iterations=newton_iterations,
    )


def simulate(scene: Scene, pre: Precomputed, *, method: str = "reduced",
             steps: int | None = None, out: Path | None = None) -> SimulationOutput:
    """Run ``scene`` with ``method`` for ``steps`` (default: the scene's) steps."""
    if method not in METHODS:
        raise LbshapeError(f"method must be one of {METHODS}, got {method!r}")
    steps = scene.simulation.steps if steps is None else int(steps)
    if steps < 1:
        raise LbshapeError(f"steps must be >= 1, got {steps}")
    stride = max(1, math.ceil(steps / MAX_FRAMES))
    if method == "full":
        times, frames, t_interp, t_total, stable, message = _run_full(scene, pre, steps, stride)
        steps_done = int(round((times[-1] - times[0]) / scene.simulation.dt)) if len(times) else 0
        r, s = 3 * (pre.mesh.n_vertices - pre.fixed_vertices.size), pre.mesh.n_tets
    else:
        sim = reduced_simulation(scene, pre, method=method)
        record = sim.run(steps)
        q = np.asarray(record.states)
        picked = np.arange(0, len(q), stride)
        times = np.asarray(record.times)[picked]
        frames = (q[picked] @ pre.U.T).reshape(len(picked), -1, 3)
        t_interp = record.mean_ms(record.t_interp_ms, WARMUP_STEPS)
        t_total = record.mean_ms(record.t_total_ms, WARMUP_STEPS)
        stable, message = record.stable, record.message
        steps_done = len(record.t_total_ms)
        r, s = pre.r, int(pre.cubature_elements.size)
    max_disp = float(np.max(np.linalg.norm(frames, axis=2))) if frames.size else 0.0
    stats = {
        "scene": scene.name, "method": method,
        "n_vertices": pre.mesh.n_vertices, "n_tets": pre.mesh.n_tets,
        "m": scene.reduced.m, "r": int(r), "s": int(s),
        "dt": scene.simulation.dt, "steps": int(steps_done),
        "t_interp_ms": t_interp, "t_total_ms": t_total,
        "stable": bool(stable), "max_displacement": max_disp,
    }
    output = SimulationOutput(stats, times, frames, message)
    if out is not None:
        write_outputs(Path(out), pre, output)
    return output


def _run_full(scene: Scene, pre: Precomputed, steps: int, stride: int):
    from lbshape.dynamics.full import run_full_space

    return run_full_space(scene, pre, steps=steps, stride=stride, warmup=WARMUP_STEPS)


def write_outputs(out: Path, pre: Precomputed, output: SimulationOutput) -> None:
    """stats.json, states.npz and the ParaView trajectory, each written atomically."""
    from lbshape.io.atomic import write_json_atomic
    from lbshape.io.trajectory import TrajectoryWriter

    out.mkdir(parents=True, exist_ok=True)
    writer = TrajectoryWriter(out, pre.mesh)
    for t, u in zip(output.times, output.displacements, strict=True):
        writer.write(float(t), u)
    writer.close()
    tmp = out / "states.tmp.npz"
    np.savez(tmp, times=output.times, displacements=output.displacements)
    tmp.replace(out / "states.npz")
    write_json_atomic(out / "stats.json", output.stats)
