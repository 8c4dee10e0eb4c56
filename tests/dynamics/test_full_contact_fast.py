"""The fast full-space reference on contact and friction scenes: the contact tangent added
into the compiled tangent's data through kept positions (equal to the sparse sum), updates
solved to a tenth of the Newton tolerance, the tangent afresh at each step's first update
(kept within the step), a ramped example spring added on its kept pattern and the free
body's rigid modes from the scalar mass."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from lbshape.dynamics.contact import ContactPlane
from lbshape.dynamics.full import FullSpaceContact, FullSpaceExamples, FullSpaceSimulator
from lbshape.dynamics.linear_solvers import NEWTON_FRACTION, ReusedFactorSolver
from lbshape.dynamics.rigid_motions import rigid_modes
from lbshape.elastic.assembly import CompiledElasticity
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.elastic.materials import Material
from lbshape.geometry.primitives import structured_box
from lbshape.spectral.spectrum import lb_spectrum


def material() -> Material:
    return Material("stvk", young=1.0e5, poisson=0.3, density=1000.0)


@pytest.fixture(scope="module")
def box():
    return structured_box((0.3, 0.1, 0.1), (6, 2, 2))


def _sparse_add(K, matrix, constant=False, scale=1.0):
    return K + scale * matrix


@pytest.mark.parametrize("held", [False, True])
def test_contact_tangent_in_place_equals_the_sparse_sum(box, held):
    """Two tilted planes with friction pressed into a box (free, or held at one end): the
    tangent added through the kept positions equals ``K + Kc[free][:, free]``."""
    mesh = box
    n = mesh.n_vertices
    fixed = np.flatnonzero(mesh.points[:, 0] < 1e-9) if held else np.array([], dtype=int)
    free = np.setdiff1d(np.arange(3 * n), (3 * fixed[:, None] + np.arange(3)).ravel())
    planes = [ContactPlane((0.0, 0.0, 0.004), (0.1, 0.0, 1.0), 2e5, 0.4),
              ContactPlane((0.3, 0.0, 0.0), (-1.0, 0.05, 0.0), 1e5, 0.0)]
    contact = FullSpaceContact(planes, mesh.points, mesh.tets)
    rng = np.random.default_rng(2)
    u = 1e-3 * rng.normal(size=3 * n)
    u.reshape(n, 3)[fixed] = 0.0
    u.reshape(n, 3)[:, 0] += 0.004 * mesh.points[:, 0] / 0.3  # into the end plane
    v = 0.2 * rng.normal(size=3 * n)
    compiled = CompiledElasticity(mesh, material(), free)
    _, K = compiled.force_and_tangent(u)
    force, parts, energy = contact.evaluate_parts(u, v, 500.0)
    assert len(parts) == 2 and parts[0][2] is not None and parts[1][2] is None
    f_old, Kc, e_old = contact.evaluate(u, v, 500.0)
    assert np.array_equal(force, f_old) and energy == e_old
    # the residual's evaluation (no blocks): the same force and energy, bit for bit
    f_alone, marks, e_alone = contact.evaluate_parts(u, v, 500.0, tangent=False)
    assert np.array_equal(f_alone, force) and e_alone == energy and len(marks) == 2
    expected = K + Kc[free][:, free]
    total = contact.add_into(K.copy(), parts, free, compiled, _sparse_add)
    assert compiled.on_pattern(total)  # added in place, on the kept positions
    assert abs(total - expected).max() <= 1e-14 * abs(expected).max()
    assert abs(Kc - Kc.T).max() > 0.0  # friction: not symmetric, and the test sees it
    # without the compiled pattern: the sparse sum
    other = contact.add_into(K.copy(), parts, free, None, _sparse_add)
    assert abs(other - expected).max() <= 1e-14 * abs(expected).max()


def test_scaled_constant_spring_equals_the_scaled_sum(box):
    compiled = CompiledElasticity(box, material())
    _, K = compiled.force_and_tangent(np.zeros(compiled.n_dofs))
    mass = mass_matrix(box, 1000.0)
    for scale in (0.25, 1.0, 3.0):
        total = compiled.add_into(K.copy(), mass, constant=True, scale=scale)
        assert compiled.on_pattern(total)
        assert abs(total - (K + scale * mass)).max() <= 1e-15 * abs(K).max()


def test_rigid_modes_from_the_scalar_mass_equal_the_sparse_product(box):
    mass = mass_matrix(box, 1000.0)
    scalar = sp.csr_matrix(mass[0::3, 0::3])
    points = box.points + 0.01 * np.random.default_rng(4).normal(size=box.points.shape)
    psi, mass_psi = rigid_modes(points, mass)
    psi2, mass_psi2 = rigid_modes(points, mass, scalar)
    assert np.abs(psi2 - psi).max() <= 1e-12 * np.abs(psi).max()
    assert np.abs(mass_psi2 - mass_psi).max() <= 1e-12 * np.abs(mass_psi).max()
    np.testing.assert_allclose(psi.T @ (mass @ psi), np.eye(6), atol=1e-12)


def test_inexact_updates_reach_a_tenth_of_the_newton_tolerance():
    """With the step's Newton tolerance τ set, a solve stops at ``NEWTON_FRACTION τ`` (in
    fewer GMRES iterations than to the linear tolerance) and not before."""
    rng = np.random.default_rng(7)
    n = 80
    lap = sp.diags([-np.ones(n - 1), 4.0 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1])
    base = sp.csr_matrix(10.0 * sp.identity(n))
    iterations = {}
    for tolerance in (0.0, 1e-6):
        solver = ReusedFactorSolver()
        solver(base, sp.csr_matrix(lap), rng.normal(size=n))  # the factor of the first J
        solver.newton_tolerance = tolerance
        K = sp.csr_matrix(lap * 1.3 + 0.3 * sp.diags(rng.uniform(size=n)))
        R = np.random.default_rng(1).normal(size=n)
        before = solver.inner_iterations
        delta = solver(base, K, R)
        iterations[tolerance] = solver.inner_iterations - before
        residual = np.linalg.norm((base + K) @ delta - R)
        if tolerance:
            assert 1e-3 * NEWTON_FRACTION * tolerance < residual
            assert residual <= NEWTON_FRACTION * tolerance * (1 + 1e-6)
        else:
            assert residual <= 1e-10 * np.linalg.norm(R)
    assert iterations[1e-6] < iterations[0.0]


def test_free_body_takes_its_tangent_once_per_step_and_keeps_its_factor(box):
    """A spinning free bar with an example pull, co-rotated damping and a rough floor:
    the stepper evaluates the tangent at each step's first update (and where an update
    contracts less than ten-fold), the reused factor is not refactorised per step."""
    mesh = box
    spectrum = lb_spectrum(mesh, 3)
    phi = spectrum.eigenvectors
    c = np.zeros((1, phi.shape[1], 3))
    c[0, 2, 1] = 0.01 / np.abs(phi).max()
    floor = ContactPlane((0.0, 0.0, mesh.points[:, 2].min() - 0.002), (0.0, 0.0, 1.0),
                         2e5, 0.3)
    arm = mesh.points - mesh.points.mean(axis=0)
    sim = FullSpaceSimulator(
        mesh, material(), dt=0.002, beta=2e-3,
        examples=FullSpaceExamples(spectrum.eigenvalues, phi, c, 1e3),
        contact=FullSpaceContact([floor], mesh.points, mesh.tets),
        initial_velocity=np.array([0.0, 0.0, -0.2]) + np.cross([0.0, 1.0, 0.5], arm))
    steps = 20
    record = sim.run(steps)
    assert record.stable, record.message
    stepper, solver = sim.stepper, sim.stepper._linear_solver
    assert stepper.tangent_each_step
    assert steps <= stepper.tangent_evaluations <= solver.solves
    assert solver.factorisations <= stepper.tangent_evaluations / 2  # not one per tangent
    assert solver.newton_tolerance > 0.0


def test_the_reused_factor_is_taken_afresh_when_the_example_ramp_ends(box):
    """With per-step tangents the factor of the first step (k_ex ≈ 0) preconditions the
    ramped spring ever worse: it is factorised again once the ramp reaches k_ex."""
    mesh = box
    spectrum = lb_spectrum(mesh, 3)
    phi = spectrum.eigenvectors
    c = np.zeros((1, phi.shape[1], 3))
    c[0, 2, 1] = 0.01 / np.abs(phi).max()
    arm = mesh.points - mesh.points.mean(axis=0)
    sim = FullSpaceSimulator(
        mesh, material(), dt=0.002, beta=2e-3, example_ramp=0.006,
        examples=FullSpaceExamples(spectrum.eigenvalues, phi, c, 1e4),
        initial_velocity=np.cross([0.0, 1.0, 0.5], arm))
    solver = sim.stepper._linear_solver
    counts = []
    record = sim.run(6, on_step=lambda *_: counts.append(solver.factorisations))
    assert record.stable, record.message
    ramp_end = 3  # steps 1–3 ramp (t ≤ 0.006 s), the third reaches k_ex
    assert counts[ramp_end - 2] == counts[0]  # kept while the ramp rises
    assert counts[ramp_end - 1] == counts[ramp_end - 2] + 1  # afresh at its end
