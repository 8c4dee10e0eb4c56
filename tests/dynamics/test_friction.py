"""Coulomb friction of plane contact: the kernels against their derivatives, and a stiff
block on a plane against the closed forms, in the reduced free body and the full-space
reference.

A 0.1 m cube (1 kg, E = 1e8 Pa: it deforms by ~1e-7 of its size) rests on a plane whose
penalty stiffness it sits at its static depth in (no drop); gravity is tilted by θ,
which is a slope of angle θ. Closed forms: it stays put when tan θ < μ and slides with
``a = g (sin θ − μ cos θ)`` when tan θ > μ; thrown at v₀ along a level floor it stops
after ``v₀² / (2 μ g)``. The regularised friction (ε = ``SLIP_SPEED``) creeps at
``ε s / √(1 − s²)`` (``s = tan θ / μ < 1``): held on tan θ = ½ by μ = 0.7 the block
must move less than 1 mm in 0.5 s.

Limits (``friction.*`` in tests/golden.toml, measured values there): travel held
1 mm, slide acceleration 2 % (θ = 30° and tan θ = ½, μ = 0.3), stopping distance
(v₀ = 2 m/s, μ = 0.5) 2 %.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import scipy.linalg as sla
from conftest import golden

from lbshape.dynamics.contact import SLIP_SPEED, ContactPlane, PlaneContact, friction_force
from lbshape.dynamics.fictitious import frame_tensors
from lbshape.dynamics.free_body import FreeBodySimulation, FreeLoad
from lbshape.dynamics.full import FullSpaceContact, FullSpaceSimulator
from lbshape.dynamics.integrators import make_stepper
from lbshape.dynamics.loads import TimedLoad, TimeProfile, gravity_pattern
from lbshape.dynamics.reduced import ReducedSimulation
from lbshape.dynamics.rigid_frame import cayley
from lbshape.elastic.element_kernels import FullSpaceElasticity, mass_matrix
from lbshape.elastic.materials import Material
from lbshape.elastic.reduced_forces import ReducedForceModel
from lbshape.errors import LbshapeError, SolverError
from lbshape.geometry.primitives import structured_box
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import reduced_simulation
from lbshape.scene import load_scene
from lbshape.scene.reader import scene_from_dict
from lbshape.scene.variants import without_examples

G = 9.81  # m/s²
SIDE = 0.1  # m
STIFFNESS = 1.8e7  # N/m³ (per area; 2e4 N/m per bottom vertex): θ = ½ at 1 ms
DT = 1e-3  # s


class Block:
    """The stiff cube with 6 linear modes (rigid modes removed) and exact forces."""

    def __init__(self):
        self.mesh = structured_box((SIDE, SIDE, SIDE), (2, 2, 2))
        self.material = Material(model="stvk", young=1e8, poisson=0.3, density=1000.0)
        self.mass = mass_matrix(self.mesh, self.material.density)
        n3 = 3 * self.mesh.n_vertices
        K = FullSpaceElasticity(self.mesh, self.material).tangent(np.zeros(n3))
        _, V = sla.eigh(K.toarray(), self.mass.toarray())
        self.U = V[:, 6:12]
        self.elastic = ReducedForceModel(self.mesh.points, self.mesh.tets, self.material,
                                         self.U, np.arange(self.mesh.n_tets),
                                         np.ones(self.mesh.n_tets))
        self.frame = frame_tensors(self.mesh.points, self.mesh.tets, self.mass, self.U)
        self.bottom = int(np.sum(self.mesh.points[:, 2] < 1e-12))
        weights = np.asarray(self.mass[0::3, 0::3].sum(axis=1)).ravel()
        self.weights = weights / weights.sum()

    def slide(self, theta: float, mu: float, *, v0: float = 0.0, duration: float,
              method: str, dt: float = DT, whole_steps: bool = False
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(times, centre-of-mass travel along x (m), its velocity (m/s)) of the block on
        a slope θ (tilted gravity) with friction μ, thrown at v₀ along x, steps of dt (s);
        ``whole_steps``: the reduced body's contact without sub-steps (contact_dt = dt)."""
        steps = int(round(duration / dt))
        if method == "reduced":
            sim = self.reduced(theta, mu, v0=v0, dt=dt, whole_steps=whole_steps)
            record = sim.run(steps)
            assert record.stable, record.message
            x = record.centers[:, 0] - record.centers[0, 0]
            return record.times, x, record.momenta[:, 0] / self.frame.mass
        n = self.mesh.n_vertices
        plane, pattern = self._slope(theta, mu)
        sim = FullSpaceSimulator(
            self.mesh, self.material, dt=dt, beta=1e-4,
            loads=[TimedLoad(pattern, TimeProfile())],
            contact=FullSpaceContact([plane], self.mesh.points, self.mesh.tets),
            initial_velocity=np.tile([v0, 0.0, 0.0], (n, 1)))
        states = []
        sim.run(steps, on_step=lambda i, t, u: states.append(
            (t, u[:, 0] @ self.weights, sim.stepper.v.reshape(n, 3)[:, 0] @ self.weights)))
        times, x, v = (np.array([0.0] + [s[k] for s in states]) for k in range(3))
        v[0] = v0
        return times, x, v

    def _slope(self, theta: float, mu: float) -> tuple[ContactPlane, np.ndarray]:
        """The plane the block rests on at its static depth, and the tilted gravity's
        nodal pattern (3n,)."""
        gravity = G * np.array([math.sin(theta), 0.0, -math.cos(theta)])
        depth = self.frame.mass * G * math.cos(theta) / (SIDE * SIDE * STIFFNESS)
        plane = ContactPlane((0.0, 0.0, depth), (0.0, 0.0, 1.0), STIFFNESS, mu)
        return plane, gravity_pattern(self.mass, gravity)

    def reduced(self, theta: float, mu: float, *, v0: float = 0.0, dt: float = DT,
                whole_steps: bool = False) -> FreeBodySimulation:
        """The reduced block on the slope (as :meth:`slide`)."""
        plane, pattern = self._slope(theta, mu)
        contact = PlaneContact.for_mesh([plane], self.mesh.points, self.mesh.tets, self.U,
                                        center=self.frame.center)
        load = FreeLoad.from_pattern(pattern, self.U, self.mesh.points - self.frame.center,
                                     TimeProfile())
        return FreeBodySimulation(self.elastic, self.frame, dt=dt, loads=[load],
                                  contact=contact, beta=1e-4, velocity=(v0, 0.0, 0.0),
                                  **({"contact_dt": dt} if whole_steps else {}))


