"""Free bodies: rigid frame, fictitious-force tensors, conservation laws and closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg as sla
from scipy.integrate import solve_ivp

from lbshape.dynamics.contact import ContactPlane, PlaneContact
from lbshape.dynamics.fictitious import frame_tensors
from lbshape.dynamics.free_body import FreeBodySimulation, FreeLoad
from lbshape.dynamics.loads import TimedLoad, TimeProfile, gravity_pattern
from lbshape.dynamics.reduced import ReducedSimulation
from lbshape.dynamics.rigid_frame import cayley, orthonormality_error, rotate
from lbshape.elastic.element_kernels import FullSpaceElasticity, mass_matrix
from lbshape.elastic.materials import Material
from lbshape.elastic.reduced_forces import ReducedForceModel
from lbshape.errors import LbshapeError, SolverError
from lbshape.geometry.primitives import structured_box

SIZE = (0.2, 0.2, 0.6)  # m: a square-section bar, symmetric top about z


class Body:
    """A small free bar with a linear-mode basis (rigid modes removed) and exact forces."""

    def __init__(self, *, young: float = 1e6, r: int = 8):
        self.mesh = structured_box(SIZE, (2, 2, 4))
        self.material = Material(model="stvk", young=young, poisson=0.3, density=1000.0)
        self.mass = mass_matrix(self.mesh, self.material.density)
        n3 = 3 * self.mesh.n_vertices
        K = FullSpaceElasticity(self.mesh, self.material).tangent(np.zeros(n3))
        _, V = sla.eigh(K.toarray(), self.mass.toarray())
        self.U = V[:, 6:6 + r]
        self.elastic = ReducedForceModel(self.mesh.points, self.mesh.tets, self.material, self.U,
                                         np.arange(self.mesh.n_tets), np.ones(self.mesh.n_tets))
        self.frame = frame_tensors(self.mesh.points, self.mesh.tets, self.mass, self.U)

    def simulation(self, **options) -> FreeBodySimulation:
        return FreeBodySimulation(self.elastic, self.frame, **options)

    def vertex_momenta(self, sim: FreeBodySimulation) -> tuple[np.ndarray, np.ndarray]:
        """(p, L about c) from the n vertices' world positions and velocities."""
        n = self.mesh.n_vertices
        R = sim.rigid.rotation
        y = self.mesh.points - self.frame.center + (self.U @ sim.q).reshape(n, 3)
        omega = sim.omega()
        velocity = sim.rigid.momentum / self.frame.mass + (
            np.cross(omega, y) + (self.U @ sim.qd).reshape(n, 3)) @ R.T
        momentum = (self.mass @ velocity.ravel()).reshape(n, 3)
        arm = y @ R.T
        return momentum.sum(axis=0), np.cross(arm, momentum).sum(axis=0)


@pytest.fixture(scope="module")
def soft():
    return Body()


@pytest.fixture(scope="module")
def stiff():
    return Body(young=1e10)


def test_frame_tensors_match_vertex_sums(soft):
    """I(q) and h(q, q̇) from the small tensors equal the n-sized mass-weighted sums."""
    rng = np.random.default_rng(3)
    q, qd = 0.05 * rng.standard_normal(8), rng.standard_normal(8)
    n = soft.mesh.n_vertices
    y = soft.mesh.points - soft.frame.center + (soft.U @ q).reshape(n, 3)
    My = (soft.mass @ y.ravel()).reshape(n, 3)
    Y = y.T @ My
    inertia = np.trace(Y) * np.eye(3) - Y
    h = np.cross(y, (soft.mass @ (soft.U @ qd)).reshape(n, 3)).sum(axis=0)
    np.testing.assert_allclose(soft.frame.inertia(q), inertia, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(soft.frame.relative_momentum(q, qd), h, rtol=1e-10, atol=1e-12)
    # the box's rest inertia is the continuum one (P1 integrates quadratics exactly)
    m = soft.frame.mass
    a, b, c = SIZE
    expected = m / 12 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])
    np.testing.assert_allclose(soft.frame.inertia0, expected, rtol=1e-12, atol=1e-12)


