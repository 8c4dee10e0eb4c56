"""The fast full-space reference's free-body Newton: its tangent terms against finite
differences (the contact pressure's facing areas, the deformation damping's turn with the
spin), the tangent kept across steps in flight turned with the body, its updates solved to
the Newton contraction, and the rigid fits it reads (compiled) against their definitions."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from lbshape.dynamics.contact import ContactPlane
from lbshape.dynamics.full import FullSpaceContact, FullSpaceExamples, FullSpaceSimulator
from lbshape.dynamics.full_damping import TurnedMatrix
from lbshape.dynamics.linear_solvers import CONTRACTION_CAP, NEWTON_FRACTION, ReusedFactorSolver
from lbshape.dynamics.rigid_frame import KabschFit
from lbshape.elastic.assembly import CompiledElasticity
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.elastic.materials import Material
from lbshape.geometry.primitives import structured_box
from lbshape.spectral.spectrum import lb_spectrum

#: agreement of the fast reference with the former one (issue 38: ≤ 1e-6)
AGREEMENT = 1e-6


def material() -> Material:
    return Material("stvk", young=1.0e5, poisson=0.3, density=1000.0)


@pytest.fixture(scope="module")
def box():
    return structured_box((0.3, 0.1, 0.1), (6, 2, 2))


def rotation(axis, angle: float) -> np.ndarray:
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    cross = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]],
                      [-axis[1], axis[0], 0.0]])
    return np.eye(3) + np.sin(angle) * cross + (1.0 - np.cos(angle)) * cross @ cross


def spinning(mesh, spin=(0.0, 3.0, 1.0), drift=(0.1, 0.0, -0.2)) -> np.ndarray:
    arm = mesh.points - mesh.points.mean(axis=0)
    return np.asarray(drift) + np.cross(spin, arm)


def directional_error(jacobian_times, force, x, direction, eps) -> float:
    """``‖J d − (f(x + ε d) − f(x − ε d)) / 2ε‖ / ‖…‖`` of a tangent's action J d."""
    fd = (force(x + eps * direction) - force(x - eps * direction)) / (2.0 * eps)
    return float(np.linalg.norm(jacobian_times - fd) / np.linalg.norm(fd))


def test_contact_tangent_holds_the_facing_areas_change(box):
    """A box pressed into a tilted frictionless plane: with the facing areas' change the
    contact tangent equals the force's finite difference to 1e-7; without it (the former
    reference's tangent) it is off by 16 %."""
    n = box.n_vertices
    contact = FullSpaceContact([ContactPlane((0.0, 0.0, 0.004), (0.1, 0.0, 1.0), 2e5, 0.0)],
                               box.points, box.tets)
    rng = np.random.default_rng(2)
    u, direction = 1e-3 * rng.normal(size=3 * n), rng.normal(size=3 * n)

    def force(w):
        return contact.evaluate_parts(w, tangent=False)[0]

    errors = {}
    for share in (False, True):
        _, parts, _ = contact.evaluate_parts(u, shares=share)
        errors[share] = directional_error(contact.matrix(parts) @ direction, force, u,
                                          direction, 1e-7)
    assert errors[True] <= 1e-7, errors
    assert errors[False] >= 0.05, errors


def test_fast_simulator_evaluates_the_facing_areas_change(box, monkeypatch):
    """The fast path's tangent asks the contact for the facing areas' change; the former
    path's does not."""
    floor = ContactPlane((0.0, 0.0, -0.001), (0.0, 0.0, 1.0), 2e5, 0.0)
    asked = []
    original = FullSpaceContact.evaluate_parts

    def spy(self, *args, **kwargs):
        if kwargs.get("tangent", True):
            asked.append(kwargs.get("shares", False))
        return original(self, *args, **kwargs)

    monkeypatch.setattr(FullSpaceContact, "evaluate_parts", spy)
    for solver, share in (("reuse", True), ("lu-each-iteration", False)):
        sim = FullSpaceSimulator(box, material(), dt=0.002, linear_solver=solver,
                                 contact=FullSpaceContact([floor], box.points, box.tets))
        asked.clear()
        sim._force_and_tangent(np.zeros(sim.free_dofs.size))
        assert asked == [share]


def damping_tangent_error(box, solver: str) -> float:
    """The free spinning box's Newton tangent (sparse and low-rank parts) against the
    finite difference of its force, co-rotated damping included, off the converged state."""
    sim = FullSpaceSimulator(box, material(), dt=0.002, beta=5e-3, linear_solver=solver,
                             initial_velocity=spinning(box))
    sim.run(5)
    stepper = sim.stepper
    rng = np.random.default_rng(5)
    x = stepper.x + stepper.dt * stepper.v + 1e-4 * rng.normal(size=stepper.x.size)
    f, K = sim._force_and_tangent(x)
    W, S = sim._tangent_correction()
    direction = rng.normal(size=x.size)

    def force(y):
        return sim._force_and_tangent(y)[0]

    return directional_error(K @ direction + W @ (S @ (W.T @ direction)), force, x,
                             direction, 1e-6)


def test_damping_tangent_turns_with_the_spin(box):
    """At 3 rad/s the projection P's turn with the body, ``− Pᵀ D P Ω``, is most of what the
    former tangent leaves out: the fast tangent is 5× closer to the finite difference."""
    former, fast = damping_tangent_error(box, "lu-each-iteration"), damping_tangent_error(
        box, "reuse")
    assert former >= 1e-3, former
    assert fast <= 0.3 * former, (fast, former)