@pytest.fixture(scope="module")
def block():
    return Block()


# ------------------------------------------------------------------ kernels
def test_friction_kernel_forces_and_rates(block):
    """The compiled friction equals the regularised Coulomb law vertex by vertex; its
    rigid rate matrix C₆ and its deformation tangent equal finite differences."""
    r = block.U.shape[1]
    mu, k = 0.4, 3e6
    plane = ContactPlane((0.0, 0.0, 0.0), (0.1, -0.2, 1.0), k, mu)
    contact = PlaneContact.for_mesh([plane], block.mesh.points, block.mesh.tets, block.U,
                                    center=block.frame.center)
    frictionless = PlaneContact.for_mesh([ContactPlane(plane.point, plane.normal, k)],
                                         block.mesh.points, block.mesh.tets, block.U,
                                         center=block.frame.center)
    rng = np.random.default_rng(5)
    q = 1e-3 * rng.standard_normal(r)
    center = block.frame.center + np.array([0.01, 0.0, -0.035])
    R = cayley(np.array([0.05, -0.1, 0.2]))
    velocity, omega = np.array([0.3, -0.1, 0.02]), np.array([0.5, 1.0, -2.0])
    qd = 0.05 * rng.standard_normal(r)
    got = contact.evaluate(center, R, q, velocity=velocity, omega=omega, qd=qd)
    base = frictionless.evaluate(center, R, q)
    assert got.active > 0
    # the law: per loaded vertex f_t = −μ F_i T (friction_force, the full model's), F_i
    # the vertex's normal force (N), its share of the pressure over the triangles
    n = contact.normals[0]
    y = contact.body_points + contact.basis @ q
    arm = y @ R.T
    normal, stiffness = contact._loads[0, 1], contact._loads[0, 2]
    hit = stiffness > 0
    assert np.allclose(base.force, n * normal[hit].sum(), rtol=1e-12)
    w = velocity + np.cross(omega, arm[hit]) + (contact.basis[hit] @ qd) @ R.T
    f_t, _, _ = friction_force(w, n, normal[hit], mu)
    np.testing.assert_allclose(got.force - base.force, f_t.sum(axis=0), rtol=1e-12,
                               atol=1e-12)
    np.testing.assert_allclose(got.torque - base.torque, np.cross(arm[hit], f_t).sum(axis=0),
                               rtol=1e-12, atol=1e-12)
    G_hit = np.einsum("ab,ibj->iaj", R, contact.basis[hit])
    np.testing.assert_allclose(got.generalized - base.generalized,
                               np.einsum("iaj,ia->j", G_hit, f_t), rtol=1e-12, atol=1e-12)
    assert np.abs(f_t @ n).max() < 1e-12  # tangential
    # C₆ = −∂(force, torque)/∂(v, ω) at fixed positions
    h = 1e-7
    for j in range(6):
        step = np.zeros(6)
        step[j] = h
        up = contact.evaluate(center, R, q, velocity=velocity + step[:3],
                              omega=omega + step[3:], qd=qd)
        down = contact.evaluate(center, R, q, velocity=velocity - step[:3],
                                omega=omega - step[3:], qd=qd)
        derivative = (np.r_[up.force, up.torque] - np.r_[down.force, down.torque]) / (2 * h)
        np.testing.assert_allclose(got.damping_rigid[:, j], -derivative, rtol=1e-5,
                                   atol=1e-6 * np.abs(got.damping_rigid).max())
    # deformation tangent: −∂generalized/∂q with q̇ = q̇₀ + rate (q − q₀), no spin
    rate = 2e3
    still = np.zeros(3)
    got = contact.evaluate(center, R, q, velocity=velocity, omega=still, qd=qd, rate=rate)
    h = 1e-8
    for j in range(r):
        step = np.zeros(r)
        step[j] = h
        up = contact.evaluate(center, R, q + step, velocity=velocity, omega=still,
                              qd=qd + rate * step)
        down = contact.evaluate(center, R, q - step, velocity=velocity, omega=still,
                                qd=qd - rate * step)
        # the normal force's share is lumped per vertex (S_i, the triangles' pairs
        # summed on the diagonal): within 2 % of the largest entry here (0.9 %)
        np.testing.assert_allclose(got.stiffness_q[:, j],
                                   -(up.generalized - down.generalized) / (2 * h),
                                   rtol=0, atol=0.02 * np.abs(got.stiffness_q).max())