def test_fictitious_forces_match_vertex_accelerations(soft):
    """Centrifugal, Euler and Coriolis forces are Uᵀ M of the frame accelerations."""
    rng = np.random.default_rng(4)
    q, qd = 0.05 * rng.standard_normal(8), rng.standard_normal(8)
    omega, omega_dot = rng.standard_normal(3), rng.standard_normal(3)
    n = soft.mesh.n_vertices
    y = soft.mesh.points - soft.frame.center + (soft.U @ q).reshape(n, 3)
    ud = (soft.U @ qd).reshape(n, 3)
    field = (np.cross(omega, np.cross(omega, y)) + np.cross(omega_dot, y)
             + 2 * np.cross(omega, ud))
    expected = soft.U.T @ (soft.mass @ field.ravel())
    centrifugal, _ = soft.frame.centrifugal(q, omega)
    euler, _ = soft.frame.euler(q, omega_dot)
    got = centrifugal + euler + soft.frame.coriolis(omega) @ qd
    np.testing.assert_allclose(got, expected, rtol=1e-10, atol=1e-12 * np.abs(expected).max())


def test_cayley_rotation_step_invariants():
    rng = np.random.default_rng(5)
    inertia = np.diag([1.0, 2.0, 3.5])
    Pi = rng.standard_normal(3)
    R = np.eye(3)
    energy0 = 0.5 * Pi @ np.linalg.solve(inertia, Pi)
    for _ in range(2000):
        R, Pi1, _ = rotate(R, Pi, inertia, np.zeros(3), 0.01)
        Pi = Pi1
    assert orthonormality_error(R) <= 1e-12
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)
    energy = 0.5 * Pi @ np.linalg.solve(inertia, Pi)
    assert abs(energy - energy0) <= 1e-12 * energy0, energy - energy0
    np.testing.assert_allclose(cayley(np.zeros(3)), np.eye(3))


def test_free_body_keeps_momenta_and_rotation(soft):
    """No loads, no contact: p and L (from the vertices) drift ≤ 1e-6 over 1000 steps."""
    sim = soft.simulation(dt=1e-3, velocity=(1.0, 0.0, 0.5), angular_velocity=(3.0, 1.0, 8.0),
                          q0=0.02 * np.ones(8))
    p0, L0 = soft.vertex_momenta(sim)
    np.testing.assert_allclose(L0, sim.rigid.angular_momentum, rtol=1e-12)
    worst_p = worst_L = worst_R = 0.0
    for index in range(1000):
        sim.step()
        if index % 10:
            continue
        p, L = soft.vertex_momenta(sim)
        worst_p = max(worst_p, np.linalg.norm(p - p0) / np.linalg.norm(p0))
        worst_L = max(worst_L, np.linalg.norm(L - L0) / np.linalg.norm(L0))
        worst_R = max(worst_R, orthonormality_error(sim.rigid.rotation))
    assert worst_p <= 1e-6, worst_p
    assert worst_L <= 1e-6, worst_L
    assert worst_R <= 1e-12, worst_R
    assert np.abs(sim.q - 0.02).max() > 1e-3  # the deformation did move


def test_initial_state_from_world_velocities(soft):
    sim = soft.simulation(dt=1e-3, velocity=(1.0, 2.0, 3.0), angular_velocity=(0.5, -1.0, 2.0))
    np.testing.assert_allclose(sim.rigid.momentum, soft.frame.mass * np.array([1.0, 2.0, 3.0]))
    np.testing.assert_allclose(sim.omega(), [0.5, -1.0, 2.0], rtol=1e-12)
    with pytest.raises(LbshapeError, match="3-vectors"):
        soft.simulation(dt=1e-3, velocity=(1.0, 2.0))


