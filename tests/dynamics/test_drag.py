"""The user's drag (:class:`~lbshape.dynamics.engine.Drag`, reduced by
:mod:`lbshape.dynamics.drag`) in the engines, against closed forms: a fixed object's static
equilibrium under the spring (complete basis, small pull: linear elasticity), the same pull
on the full-space engine, and a free body's momentum and angular momentum impulse over a
step."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sla
from conftest import golden

from lbshape.dynamics.drag import explicit_stiffness_limit
from lbshape.dynamics.engine import Drag
from lbshape.dynamics.fictitious import frame_tensors
from lbshape.dynamics.free_body import FreeBodySimulation
from lbshape.dynamics.full import FullSpaceSimulator
from lbshape.dynamics.reduced import ReducedSimulation
from lbshape.elastic.element_kernels import FullSpaceElasticity, mass_matrix
from lbshape.elastic.materials import Material
from lbshape.elastic.reduced_forces import ReducedForceModel
from lbshape.geometry.primitives import structured_box

MATERIAL = Material(model="stvk", young=1e6, poisson=0.3, density=1000.0)


def _elastic(mesh, U):
    every = np.arange(mesh.n_tets)
    return ReducedForceModel(mesh.points, mesh.tets, MATERIAL, U, every, np.ones(mesh.n_tets))


@pytest.fixture(scope="module")
def clamped():
    """A bar fixed at z = 0 and its complete mass-orthonormal basis of the free dofs."""
    mesh = structured_box((0.2, 0.2, 0.6), (1, 1, 3))
    M = mass_matrix(mesh, MATERIAL.density).toarray()
    K = FullSpaceElasticity(mesh, MATERIAL).tangent(np.zeros(3 * mesh.n_vertices)).toarray()
    free = np.flatnonzero(np.repeat(mesh.points[:, 2] > 1e-9, 3))
    _, V = sla.eigh(K[np.ix_(free, free)], M[np.ix_(free, free)])
    U = np.zeros((3 * mesh.n_vertices, free.size))
    U[free] = V
    return mesh, U


def test_fixed_object_settles_where_spring_and_elasticity_balance(clamped):
    mesh, U = clamped
    vertex = int(np.argmax(mesh.points @ np.array([1.0, 1.0, 10.0])))  # a top corner
    rows = U[3 * vertex:3 * vertex + 3]
    offset = np.array([1e-4, -0.5e-4, 0.2e-4])  # m: small, so the response is linear
    k = 5e4
    elastic = _elastic(mesh, U)
    sim = ReducedSimulation(elastic, r=U.shape[1], dt=0.01, integrator="backward-euler",
                            alpha=30.0, basis=U, rest_points=mesh.points)
    sim.set_drag(Drag(vertex, mesh.points[vertex] + offset, k))
    for _ in range(400):
        sim.step()
    _, K0 = elastic.force_and_tangent(np.zeros(U.shape[1]))
    # K q + k U_iᵀ (U_i q − offset) = 0
    expected = np.linalg.solve(K0 + k * rows.T @ rows, k * rows.T @ offset)
    # the StVK nonlinearity at a 0.1 mm pull
    limit = golden("drag.static_equilibrium_error").limit
    assert np.linalg.norm(sim.x - expected) < limit * np.linalg.norm(expected)
    # the vertex lies between rest and target, pulled most of the way along the offset
    moved = rows @ sim.x
    assert 0.0 < moved @ offset < offset @ offset
    # released: it springs back to rest
    sim.set_drag(None)
    for _ in range(400):
        sim.step()
    assert np.linalg.norm(sim.x) < 1e-3 * np.linalg.norm(expected)


def test_free_body_gets_the_spring_impulse_and_its_moment():
    mesh = structured_box((0.2, 0.2, 0.6), (2, 2, 4))
    mass = mass_matrix(mesh, MATERIAL.density)
    K = FullSpaceElasticity(mesh, MATERIAL).tangent(np.zeros(3 * mesh.n_vertices))
    _, V = sla.eigh(K.toarray(), mass.toarray())
    U = V[:, 6:14]
    frame = frame_tensors(mesh.points, mesh.tets, mass, U)
    dt = 1e-3
    sim = FreeBodySimulation(_elastic(mesh, U), frame, dt=dt, basis=U, rest_points=mesh.points)
    vertex = int(np.argmax(mesh.points[:, 2]))
    rows = U[3 * vertex:3 * vertex + 3]
    body_point = mesh.points[vertex] - frame.center
    target = mesh.points[vertex] + np.array([0.05, 0.02, 0.0])
    limit = explicit_stiffness_limit(rows, dt, mass=frame.mass,
                                     arm=float(np.linalg.norm(body_point)),
                                     inertia=float(np.linalg.eigvalsh(frame.inertia0)[0]))
    k = min(2e4, limit)  # the engine caps the stiffness asked for
    sim.set_drag(Drag(vertex, target, 2e4))
    assert sim.drag.stiffness == k
    sim.step()
    force = k * (target - mesh.points[vertex])  # at the start of the step (rest)
    rigid = sim.rigid
    assert np.allclose(rigid.momentum, dt * force, rtol=1e-12, atol=1e-15)
    assert np.allclose(rigid.angular_momentum, dt * np.cross(body_point, force), rtol=1e-10,
                       atol=1e-15)
    # released: no more impulse
    sim.set_drag(None)
    sim.step()
    assert np.allclose(sim.rigid.momentum, dt * force, rtol=1e-12, atol=1e-15)


def test_full_and_reduced_engines_hold_the_same_pull_and_let_go(clamped):
    """One drag on the full-space engine and on the reduced engine (complete basis) of the
    same fixed bar: the same steady displacement of the vertex; released, back to rest."""
    mesh, U = clamped
    vertex = int(np.argmax(mesh.points @ np.array([1.0, 1.0, 10.0])))
    target = mesh.points[vertex] + np.array([2e-4, -1e-4, 0.5e-4])
    drag = Drag(vertex, target, 5e4)
    fixed = np.flatnonzero(mesh.points[:, 2] <= 1e-9)
    options = dict(dt=0.01, integrator="backward-euler", alpha=30.0)
    full = FullSpaceSimulator(mesh, MATERIAL, fixed_vertices=fixed, **options)
    reduced = ReducedSimulation(_elastic(mesh, U), r=U.shape[1], basis=U,
                                rest_points=mesh.points, **options)
    moved = {}
    for name, sim in (("full", full), ("reduced", reduced)):
        sim.set_drag(drag)
        for _ in range(300):
            sim.step()
        moved[name] = sim.displacement()[vertex]
        assert 0.0 < moved[name] @ (target - mesh.points[vertex])
        sim.set_drag(None)
        for _ in range(300):
            sim.step()
        assert np.abs(sim.displacement()).max() < 1e-3 * np.linalg.norm(moved[name])
    np.testing.assert_allclose(moved["reduced"], moved["full"], rtol=0,
                               atol=0.02 * np.linalg.norm(moved["full"]))


def test_explicit_limit_is_the_mobility_bound():
    rows = np.diag([2.0, 1.0, 0.5])
    # λ_max(rowsᵀ rows) = 4, plus 1/m = 0.5 and arm²/I = 4 / 8 = 0.5: λ = 5
    assert explicit_stiffness_limit(rows, 0.01, mass=2.0, arm=2.0, inertia=8.0) == \
        pytest.approx(0.25 / (5.0 * 1e-4))


def test_a_grab_is_work_for_the_energy_monitor(clamped):
    """A drag's spring ``½ k |U_i q|²`` is potential and its pull a load (the monitor's
    split): grabbing or letting go at a displaced state changes that potential at once, and
    the energy monitor's budget counts the change as work (else a drag on an object with a
    small budget, the live teddy, is stopped as a blow-up)."""
    mesh, U = clamped
    top = np.flatnonzero(mesh.points[:, 2] > mesh.points[:, 2].max() - 1e-9)
    offset, k = np.array([0.0, 0.05, 0.0]), 5e4
    sim = ReducedSimulation(_elastic(mesh, U), r=U.shape[1], dt=0.01, alpha=30.0,
                            integrator="backward-euler", basis=U, rest_points=mesh.points)
    sim.set_drag(Drag(top[0], mesh.points[top[0]] + offset, k))
    for _ in range(20):
        sim.step()
    for vertex in (top[1], None):  # a second vertex grabbed, then let go
        before, held, potential = sim._work, sim._held_energy, sim.drag.energy(sim.x)
        sim.set_drag(None if vertex is None else Drag(vertex, mesh.points[vertex], k))
        added = 0.0 if sim.drag is None else sim.drag.energy(sim.x)
        assert abs(added - potential) > 1.0  # J: the bar moved, the grab changes it
        # the monitor's held potential (tracked by the work of f, exact after the grab)
        # changes by about the grab's, and that change is work
        assert sim._held_energy - held == pytest.approx(added - potential, rel=0.2)
        assert sim._work - before == pytest.approx(abs(sim._held_energy - held), rel=1e-12)