def test_full_contact_tangent_is_consistent(block):
    """The full-space friction's tangent (with ∂v/∂u = rate) equals finite differences."""
    contact = FullSpaceContact([ContactPlane((0.0, 0.0, 0.001), (0.0, 0.2, 1.0), 2e4, 0.5)],
                               block.mesh.points, block.mesh.tets)
    rng = np.random.default_rng(1)
    n3 = 3 * block.mesh.n_vertices
    u0, v0, rate = 1e-4 * rng.standard_normal(n3), 0.01 * rng.standard_normal(n3), 2e3
    # the triangles' areas facing the plane held at u0 (their change is left out of K)
    x0 = contact.rest + u0.reshape(-1, 3)[contact.vertices]
    shares = contact.face_shares(x0, contact.normals[0])
    contact.face_shares = lambda x, n: shares

    def force(u):
        return contact.evaluate(u, v0 + rate * (u - u0), rate)

    u = u0 + 1e-6 * rng.standard_normal(n3)
    f, K, _ = force(u)
    K = K.toarray()
    h = 1e-9
    for j in range(n3):
        step = np.zeros(n3)
        step[j] = h
        np.testing.assert_allclose(K[:, j], (force(u + step)[0] - force(u - step)[0]) / (2 * h),
                                   rtol=0, atol=1e-6 * np.abs(K).max())
    assert np.abs(K - K.T).max() > 1e-3 * np.abs(K).max()  # friction is not symmetric