def test_tangent_of_a_turned_state_is_the_turned_tangent(box):
    """The premise of the tangent kept across steps in flight: the elastic tangent of a
    deformed box turned rigidly by R is ``Q K Qᵀ`` (CompiledElasticity.rotated)."""
    compiled = CompiledElasticity(box, material())
    rng = np.random.default_rng(3)
    u = 0.01 * rng.normal(size=(box.n_vertices, 3))
    R = rotation([1.0, 2.0, 0.5], 0.4)
    turned = (box.points + u) @ R.T - box.points
    _, K = compiled.force_and_tangent(u.ravel())
    _, K_turned = compiled.force_and_tangent(turned.ravel())
    expected = compiled.rotated(K.data, R)
    assert np.abs(K_turned.data - expected).max() <= 1e-9 * np.abs(K.data).max()
    Q = sp.kron(sp.identity(box.n_vertices), sp.csr_matrix(R))
    v = rng.normal(size=3 * box.n_vertices)
    np.testing.assert_allclose(TurnedMatrix(K, R) @ v, Q @ (K @ (Q.T @ v)), atol=1e-9
                               * np.abs(K.data).max())


def test_free_body_in_flight_keeps_its_tangent_across_steps(box):
    """A spinning free box with an example pull and co-rotated damping, in flight: the fast
    path evaluates its tangent at fewer than one step in two (turned with the body between)
    and keeps its one factorisation, and its motion equals the former reference's."""
    spectrum = lb_spectrum(box, 3)
    phi = spectrum.eigenvectors
    c = np.zeros((1, phi.shape[1], 3))
    c[0, 2, 1] = 0.01 / np.abs(phi).max()
    states, sims = {}, {}
    steps = 40
    for solver in ("reuse", "lu-each-iteration"):
        sim = FullSpaceSimulator(box, material(), dt=0.002, beta=2e-3, linear_solver=solver,
                                 examples=FullSpaceExamples(spectrum.eigenvalues, phi, c, 1e3),
                                 initial_velocity=spinning(box, spin=(0.0, 1.5, 0.5)))
        record = sim.run(steps)
        assert record.stable, record.message
        states[solver], sims[solver] = np.asarray(record.states), sim
    fast = sims["reuse"]
    assert fast.stepper.tangent_evaluations <= steps / 2
    assert fast.stepper._linear_solver.factorisations == 1
    mass = fast.mass

    def norms(u):
        return np.sqrt(np.einsum("ti,ti->t", u, (mass @ u.T).T))

    difference = norms(states["reuse"] - states["lu-each-iteration"]).max()
    assert difference <= AGREEMENT * norms(states["lu-each-iteration"]).max()


def test_solves_follow_the_newton_contraction_up_to_the_cap():
    """With ``contraction_cap`` set, a solve stops at ``NEWTON_FRACTION · c ‖R‖`` for the
    last Newton contraction c (at most the cap), in fewer GMRES iterations; without it (held
    objects) the contraction is not followed."""
    rng = np.random.default_rng(7)
    n = 80
    lap = sp.diags([-np.ones(n - 1), 4.0 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1])
    base = sp.csr_matrix(10.0 * sp.identity(n))
    K = sp.csr_matrix(lap * 1.3 + 0.3 * sp.diags(rng.uniform(size=n)))
    R = np.random.default_rng(1).normal(size=n)
    iterations, residuals = {}, {}
    for cap in (0.0, CONTRACTION_CAP):
        solver = ReusedFactorSolver()
        solver(base, sp.csr_matrix(lap), rng.normal(size=n))  # the factor of the first J
        solver.newton_contraction, solver.contraction_cap = 0.5, cap  # a stalling Newton
        before = solver.inner_iterations
        delta = solver(base, K, R)
        iterations[cap] = solver.inner_iterations - before
        residuals[cap] = np.linalg.norm((base + K) @ delta - R) / np.linalg.norm(R)
    assert residuals[0.0] <= 1e-10
    assert 1e-3 * NEWTON_FRACTION * CONTRACTION_CAP < residuals[CONTRACTION_CAP]
    assert residuals[CONTRACTION_CAP] <= NEWTON_FRACTION * CONTRACTION_CAP * (1 + 1e-6)
    assert iterations[CONTRACTION_CAP] < iterations[0.0]


def test_compiled_kabsch_fit_equals_the_polar_decomposition(box):
    """The compiled fit's centre and rotation equal the mass-weighted centre and the polar
    factor of ``Σ M₁ (x − c) X̄ᵀ`` from numpy's SVD, a reflected shape included."""
    scalar = sp.csr_matrix(mass_matrix(box, 1000.0)[0::3, 0::3])
    fit = KabschFit(scalar, box.points)
    rng = np.random.default_rng(9)
    for sign in (1.0, -1.0):
        R = rotation([0.3, -1.0, 2.0], 2.5)
        positions = sign * (box.points @ R.T) + 0.01 * rng.normal(size=box.points.shape) + 1.0
        center, got = fit(positions)
        weights = np.asarray(scalar.sum(axis=1)).ravel() / scalar.sum()
        np.testing.assert_allclose(center, weights @ positions, rtol=1e-13)
        A = (positions - center).T @ (scalar @ (box.points - weights @ box.points))
        left, _, right = np.linalg.svd(A)
        expected = left @ np.diag([1.0, 1.0, np.sign(np.linalg.det(left @ right))]) @ right
        np.testing.assert_allclose(got, expected, atol=1e-13)
        assert np.linalg.det(got) == pytest.approx(1.0)