def test_spin_energy_error_is_first_order(soft):
    """Undamped spinning free body: torque-free rotation is exact, the staggered
    rigid/deformation coupling has a bounded energy error of first order in dt."""
    errors = []
    for dt in (2e-3, 1e-3, 5e-4):
        sim = soft.simulation(dt=dt, angular_velocity=(8.0, 0.0, 0.0))
        record = sim.run(int(round(0.25 / dt)))
        assert record.stable, record.message
        energy = np.asarray(record.energies)
        errors.append(np.abs(energy - energy[0]).max() / energy[0])
    rates = np.log2(np.asarray(errors[:-1]) / np.asarray(errors[1:]))
    assert max(errors) <= 1e-3, errors
    assert np.all(rates >= 0.8), (errors, rates)


def test_stiff_symmetric_top_matches_closed_form(stiff):
    """Torque-free symmetric top: the symmetry axis precesses about L at |L| / I₁."""
    sim = stiff.simulation(dt=1e-3, angular_velocity=(2.0, 0.0, 10.0))
    I1 = stiff.frame.inertia0[0, 0]
    L = sim.rigid.angular_momentum.copy()
    record = sim.run(1000)
    assert record.stable, record.message
    axis = L / np.linalg.norm(L)
    rate = np.linalg.norm(L) / I1
    worst = 0.0
    for t, R in zip(record.times, record.rotations, strict=True):
        expected = _rotate_about(axis, rate * t) @ np.array([0.0, 0.0, 1.0])
        worst = max(worst, float(np.linalg.norm(R[:, 2] - expected)))
    # body ω⊥ turns at Ω = (I₃ − I₁)/I₁ ω₃ in the body frame (Euler equations)
    omega = sim.omega()
    I3 = stiff.frame.inertia0[2, 2]
    angle = math.atan2(omega[1], omega[0])
    expected_angle = (I3 - I1) / I1 * 10.0 * record.times[-1]
    assert worst <= 2e-3, worst
    assert abs(math.remainder(angle - expected_angle, 2 * math.pi)) <= 2e-3


def test_rotation_under_a_torque_is_split_about_the_impulse(stiff):
    """A couple about the stiff bar's axis (the world forces ``M α ẑ × X̄``, torque
    ``α I₃ cos φ``): the angle follows ``φ̈ = α cos φ`` to 1e-5 rad at Δt = 5 ms. A kick
    then a rotation with the end-of-step momentum would be first order, ``α Δt T / 2``
    = 2.5e-3 rad ahead."""
    X = stiff.mesh.points - stiff.frame.center
    alpha, duration = 20.0, 0.05
    field = alpha * np.column_stack([-X[:, 1], X[:, 0], np.zeros(len(X))])
    load = FreeLoad.from_pattern(stiff.mass @ field.ravel(), stiff.U, X, TimeProfile())
    exact = solve_ivp(lambda t, y: [y[1], alpha * math.cos(y[0])], (0.0, duration),
                      [0.0, 0.0], rtol=1e-12, atol=1e-14, dense_output=True)
    for dt in (5e-3, 2.5e-3):
        record = stiff.simulation(dt=dt, loads=[load]).run(int(round(duration / dt)))
        assert record.stable, record.message
        angle = np.array([math.atan2(R[1, 0], R[0, 0]) for R in record.rotations])
        error = np.abs(angle - exact.sol(np.asarray(record.times))[0]).max()
        assert error <= 1e-5, (dt, error, alpha * dt * duration / 2)


def test_ballistic_throw_is_exact(soft):
    """Gravity on a free body: parabola of the centre of mass, no deformation, spin kept."""
    g = np.array([0.0, 0.0, -9.81])
    load = FreeLoad.from_pattern(gravity_pattern(soft.mass, g), soft.U,
                                 soft.mesh.points - soft.frame.center, TimeProfile())
    v0, w0 = np.array([2.0, 0.5, 4.0]), np.array([0.0, 3.0, 0.0])
    sim = soft.simulation(dt=1e-3, loads=[load], velocity=v0, angular_velocity=w0)
    record = sim.run(500)
    t = np.asarray(record.times)[:, None]
    expected = soft.frame.center + v0 * t + 0.5 * g * t**2
    np.testing.assert_allclose(np.asarray(record.centers), expected, rtol=0, atol=1e-12)
    assert np.abs(np.asarray(record.states)).max() <= 1e-3  # only centrifugal deformation
    np.testing.assert_allclose(record.angular_momenta[-1], record.angular_momenta[0],
                               rtol=1e-12, atol=1e-12)