def test_zero_friction_ignores_the_motion(block):
    """μ = 0: the velocities change nothing and the rate matrix stays zero."""
    plane = ContactPlane((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), 2e4)
    assert plane.friction == 0.0
    contact = PlaneContact.for_mesh([plane], block.mesh.points, block.mesh.tets, block.U,
                                    center=block.frame.center)
    center = block.frame.center - np.array([0.0, 0.0, 0.01])
    q = np.zeros(block.U.shape[1])
    still = contact.evaluate(center, np.eye(3), q)
    moving = contact.evaluate(center, np.eye(3), q, velocity=(3.0, 1.0, 0.0),
                              omega=(0.0, 0.0, 5.0), qd=np.ones_like(q), rate=1e3)
    assert still.active > 0
    for key in ("force", "torque", "generalized", "stiffness_q", "damping_rigid"):
        assert np.array_equal(getattr(still, key), getattr(moving, key)), key
    assert not moving.damping_rigid.any()


def test_line_search_tames_a_saturating_force():
    """A force that saturates within a narrow band (F x / √(x² + ε²), as friction in its
    slip): full Newton updates jump across the band back and forth and never converge;
    the full reference's line search (halved updates) does, to the root."""
    force, eps = 1e3, 1e-3

    def force_and_tangent(x):
        s = np.sqrt(x * x + eps * eps)
        return force * x / s, np.diag(force * eps * eps / s**3)

    def stepper(line_search):
        return make_stepper("newmark", np.eye(1), force_and_tangent, dt=1.0, x0=np.array([0.5]),
                            v0=np.array([1.0]), line_search=line_search, energy_factor=None)

    with pytest.raises(SolverError, match="Newton did not converge"):
        stepper(False).step()
    damped = stepper(True)
    info = damped.step()
    x, a = damped.x[0], damped.a[0]
    assert abs(a + force * x / math.sqrt(x * x + eps * eps)) <= 1e-8 * force  # M a + f = 0
    assert info.iterations <= 20 and abs(x) < 0.02  # held within the band


# ------------------------------------------------------------- closed forms
@pytest.mark.parametrize("method", ["reduced", pytest.param("full", marks=pytest.mark.slow)])
def test_block_held_by_friction_stays(block, method):
    """A slope of tan θ = ½ and μ = 0.7 > tan θ: the block is held to the golden travel
    (1 mm) over 0.5 s (the regularisation's creep ε s / √(1 − s²) is 0.26 mm in that time
    at ε = 5e-4 m/s; ε = 1e-3 m/s held the full block to 2.3 mm only)."""
    theta, mu = math.atan(0.5), 0.7
    s = math.tan(theta) / mu
    creep = SLIP_SPEED * s / math.sqrt(1 - s * s)  # m/s
    times, x, v = block.slide(theta, mu, duration=0.5, method=method)
    assert times[-1] == pytest.approx(0.5)  # the run went the whole way
    assert np.abs(x).max() <= golden("friction.stick_travel").limit, (np.abs(x).max(), creep)
    # without friction it would have slid g sin θ t² / 2 = 0.55 m
    assert creep * times[-1] < 1e-3


def test_a_contact_pass_kicks_with_the_last_pass_friction_rate(block):
    """The first kick of a pass in contact takes the friction's effective rate (the
    deformation's answer to a change of slip counted) of the pass before it; the pass
    where the contact begins (here: the first step's whole pass, then its retake in
    passes), and the first after a reset, take the raw C₆ at t₀. The later sweeps of a
    pass take the rate of the sweep before them."""
    sim = block.reduced(math.atan(0.5), 0.7)
    computed, kicks = [], []
    compute, kick = sim._effective_friction_rate, sim._kick

    def record_rate(out):
        compute(out)
        computed.append(out.copy())

    def record_kick(index, t1, active, *, sweep, times):
        if active or sweep:  # the contact acts in this kick
            kicks.append((sweep, sim._kick_arrays.C6.copy(),
                          sim.contact.damping_rigid.copy(),
                          computed[-1] if computed else None))
        kick(index, t1, active, sweep=sweep, times=times)

    sim._effective_friction_rate, sim._kick = record_rate, record_kick
    for _ in range(2):
        kicks.clear()
        computed.clear()
        sim.run(20)
        firsts = [(C6, raw, last) for sweep, C6, raw, last in kicks if not sweep]
        assert len(firsts) == 61 and len(kicks) >= 120  # 3 passes a step, swept
        for C6, raw, _ in firsts[:2]:  # the whole pass and the retake's first: C₆
            assert np.array_equal(C6, raw)
        for C6, raw, last in firsts[2:] + [(C6, raw, last) for sweep, C6, raw, last
                                           in kicks if sweep]:
            assert np.array_equal(C6, last)
            assert np.abs(C6 - raw).max() > 1e-3 * np.abs(raw).max()  # not C₆ itself
        sim.reset()


