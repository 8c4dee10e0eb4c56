"""Local examples: the full-space reference and the reduced method integrate the same
equations. In a complete mass-orthonormal basis (every free dof), with every element
at weight 1 and the all-element target route, the two trajectories agree to solver
tolerance — any difference in how the example forces act in the two methods (spring,
pull, anchor fit, weights) would show here."""

from __future__ import annotations

import numpy as np
from conftest import rel

from lbshape.dynamics.engine import NewtonSettings
from lbshape.dynamics.full import FullSpaceSimulator
from lbshape.dynamics.loads import (
    TimedLoad,
    TimeProfile,
    region_force_pattern,
    region_torque_pattern,
)
from lbshape.dynamics.reduced import ReducedSimulation
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.elastic.materials import Material
from lbshape.elastic.reduced_forces import ReducedForceModel
from lbshape.geometry.poses import twist
from lbshape.geometry.primitives import structured_box
from lbshape.shapespace.interpolation import BASELINE_ROUTE
from lbshape.shapespace.local_build import RegionSpec, build_local_space
from lbshape.shapespace.local_driver import local_example_driver
from lbshape.shapespace.local_full_force import FullSpaceLocalForce
from lbshape.shapespace.local_regions import region_cells, submesh

MATERIAL = Material(model="stvk", young=1e5, poisson=0.3, density=1000.0)
BAR = (0.2, 0.2, 1.0)


def test_local_examples_full_space_is_the_reduced_method_in_a_complete_basis():
    mesh = structured_box(BAR, (1, 1, 6))
    fixed = np.flatnonzero(mesh.points[:, 2] < 1e-9)
    M = mass_matrix(mesh, MATERIAL.density)
    free = np.setdiff1d(np.arange(3 * mesh.n_vertices), (3 * fixed[:, None] + np.arange(3)))
    chol = np.linalg.cholesky(M[free][:, free].toarray())
    U = np.zeros((3 * mesh.n_vertices, free.size))
    U[free] = np.linalg.inv(chol).T  # UᵀMU = I, span U = every free displacement
    example = structured_box(BAR, (2, 2, 10))
    angles = {0: 0.9, 1: 0.3, 2: -0.6, 3: 0.2}

    def part(k, spec):
        cells = region_cells(example, group=spec.group, region=spec.region)
        sub, _ = submesh(example, cells)
        return sub, twist(sub.points, angle=angles[k], axis="z", anchor="min")

    specs = [RegionSpec("low", None, "z < 0.5", (0, 1)), RegionSpec("high", None, "z > 0.5",
                                                                   (2, 3))]
    space = build_local_space(mesh, MATERIAL, U, specs, part, m=4, fixed_vertices=fixed,
                              tabulate=False)
    top = np.flatnonzero(mesh.points[:, 2] > 1.0 - 1e-9)
    load = TimedLoad(region_force_pattern(M, top, np.array([3.0, 0.0, 0.0]))
                     + region_torque_pattern(M, mesh.points, top, np.array([0.0, 0.0, 8.0])),
                     TimeProfile("ramp", 0.0, 0.05))
    k_ex, dt, steps = 300.0, 0.004, 40
    full_sim = FullSpaceSimulator(
        mesh, MATERIAL, dt=dt, fixed_vertices=fixed, alpha=1.0, beta=1e-4, loads=[load],
        local_examples=(FullSpaceLocalForce(mesh, MATERIAL, space, tolerance=1e-10), k_ex),
        newton=NewtonSettings(1e-12, 20))
    weights = []
    full = full_sim.run(steps, on_step=lambda i, t, u: weights.append(full_sim.weights.copy()))

    elastic = ReducedForceModel(mesh.points, mesh.tets, MATERIAL, U, np.arange(mesh.n_tets),
                                np.ones(mesh.n_tets))
    driver = local_example_driver(mesh, MATERIAL, space, route=BASELINE_ROUTE,
                                  tolerance=1e-10)
    reduced = ReducedSimulation(elastic, r=free.size, dt=dt, alpha=1.0, beta=1e-4,
                                loads=[TimedLoad(U.T @ load.pattern, load.profile)],
                                driver=driver, k_ex=k_ex, newton=NewtonSettings(1e-12, 20),
                                energy_factor=None)
    record = reduced.run(steps)
    assert record.stable, record.message
    u_reduced = (np.asarray(record.states) @ U.T).reshape(full.displacements().shape)
    assert np.abs(full.displacements()).max() > 1e-3  # a real motion
    err = rel(full.displacements(), u_reduced)
    assert err < 1e-6, f"full-space vs complete-basis reduced trajectory (local): {err:.2e}"
    weights = np.array(weights)
    assert np.ptp(weights, axis=0).max() > 0.1, "the examples' weights should change"