def test_fast_spin_at_large_step_is_stable(stiff):
    """20 rad/s with dt = 1/60 s: stable, momenta kept."""
    sim = stiff.simulation(dt=1.0 / 60.0, angular_velocity=(1.0, 20.0, 2.0))
    record = sim.run(300)
    assert record.stable, record.message
    L = np.asarray(record.angular_momenta)
    assert np.abs(L - L[0]).max() <= 1e-9 * np.linalg.norm(L[0])


def test_rotation_failure_names_the_step(stiff):
    """A spin far too fast for the step stops with a one-line error naming the step."""
    sim = stiff.simulation(dt=0.5, angular_velocity=(0.0, 300.0, 1.0))
    with pytest.raises(SolverError, match=r"step 1 "):
        sim.step()


class _Unbounded:
    """A force model of energy ``½ k |q|² − ¼ c |q|⁴`` (J): a spring that gives way, its
    energy unbounded below past the barrier |q|² = k/c (a reduced model outside the
    deformations it holds)."""

    def __init__(self, r: int, k: float, c: float):
        self.r, self.k, self.c = r, k, c

    def energy(self, q):
        s = float(q @ q)
        return 0.5 * self.k * s - 0.25 * self.c * s * s

    def force_and_tangent(self, q):
        q = np.asarray(q, dtype=float)
        s = float(q @ q)
        force = (self.k - self.c * s) * q
        tangent = (self.k - self.c * s) * np.eye(self.r) - 2.0 * self.c * np.outer(q, q)
        return force, tangent


def test_an_energy_falling_far_below_zero_stops_the_run(soft):
    """Thrown over the barrier of a model whose energy falls without bound, the body
    stops with a one-line error naming the step once the elastic energy is below −10 x
    the energy put in (step 222), before its kinetic energy reaches the blow-up check
    (step 272 without this one; a body that sinks with little motion, as the car meshed
    at half its size did in a corner hit, never reaches it)."""
    r = soft.U.shape[1]
    model = _Unbounded(r, k=100.0, c=100.0)  # barrier at |q| = 1, 25 J high
    qd0 = np.zeros(r)
    qd0[0] = 10.0  # 50 J of deformation's kinetic energy: over the barrier
    sim = FreeBodySimulation(model, soft.frame, dt=1e-3, qd0=qd0)
    with pytest.raises(SolverError, match=r"the elastic energy fell to -\S+ J \(below -10 x "
                                          r"budget \S+ J\) at step \d+ \(t = "):
        for _ in range(2000):
            sim.step()
    assert sim.steps_taken > 10  # it crossed the barrier first


def _rotate_about(axis: np.ndarray, angle: float) -> np.ndarray:
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


# ------------------------------------------------------------------ contact
def _gravity(body: Body) -> FreeLoad:
    return FreeLoad.from_pattern(gravity_pattern(body.mass, np.array([0.0, 0.0, -9.81])),
                                 body.U, body.mesh.points - body.frame.center, TimeProfile())


#: 1/m²: the bar's end face carries 9 surface vertices on 0.04 m², so a plane of
#: stiffness k × PER_AREA (N/m³) holds it as k per vertex (N/m) would
PER_AREA = 225.0


def _contact(body: Body, point, normal, stiffness: float) -> PlaneContact:
    """A plane of ``stiffness`` N/m per end-face vertex (× :data:`PER_AREA` per area)."""
    return PlaneContact.for_mesh([ContactPlane(point, normal, stiffness * PER_AREA)],
                                 body.mesh.points,
                                 body.mesh.tets, body.U, center=body.frame.center)