def test_reduced_block_creep_converges_in_dt(block):
    """The held block's travel in whole steps (no contact sub-steps) of dt = 0.5 and
    0.25 ms: within the 1 mm target and within 15 % of each other (in whole 1 ms steps
    its rocking on the penalty grows: 1.10 mm; the default 1 ms step, its contact in
    1/3 ms sub-steps, is ``friction.stick_travel``)."""
    theta, mu = math.atan(0.5), 0.7
    travel = [np.abs(block.slide(theta, mu, duration=0.5, method="reduced", dt=dt,
                                 whole_steps=True)[1]).max()
              for dt in (5e-4, 2.5e-4)]
    assert max(travel) <= golden("friction.stick_travel_converged").limit, travel
    assert abs(travel[0] / travel[1] - 1) <= 0.15, travel


@pytest.mark.parametrize("theta", [math.radians(30.0), math.atan(0.5)])
@pytest.mark.parametrize("method", ["reduced", pytest.param("full", marks=pytest.mark.slow)])
def test_block_slides_at_the_coulomb_acceleration(block, method, theta):
    mu = 0.3
    times, x, v = block.slide(theta, mu, duration=0.6, method=method)
    first, last = np.searchsorted(times, 0.2), len(times) - 1  # slipping ≫ ε
    measured = (v[last] - v[first]) / (times[last] - times[first])
    expected = G * (math.sin(theta) - mu * math.cos(theta))
    limit = golden("friction.slide_acceleration").limit
    assert abs(measured / expected - 1) <= limit, (measured, expected)


@pytest.mark.parametrize("method", ["reduced", pytest.param("full", marks=pytest.mark.slow)])
def test_thrown_block_stops_after_the_coulomb_distance(block, method):
    mu, v0 = 0.5, 2.0
    times, x, v = block.slide(0.0, mu, v0=v0, duration=0.6, method=method)  # stops at 0.41 s
    distance = v0**2 / (2 * mu * G)
    limit = golden("friction.stopping_distance").limit
    assert abs(x[-1] / distance - 1) <= limit, (x[-1], distance)
    assert abs(v[-1]) <= 0.01 * v0


def test_zero_friction_slides_freely(block):
    """μ = 0 on a slope: the frictionless acceleration g sin θ."""
    theta = math.radians(20.0)
    times, x, v = block.slide(theta, 0.0, duration=0.3, method="reduced")
    measured = (v[-1] - v[0]) / times[-1]
    assert abs(measured / (G * math.sin(theta)) - 1) <= 1e-3, measured


# ------------------------------------------------------------------- inputs
_SCENE = {
    "name": "rubbing",
    "object": {"shape": "demo-bar"},
    "material": {"young": 1e6, "density": 1000.0},
    "reduced": {"m": 4, "r": 8, "s": 20},
    "planes": [{"point": [0.0, 0.0, -0.1], "normal": [0.0, 0.0, 1.0], "stiffness": 1e5,
                "friction": 0.4}],
}


def _scene(friction=None, **changes):
    plane = dict(_SCENE["planes"][0])
    if friction is None:
        del plane["friction"]
    else:
        plane["friction"] = friction
    return scene_from_dict({**_SCENE, "planes": [plane], **changes}, name="rubbing")


def test_scene_friction_key():
    assert _scene(0.4).planes[0].friction == 0.4
    assert _scene().planes[0].friction == 0.0  # default: frictionless
    assert _scene(0.4).runtime_fields()["planes"][0]["friction"] == 0.4
    assert _scene(0.0, fixed={"region": "z > 0.999"}).planes[0].friction == 0.0
    cases = [(-0.1, {}, "'planes[0].friction' must be >= 0, got -0.1"),
             ("high", {}, "'planes[0].friction' must be a number, got 'high'"),
             (True, {}, "'planes[0].friction' must be a number"),
             (float("inf"), {}, "'planes[0].friction' must be finite"),
             (0.4, {"fixed": {"region": "z > 0.999"}},
              "'planes[0].friction' acts on free bodies only")]
    for value, changes, words in cases:
        with pytest.raises(LbshapeError) as failure:
            _scene(value, **changes)
        message = str(failure.value)
        assert words in message and "\n" not in message, message


def test_scene_contact_step_key():
    """``[simulation] contact_dt`` reaches the reduced free body's sub-steps; it is refused
    where no free body touches a plane, and where it is not a positive time."""
    from lbshape.pipeline.simulate import reduced_simulation

    scene = _scene(0.4, simulation={"dt": 1e-3, "contact_dt": 5e-4})
    assert scene.simulation.contact_dt == 5e-4
    assert scene.runtime_fields()["contact_dt"] == 5e-4
    assert _scene(0.4).simulation.contact_dt is None
    from lbshape.geometry.primitives import structured_box
    from lbshape.scene.build import scene_from_mesh

    built = scene_from_mesh(structured_box((0.1, 0.1, 0.1), (1, 1, 1)),
                            planes=_SCENE["planes"], contact_dt=5e-4)
    assert built.simulation.contact_dt == 5e-4
    pre = precompute(scene)
    assert reduced_simulation(scene, pre).contact_substeps == 2
    assert reduced_simulation(_scene(0.4, simulation={"dt": 1e-3}), pre).contact_substeps == 3
    cases = [({"planes": []}, "has no '[[planes]]'"),
             ({"fixed": {"region": "z > 0.999"}}, "has '[fixed]'")]
    for changes, words in cases:
        with pytest.raises(LbshapeError) as failure:
            _scene(0.0, simulation={"contact_dt": 5e-4}, **changes)
        message = str(failure.value)
        assert "'simulation.contact_dt'" in message and words in message, message
    with pytest.raises(LbshapeError, match="'simulation.contact_dt' must be > 0"):
        _scene(0.4, simulation={"contact_dt": 0.0})


def test_scene_flight_step_key():
    """``[simulation] flight_dt`` reaches the reduced free body's flight passes (with or
    without planes); it is refused on a fixed object and where it is not a positive time."""
    from lbshape.geometry.primitives import structured_box
    from lbshape.pipeline.simulate import reduced_simulation
    from lbshape.scene.build import scene_from_mesh

    scene = _scene(0.4, simulation={"dt": 1e-3, "flight_dt": 2.5e-4})
    assert scene.simulation.flight_dt == 2.5e-4
    assert scene.runtime_fields()["flight_dt"] == 2.5e-4
    assert "flight_dt" not in _scene(0.4).runtime_fields()
    engine = reduced_simulation(scene, precompute(scene))
    assert (engine.flight_dt, engine.flight_passes) == (2.5e-4, 4)
    assert _scene(None, planes=[], simulation={"flight_dt": 1e-3}).simulation.flight_dt == 1e-3
    built = scene_from_mesh(structured_box((0.1, 0.1, 0.1), (1, 1, 1)), flight_dt=5e-4)
    assert built.simulation.flight_dt == 5e-4
    with pytest.raises(LbshapeError) as failure:
        _scene(0.0, simulation={"flight_dt": 5e-4}, fixed={"region": "z > 0.999"})
    message = str(failure.value)
    assert "'simulation.flight_dt'" in message and "has '[fixed]'" in message, message
    with pytest.raises(LbshapeError, match="'simulation.flight_dt' must be > 0"):
        _scene(0.4, simulation={"flight_dt": -1e-3})