def test_contact_forces_are_the_penalty_energy_gradient(soft):
    contact = _contact(soft, (0.0, 0.0, 0.05), (0.0, 0.3, 1.0), 1e4)
    rng = np.random.default_rng(6)
    q = 0.05 * rng.standard_normal(8)
    center = soft.frame.center + np.array([0.0, 0.0, 0.01])
    R = cayley(np.array([0.1, -0.2, 0.3]))
    res = contact.evaluate(center, R, q)
    assert res.active > 0
    h = 1e-7
    # the vertices' normal forces F_i, lumped stiffnesses S_i and arms of the evaluation
    n = contact.normals[0]
    F, S = contact._loads[0, 1].copy(), contact._loads[0, 2].copy()
    arms = contact._arms.copy()
    g = np.einsum("iaj,a->ij", contact.basis, R.T @ n)
    np.testing.assert_allclose(res.stiffness_q, np.einsum("i,ij,ik->jk", S, g, g),
                               rtol=1e-12, atol=1e-12 * np.abs(res.stiffness_q).max())
    np.testing.assert_allclose(res.torque, np.cross(arms, n).T @ F, rtol=1e-12, atol=1e-12)
    for j in range(3):
        dq = np.zeros(8)
        dq[j] = h
        up = contact.evaluate(center, R, q + dq)
        down = contact.evaluate(center, R, q - dq)
        assert (down.energy - up.energy) / (2 * h) == pytest.approx(res.generalized[j], rel=1e-5)
    for j in range(3):
        shift = np.zeros(3)
        shift[j] = h
        up = contact.evaluate(center + shift, R, q)
        down = contact.evaluate(center - shift, R, q)
        assert (down.energy - up.energy) / (2 * h) == pytest.approx(res.force[j], rel=1e-5,
                                                                     abs=1e-6)
    # a turn about the plane's normal leaves the triangles' facing shares: the torque's
    # component along n is the energy's derivative
    turn = cayley(h * n)
    up = contact.evaluate(center, turn @ R, q)
    down = contact.evaluate(center, turn.T @ R, q)
    assert (down.energy - up.energy) / (2 * h) == pytest.approx(res.torque @ n, rel=1e-5,
                                                                 abs=1e-6)


def test_bounding_sphere_skips_the_vertex_loop(soft):
    contact = _contact(soft, (0.0, 0.0, -5.0), (0.0, 0.0, 1.0), 1e4)
    sim = soft.simulation(dt=1e-3, contact=contact, angular_velocity=(0.0, 2.0, 0.0))
    sim.run(20)
    assert contact.evaluated == 0 and contact.skipped >= 20


def test_dropped_body_comes_to_rest_on_the_floor(soft):
    """Penetration at rest ≤ weight / stiffness; the bounce dies out, jitter does not grow.

    The contact is conservative (trapezoidal impulse, no numerical damping): the bounce
    dies by the deformation's damping alone. Over the last 0.5 s of 2 s the height's range
    shrinks to 0.56 of the 0.5 s before (0.60 at dt = 1 ms, 0.61 at 0.5 ms), limit 0.75;
    at the end the body moves at 4.1 % of its largest speed (3.9 %, 6.0 %), limit 8 %.
    """
    k = 1e5
    contact = _contact(soft, (0.0, 0.0, -0.02), (0.0, 0.0, 1.0), k)
    sim = soft.simulation(dt=2e-3, loads=[_gravity(soft)], contact=contact, beta=0.001,
                          angular_velocity=(0.3, 0.2, 0.0))
    record = sim.run(1000)
    assert record.stable, record.message
    weight = soft.frame.mass * 9.81
    depth = np.asarray(record.contact_depth)
    assert 0 < depth[-1] <= weight / k, depth[-1]
    z = np.asarray(record.centers)[:, 2]
    assert np.ptp(z[-250:]) <= 0.75 * np.ptp(z[-500:-250]) + 1e-9
    speeds = np.linalg.norm(np.asarray(record.momenta), axis=1) / soft.frame.mass
    assert speeds[-1] <= 0.08 * speeds.max(), (speeds[-1], speeds.max())