def test_engines_refuse_bad_friction(block):
    with pytest.raises(LbshapeError, match="friction must be a finite number >= 0"):
        PlaneContact.for_mesh([ContactPlane((0, 0, 0), (0, 0, 1), 1e4, -1.0)],
                              block.mesh.points, block.mesh.tets, block.U)
    with pytest.raises(LbshapeError, match="friction must be a finite number >= 0"):
        FullSpaceContact([ContactPlane((0, 0, 0), (0, 0, 1), 1e4, float("nan"))],
                         block.mesh.points, block.mesh.tets)
    rubbing = PlaneContact.for_mesh([ContactPlane((0, 0, 0), (0, 0, 1), 1e4, 0.5)],
                                    block.mesh.points, block.mesh.tets, block.U)
    with pytest.raises(LbshapeError, match="free bodies only"):
        ReducedSimulation(block.elastic, r=block.U.shape[1], dt=DT, contact=rubbing)


@pytest.mark.slow
def test_car_passes_a_contact_that_begins_at_round_off():
    """The car's nose reaches the wall at exactly t = 0.140 s (0.7 m at 5 m/s): its
    vertices touch to round-off (depth 6e-16 m), where friction makes the residual
    non-monotone. Without the contact's round-off in the Newton noise level the reduced
    Newton cycled at a residual of 3e-12 and stopped the run (the paper's setting: cubature
    forces, s = 23, no examples)."""
    scene = without_examples(load_scene("car"))
    assert all(plane.friction > 0 for plane in scene.planes)
    scene = dataclasses.replace(
        scene, reduced=dataclasses.replace(scene.reduced, forces="cubature", s=23),
        simulation=dataclasses.replace(scene.simulation, steps=160))
    sim = reduced_simulation(scene, precompute(scene))
    record = sim.run(160)
    assert record.stable, record.message
    assert record.contact_depth[139] < 1e-12 < record.contact_depth[150]  # the onset


def test_a_trial_increment_leaves_the_state_and_starts_the_same_step(block):
    """``trial_increment`` converges the next step without taking it; ``step`` from it
    converges at once (an update at most) to the state ``step`` reaches from the predictor."""
    gravity = G * np.array([0.5, 0.0, -1.0]) / math.sqrt(1.25)
    plane = ContactPlane((0.0, 0.0, 1e-5), (0.0, 0.0, 1.0), STIFFNESS, 0.7)

    def simulator():
        return FullSpaceSimulator(
            block.mesh, block.material, dt=DT, beta=1e-4,
            loads=[TimedLoad(gravity_pattern(block.mass, gravity), TimeProfile())],
            contact=FullSpaceContact([plane], block.mesh.points, block.mesh.tets))

    plain, started = simulator(), simulator()
    for _ in range(3):
        plain.stepper.step()
        x = started.stepper.x.copy()
        dx = started.stepper.trial_increment()
        assert np.array_equal(started.stepper.x, x)  # nothing taken
        info = started.stepper.step(guess=dx)
        assert info.iterations <= 1  # the residual scale counts the first residual too
        scale = np.abs(plain.stepper.x).max()
        assert np.abs(started.stepper.x - plain.stepper.x).max() <= 1e-6 * scale


#: Newton iterations allowed in the car's wall steps: the step from the scheme's
#: predictor needs ~40-57, the continued one 8
NEWTON_CAP_AT_THE_WALL = 25


@pytest.fixture(scope="module")
def car_before_the_wall():
    """The full car with its examples (the scene's settings) and its state after 151 steps."""
    from lbshape.pipeline.simulate import full_simulation

    scene = load_scene("car")
    sim = full_simulation(scene, precompute(scene))
    record = sim.run(151)
    assert record.stable, record.message
    return sim, sim.state


@pytest.mark.slow
@pytest.mark.parametrize("continuation", [True, False])
def test_full_car_reaches_its_wall_step_through_the_slip_continuation(
        monkeypatch, car_before_the_wall, continuation):
    """The full car with its examples at the wall (step 152, t = 0.152 s): Newton from the
    predictor needs ~57 iterations there (friction's slip speed ε turns the slip direction
    within 0.5 mm/s), at the edge of the scene's 60: round-off in the example target
    decides whether it fails. With Newton capped at 25, the step from the predictor fails
    by a wide margin, and from the step converged at 16 ε and 4 ε it meets the same test at
    ε (8 iterations). (The fast path starts its steps in contact from ``h v``, which the
    next test covers; here the steps start from the scheme's predictor.)"""
    from lbshape.dynamics import full_contact
    from lbshape.errors import NewtonFailure

    sim, state = car_before_the_wall
    sim.reset(state)
    monkeypatch.setattr(sim.stepper, "max_iterations", NEWTON_CAP_AT_THE_WALL)
    monkeypatch.setattr(sim.contact, "touches", lambda u: False)  # the scheme's predictor
    if not continuation:
        monkeypatch.setattr(full_contact, "SLIP_CONTINUATION", ())
        with pytest.raises(NewtonFailure, match="step 152"):
            sim.step()
        return
    before = sim.contact.continued_steps
    for _ in range(3):  # 152-154
        sim.step()
    assert sim.contact.continued_steps > before
    assert sim.stepper.time == pytest.approx(0.154)


@pytest.mark.slow
def test_full_car_wall_steps_from_the_constant_velocity_increment(monkeypatch,
                                                                  car_before_the_wall):
    """The fast path's steps in contact start from ``h v``: at the car's wall (steps
    152-154) each converges from it in under half the iterations the scheme's predictor
    needs (~40-57 there), without the slip continuation, to the state the continued
    steps from the predictor reach (within the Newton tolerance's reach, 1e-6)."""
    sim, state = car_before_the_wall
    sim.reset(state)
    before = sim.contact.continued_steps
    iterations = [sim.step() for _ in range(3)]
    assert sim.contact.continued_steps == before
    assert max(iterations) < NEWTON_CAP_AT_THE_WALL, iterations
    from_h_v = np.array(sim.stepper.x)
    sim.reset(state)
    monkeypatch.setattr(sim.stepper, "max_iterations", NEWTON_CAP_AT_THE_WALL)
    monkeypatch.setattr(sim.contact, "touches", lambda u: False)
    for _ in range(3):
        sim.step()
    assert sim.contact.continued_steps > before  # the predictor's steps were continued
    scale = np.abs(sim.stepper.x).max()
    assert np.abs(from_h_v - sim.stepper.x).max() <= 1e-6 * scale


@pytest.mark.slow
def test_reduced_car_at_60_hz_takes_its_contacts_in_sub_steps():
    """The reduced car without examples at 60 Hz steps, its contacts in sub-steps of
    1/3 ms (the default contact_dt), follows its own run at 1 ms within 2 % (measured
    0.23 %) over 0.4 s: the wall impact and the first floor contact. Taken in whole 60 Hz
    steps (contact_dt = flight_dt = dt), the kick's θ goes to 1 at the wall (its contact
    frequency unresolved) and the rebound is lost: the run ends 105 % from the 1 ms one
    (measured), under the set-up's warning that dt is coarse."""
    from lbshape.analysis.norms import trajectory_error
    from lbshape.pipeline.simulate import reduced_simulation
    from lbshape.scene.variants import with_step, without_examples

    car = without_examples(load_scene("car"))
    pre = precompute(car)

    def run(scene):
        engine = reduced_simulation(scene, pre)
        record = engine.run(scene.simulation.steps)
        return record, engine.displacements(record)

    fine, u_fine = run(with_step(car, 1e-3, 0.4))
    coarse_scene = with_step(car, 1.0 / 60.0, 0.4)
    coarse, u_coarse = run(coarse_scene)
    assert fine.stable and coarse.stable, (fine.message, coarse.message)
    frames = [int(round(t * 1000)) for t in coarse.times]
    mass = mass_matrix(pre.mesh, pre.material.density)
    error = trajectory_error(u_coarse, u_fine[frames], mass)
    assert error <= 0.02, error
    whole = dataclasses.replace(coarse_scene, simulation=dataclasses.replace(
        coarse_scene.simulation, contact_dt=1.0 / 60.0, flight_dt=1.0 / 60.0))
    engine = reduced_simulation(whole, pre)
    record = engine.run(whole.simulation.steps)
    assert any("coarse" in warning for warning in engine.warnings), engine.warnings
    if record.stable:  # it may also stop in the wall impact, advising a smaller dt
        lost = trajectory_error(engine.displacements(record), u_fine[frames], mass)
        assert lost > 0.5, lost
    else:
        assert "lower dt" in record.message, record.message