def test_contact_steps_are_sub_steps(soft):
    """While a plane touches the body a step of Δt is k steps of Δt/k: a bar dropped (no
    spin, so its flight is exact at either step) onto a tilted floor follows the run at
    Δt/4 to round-off through its first contact, the step it begins in taken again in
    sub-steps; in flight a step is one pass."""
    contact = _contact(soft, (0.0, 0.0, -0.011), (0.1, 0.0, 1.0), 1e5)
    whole = soft.simulation(dt=2e-3, loads=[_gravity(soft)], contact=contact, beta=0.001,
                            contact_dt=5e-4)
    fine_contact = _contact(soft, (0.0, 0.0, -0.011), (0.1, 0.0, 1.0), 1e5)
    fine = soft.simulation(dt=5e-4, loads=[_gravity(soft)], contact=fine_contact,
                           beta=0.001, contact_dt=5e-4)
    assert (whole.contact_substeps, fine.contact_substeps) == (4, 1)
    taken = []
    while True:
        whole.step()
        for _ in range(4):
            fine.step()
        taken.append(whole.substeps)
        if taken[-1] == 1 and 4 in taken:
            break  # the first whole step after the contact: flight steps differ from here
        assert whole.time == pytest.approx(fine.time, abs=1e-12)
        scale = max(np.abs(fine.q).max(), 1e-6)  # q is round-off (1e-19) in flight
        np.testing.assert_allclose(whole.q, fine.q, rtol=0, atol=1e-9 * scale)
        np.testing.assert_allclose(whole.rigid.momentum, fine.rigid.momentum, rtol=1e-9,
                                   atol=1e-12)
        np.testing.assert_allclose(whole.rigid.angular_momentum,
                                   fine.rigid.angular_momentum, rtol=1e-9, atol=1e-12)
    first = taken.index(4)
    assert first > 5 and set(taken[:first]) == {1}  # it fell in whole steps
    assert taken.count(4) >= 5  # the contact lasted several steps, every one sub-stepped
    assert np.abs(fine.rigid.angular_momentum).max() > 1e-3  # the edge hit turned it


def test_contact_step_sets_the_sub_steps(soft):
    """k = ceil(Δt / contact_dt): the default 1/3 ms makes a 1 ms step 3 sub-steps and
    a 60 Hz step 67; a contact_dt that is not a positive time is refused."""
    assert soft.simulation(dt=1e-3).contact_substeps == 3
    assert soft.simulation(dt=1.0 / 60.0).contact_substeps == 50
    assert soft.simulation(dt=1e-3, contact_dt=1e-3).contact_substeps == 1
    assert soft.simulation(dt=1e-4).contact_substeps == 1
    for bad in (0.0, -1e-3, float("nan")):
        with pytest.raises(LbshapeError, match="contact_dt"):
            soft.simulation(dt=1e-3, contact_dt=bad)


def test_resting_five_seconds_at_large_step(soft):
    """Dropped 0.3 m (2.43 m/s at landing) at 60 Hz steps, its contact in 1/3 ms
    sub-steps: after 5 s it rests on the floor (speed 1.5e-8 m/s, limit 1e-3). The
    resolved contact is conservative, so the deformation's damping ends the bounce: at
    β = 0.01 it does within the 5 s; at β = 0.001 the bar still bounced at up to
    0.3-0.8 m/s in the last second (the amount depending on round-off, the BLAS threads)."""
    contact = _contact(soft, (0.0, 0.0, -0.3), (0.0, 0.0, 1.0), 1e5)
    sim = soft.simulation(dt=1.0 / 60.0, loads=[_gravity(soft)], contact=contact, beta=0.01)
    record = sim.run(300)
    assert record.stable, record.message
    assert 0 < record.contact_depth[-1] <= soft.frame.mass * 9.81 / 1e5
    speeds = np.linalg.norm(np.asarray(record.momenta)[-60:], axis=1) / soft.frame.mass
    assert speeds.max() <= 1e-3, speeds.max()


def test_fast_impact_into_a_wall(soft):
    """10 m/s into a wall at dt = 1 ms: stable, rebounds, never passes through."""
    # the wall sits off the 10 mm the bar travels per step, so no step lands at exactly
    # zero gap (where "touching" would hinge on round-off)
    contact = _contact(soft, (0.2537, 0.0, 0.0), (-1.0, 0.0, 0.0), 1e6)
    sim = soft.simulation(dt=1e-3, contact=contact, velocity=(10.0, 0.0, 0.0), beta=0.001)
    record = sim.run(100)
    assert record.stable, record.message
    assert record.momenta[-1][0] < 0.0  # bounced back
    assert max(record.contact_depth) <= contact.radius0
    p = np.asarray(record.momenta)
    assert np.abs(p[:, 1:]).max() == 0.0  # the wall pushes along its normal only
    assert abs(p[-1, 0]) <= abs(p[0, 0])  # penalty contact does not add energy


def test_a_whole_step_that_fails_in_contact_is_taken_in_sub_steps(soft):
    """20 m/s into a wall at 30 Hz: the whole step ends 0.42 m behind it and fails
    (contact_dt = dt stops the run there); taken again in 1/3 ms sub-steps it rebounds
    at the speed of the 1 ms run (both 18.77 m/s: the 1 ms run's contact passes are as
    long; limit 2 %)."""
    def run(dt, **options):
        contact = _contact(soft, (0.3537, 0.0, 0.0), (-1.0, 0.0, 0.0), 1e6)
        sim = soft.simulation(dt=dt, contact=contact, velocity=(20.0, 0.0, 0.0),
                              beta=0.001, **options)
        return sim.run(int(round(0.3 / dt)))

    whole = run(1.0 / 30.0, contact_dt=1.0 / 30.0)
    assert not whole.stable and "contact failed at step 1" in whole.message, whole.message
    coarse, fine = run(1.0 / 30.0), run(1e-3)
    assert coarse.stable and fine.stable
    rebound, reference = (-record.momenta[-1][0] / soft.frame.mass for record in (coarse, fine))
    assert rebound == pytest.approx(reference, rel=0.02) and reference > 15.0


def test_contact_on_a_fixed_object(soft):
    """A hanging bar sags onto a plane just under it: the plane stops it."""
    top = np.flatnonzero(soft.mesh.points[:, 2] > 0.599)
    mesh, mass = soft.mesh, soft.mass
    K = FullSpaceElasticity(mesh, soft.material).tangent(np.zeros(3 * mesh.n_vertices))
    free = np.setdiff1d(np.arange(3 * mesh.n_vertices), (3 * top[:, None] + np.arange(3)).ravel())
    w, V = sla.eigh(K.toarray()[np.ix_(free, free)], mass.toarray()[np.ix_(free, free)])
    U = np.zeros((3 * mesh.n_vertices, 6))
    U[free] = V[:, :6]
    elastic = ReducedForceModel(mesh.points, mesh.tets, soft.material, U,
                                np.arange(mesh.n_tets), np.ones(mesh.n_tets))
    g = TimedLoad(U.T @ gravity_pattern(mass, np.array([0.0, 0.0, -9.81])), TimeProfile())
    gap = 1e-4
    planes = [ContactPlane((0.0, 0.0, -gap), (0.0, 0.0, 1.0), 1e6 * PER_AREA)]
    contact = PlaneContact.for_mesh(planes, mesh.points, mesh.tets, U)
    sags = []
    for c in (None, contact):
        sim = ReducedSimulation(elastic, r=6, dt=1e-3, loads=[g], alpha=20.0, contact=c)
        record = sim.run(300)
        assert record.stable, record.message
        sags.append(-float((U @ record.states[-1]).reshape(-1, 3)[:, 2].min()))
    assert sags[0] > 5 * gap  # without the plane the bottom sags well below it
    assert sags[1] <= gap + soft.frame.mass * 9.81 / 1e6
