"""The compiled free-body step against a straightforward numpy reference.

The reference below is the free-body step written plainly with numpy (einsum over the
frame tensors as the formulas of ``lbshape.dynamics.fictitious`` state them, the
penalty contact as a vectorised pass over the surface vertices, the Cayley map as
``(I − W/2)⁻¹ (I + W/2)``, dense LAPACK solves and a generalized eigenvalue problem for
the contact θ). It is kept in the tests only: the library's step runs compiled
kernels, and these tests make sure the two agree.
"""

from __future__ import annotations

import dataclasses
import math
from types import SimpleNamespace

import numpy as np
import pytest
import scipy.linalg as sla
from test_free_body import Body, _gravity

from lbshape.dynamics.contact import ContactPlane, ContactResult, PlaneContact
from lbshape.dynamics.contact_faces import FACING_FLOOR, face_loads
from lbshape.dynamics.dense_lu import DenseLU
from lbshape.dynamics.fictitious import LEVI_CIVITA
from lbshape.dynamics.free_body import PHASES, FreeLoad
from lbshape.dynamics.free_body_contact import (
    CONTRACTION_AGE,
    CONTRACTION_LIMIT,
    MAX_CONTACT_SWEEPS,
    SWEEP_ERROR_SHARE,
    SWEEP_RTOL,
    contact_theta,
)
from lbshape.dynamics.kernels import max_symmetric_eigenvalue
from lbshape.dynamics.loads import TimeProfile
from lbshape.dynamics.reduced import REALTIME_RTOL
from lbshape.dynamics.rigid_frame import cayley, orthonormality_error, rotate
from lbshape.errors import SolverError


# ------------------------------------------------------------------ reference pieces
def ref_cayley(w):
    W = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    return np.linalg.solve(np.eye(3) - 0.5 * W, np.eye(3) + 0.5 * W)


def ref_rotate(R, Pi, inertia, h, dt):
    omega = np.linalg.solve(inertia, Pi - h)
    for _ in range(100):
        after = ref_cayley(dt * omega).T @ Pi
        new = np.linalg.solve(inertia, 0.5 * (Pi + after) - h)
        change = np.abs(new - omega).max()
        omega = new
        if change <= 1e-14 * max(np.abs(omega).max(), 1e-300):
            break
    else:
        raise SolverError("reference rotation did not converge")
    F = ref_cayley(dt * omega)
    return R @ F, F.T @ Pi, omega


def ref_inertia(frame, q):
    Y = (frame.Y0 + np.einsum("j,jab->ab", q, frame.G) + np.einsum("j,jba->ab", q, frame.G)
         + np.einsum("j,k,jkab->ab", q, q, frame.C))
    return np.trace(Y) * np.eye(3) - Y


def ref_momentum(frame, q, qd):
    return frame.H @ qd + np.einsum("j,k,jkc->c", q, qd, frame.S)


def ref_fictitious(frame, q, omega, omega_dot):
    """Euler + centrifugal force (r,) and tangent (r, r) from the docstring formulas."""
    w2 = omega @ omega
    euler_t = np.einsum("kjc,c->jk", frame.S, omega_dot)  # ∂/∂q_k of ω̇ · Σ_k q_k S_kj
    trace_C = np.einsum("jkaa->jk", frame.C)
    centrifugal_t = np.einsum("jkab,a,b->jk", frame.C, omega, omega) - w2 * trace_C
    base = (frame.H.T @ omega_dot + np.einsum("jab,a,b->j", frame.G, omega, omega)
            - w2 * np.einsum("jaa->j", frame.G))
    tangent = euler_t + centrifugal_t
    return base + tangent @ q, tangent


def ref_coriolis(frame, omega):
    return 2.0 * np.einsum("kjc,c->jk", frame.S, omega)


def ref_contact(contact, center, R, q, rigid=True):
    """The penalty contact, vectorised over the surface vertices; the vertices' normal
    forces F and lumped stiffnesses S from the pressure over the triangles
    (:func:`~lbshape.dynamics.contact_faces.face_loads`)."""
    r = contact.r
    out = dict(force=np.zeros(3), torque=np.zeros(3), generalized=np.zeros(r),
               stiffness_q=np.zeros((r, r)), stiffness_rigid=np.zeros((6, 6)), energy=0.0,
               active=0, depth=0.0)
    radius = contact.radius0 + contact.u_max * np.linalg.norm(q)
    reach = np.einsum("pk,pk->p", center - contact.points, contact.normals) <= radius
    if not reach.any():
        return out
    local = contact.body_points + np.einsum("iaj,j->ia", contact.basis, q)
    arm = local @ R.T
    for plane in np.flatnonzero(reach):
        n, k = contact.normals[plane], contact.stiffness[plane]
        depth = -((arm + (center - contact.points[plane])) @ n)
        if not depth.max() > 0:
            continue
        shares = np.maximum(-(contact.face_areas @ R.T) @ n,
                            FACING_FLOOR * np.linalg.norm(contact.face_areas, axis=1))
        F, S = np.zeros(len(depth)), np.zeros(len(depth))
        out["energy"] += face_loads(contact.faces, np.arange(len(shares)), depth, shares, k,
                                    F, S,
                                    np.zeros((len(shares), 9)), np.zeros((6, 3)))
        hit = np.flatnonzero(S > 0.0)
        out["active"] += hit.size
        out["depth"] = max(out["depth"], float(depth[hit].max(initial=0.0)))
        out["force"] += F[hit].sum() * n
        g = np.einsum("sar,a->sr", contact.basis[hit], R.T @ n)
        out["generalized"] += F[hit] @ g
        out["stiffness_q"] += (S[hit, None] * g).T @ g
        if rigid:
            a = np.cross(arm[hit], n)
            out["torque"] += F[hit] @ a
            J = np.concatenate([np.broadcast_to(n, a.shape), a], axis=1)
            out["stiffness_rigid"] += (S[hit, None] * J).T @ J
    return out


def ref_load(load, R, q, t):
    scale = load.profile(t)
    W = load.Z0 + np.einsum("j,jda->da", q, load.Z1)
    torque = R @ np.einsum("cde,ae,da->c", LEVI_CIVITA, R, W)
    return scale * load.force, scale * torque, scale * np.einsum("ab,jba->j", R, load.P)


def ref_theta(M6, K6, dt):
    omega2 = float(sla.eigh(K6, M6, eigvals_only=True).max())
    return 0.5 + 0.5 * float(np.clip(math.sqrt(max(omega2, 0.0)) * dt - 0.5, 0.0, 1.0))


class ReferenceFreeBody:
    """The free-body step of ``lbshape.dynamics.free_body`` written plainly (numpy)."""

    def __init__(self, elastic, frame, *, dt, integrator="newmark", alpha=0.0, beta=0.0,
                 loads=(), k_ex=0.0, target=None, contact=None, velocity=(0, 0, 0),
                 angular_velocity=(0, 0, 0), rtol=REALTIME_RTOL, max_iterations=20):
        r = frame.r
        self.elastic, self.frame, self.dt, self.scheme = elastic, frame, dt, integrator
        self.loads, self.k_ex, self.contact = list(loads), k_ex, contact
        self.examples = np.zeros(r) if target is None else target
        self.target = np.zeros(r)  # the driver is first asked at the first step
        self.rtol, self.max_iterations = rtol, max_iterations
        self.damping = alpha * np.eye(r) + beta * elastic.force_and_tangent(np.zeros(r))[1]
        self.q, self.qd = np.zeros(r), np.zeros(r)
        self.c, self.p = frame.center.copy(), frame.mass * np.asarray(velocity, dtype=float)
        self.R = np.eye(3)
        self.L = ref_inertia(frame, self.q) @ np.asarray(angular_velocity, dtype=float)
        self.time = 0.0
        # the sweeps' contraction last measured and the passes it has served since
        self.contraction, self.contraction_age = 1.0, CONTRACTION_AGE
        self.last_change = 0.0  # the last sweep's squared change of the end momenta
        self.estimated = 0  # second sweeps accepted by their estimated error
        omega = self.omega()
        f = elastic.force_and_tangent(self.q)[0] + k_ex * self.q
        f = f + ref_fictitious(frame, self.q, omega, np.zeros(3))[0]
        self.qa = (self.load_q(self.R, 0.0) - (self.damping + ref_coriolis(frame, omega))
                   @ self.qd - f)

    def omega(self):
        return np.linalg.solve(ref_inertia(self.frame, self.q),
                               self.R.T @ self.L - ref_momentum(self.frame, self.q, self.qd))

    def load_q(self, R, t):
        total = self.k_ex * self.target
        for load in self.loads:
            total = total + ref_load(load, R, self.q, t)[2]
        return total

    def force(self, q, omega, omega_dot, pose):
        f, K = self.elastic.force_and_tangent(q)
        scale = np.linalg.norm(f)
        f = f + self.k_ex * q
        K = K + self.k_ex * np.eye(q.size)
        fi, Ki = ref_fictitious(self.frame, q, omega, omega_dot)
        f, K = f + fi, K + Ki
        if self.contact is not None:
            res = ref_contact(self.contact, pose[0], pose[1], q, rigid=False)
            f, K = f - res["generalized"], K + res["stiffness_q"]
            scale = max(scale, np.linalg.norm(res["generalized"]))
        return f, K, scale

    def kinematics(self, dq):
        dt = self.dt
        if self.scheme == "newmark":
            return 2 / dt * dq - self.qd, 4 / dt**2 * (dq - dt * self.qd) - self.qa
        return dq / dt, (dq / dt - self.qd) / dt

    def step(self):
        """One step: the rigid kick and the deformation solve, swept while the contact acts
        at the step's end until the end momenta settle (the trapezoidal contact impulse)."""
        dt, frame, m = self.dt, self.frame, self.frame.mass
        t1 = self.time + dt
        self.target = self.examples
        inertia = ref_inertia(frame, self.q)
        omega0 = np.linalg.solve(inertia, self.R.T @ self.L - ref_momentum(frame, self.q,
                                                                           self.qd))
        loads = np.zeros(6)
        for load in self.loads:
            f_l, tau_l, _ = ref_load(load, self.R, self.q, self.time)
            loads += np.concatenate([f_l, tau_l])
        contact0, K6, active = np.zeros(6), np.zeros((6, 6)), False
        if self.contact is not None:
            res = ref_contact(self.contact, self.c, self.R, self.q)
            active = res["active"] > 0
            if active:
                contact0 = np.concatenate([res["force"], res["torque"]])
                K6 = res["stiffness_rigid"]
        nu0 = np.concatenate([self.p / m, self.R @ omega0])
        M6 = sla.block_diag(m * np.eye(3), self.R @ inertia @ self.R.T)
        end, previous, iterations = None, None, 0
        deformation, scale = None, 0.0
        for sweeps in range(1, MAX_CONTACT_SWEEPS + 1):
            if not active and end is None:
                impulse, theta = dt * (loads + contact0), 0.5
            else:
                theta = ref_theta(M6, K6, dt)
                if end is None:  # the first kick: contact at t₀, linearly implicit
                    rhs = dt * (loads + contact0) - theta * dt * dt * K6 @ nu0
                else:  # a sweep: trapezoidal contact impulse of the last sweep's end
                    rhs = (dt * loads + 0.5 * dt * (contact0 + end[0])
                           + theta**2 * dt * dt * K6 @ (end[1] - nu0))
                impulse = M6 @ np.linalg.solve(M6 + theta**2 * dt * dt * K6, rhs)
            pose = self.kick(impulse[:3], impulse[3:])
            # a sweep's Newton starts from the last sweep's Δq, at the first one's scale
            iteration, deformation, scale = self.deform(
                pose, t1, None if end is None else (deformation[0], scale))
            iterations += iteration
            if self.contact is None:
                break
            res1 = ref_contact(self.contact, pose[0], pose[1], self.q + deformation[0])
            if res1["active"] == 0 or theta != 0.5:
                self.contraction_age = CONTRACTION_AGE
                break
            radius = self.contact.radius0
            momentum = np.concatenate([pose[2], pose[3] / radius])
            size = np.sum(momentum**2) + np.sum(impulse[:3] ** 2) + np.sum(
                (impulse[3:] / radius) ** 2)
            if sweeps > 1 and self.sweep_accepted(sweeps, np.sum((momentum - previous) ** 2),
                                                  size):
                break
            previous = momentum
            if sweeps == MAX_CONTACT_SWEEPS:
                break
            if sweeps == 1 and not K6.any():  # the contact began within the step
                K6 = res1["stiffness_rigid"]
            end = (np.concatenate([res1["force"], res1["torque"]]),
                   np.concatenate([pose[2] / m, pose[1] @ pose[4]]))
        c1, R1, p1, L1, _, _ = pose
        dq, v1, a1 = deformation
        self.c, self.p, self.R, self.L = c1, p1, R1, L1
        self.q, self.qd, self.qa = self.q + dq, v1, a1
        self.time = t1
        return iterations

    def sweep_accepted(self, sweeps, change, size):
        """The change test, or the second sweep's error estimated from the contraction
        (third sweep's change over the second's) of a recent pass."""
        if sweeps == 3 and self.last_change > 0:
            self.contraction, self.contraction_age = np.sqrt(change / self.last_change), 0
        self.last_change = change
        if change <= SWEEP_RTOL**2 * size:
            return True
        if (sweeps != 2 or self.contraction_age >= CONTRACTION_AGE
                or self.contraction > CONTRACTION_LIMIT):
            return False
        self.contraction_age += 1
        error = self.contraction / (1 - self.contraction) * np.sqrt(change)
        accepted = error <= SWEEP_ERROR_SHARE * SWEEP_RTOL * np.sqrt(size)
        self.estimated += accepted
        return accepted

    def kick(self, dp, dL):
        """(c₁, R₁, p₁, L₁, ω₁, ω̇) (body ω) after the impulse (dp, dL), world."""
        dt, frame, m = self.dt, self.frame, self.frame.mass
        p1, L1 = self.p + dp, self.L + dL
        c1 = self.c + 0.5 * dt * (self.p + p1) / m
        q_mid = self.q + 0.5 * dt * self.qd + 0.125 * dt * dt * self.qa
        qd_mid = self.qd + 0.5 * dt * self.qa
        I_mid, h_mid = ref_inertia(frame, q_mid), ref_momentum(frame, q_mid, qd_mid)
        R1, _, _ = ref_rotate(self.R, self.R.T @ (self.L + L1) / 2, I_mid, h_mid, dt)
        omega1 = np.linalg.solve(I_mid, R1.T @ L1 - h_mid)
        omega_dot = (omega1 - np.linalg.solve(I_mid, self.R.T @ self.L - h_mid)) / dt
        return c1, R1, p1, L1, omega1, omega_dot

    def deform(self, pose, t1, start=None):
        """Newton with backtracking on the deformation at the pose, from the predictor or
        ``start`` = (Δq, residual scale) of the last sweep; (iterations, (Δq, q̇₁, q̈₁),
        residual scale)."""
        dt, frame = self.dt, self.frame
        c1, R1, _, _, omega1, omega_dot = pose
        ca, cv = (4.0, 2.0) if self.scheme == "newmark" else (1.0, 1.0)
        damping = self.damping + ref_coriolis(frame, omega1)
        b = self.load_q(R1, t1)
        if start is None:
            dq = dt * self.qd + (0.5 * dt * dt * self.qa if self.scheme == "newmark" else 0.0)
        else:
            dq = start[0]
        base = ca / dt**2 * np.eye(self.q.size) + cv / dt * damping

        def evaluate(dq):
            f, K, scale = self.force(self.q + dq, omega1, omega_dot, (c1, R1))
            v1, a1 = self.kinematics(dq)
            residual = a1 + damping @ v1 + f - b
            return f, K, v1, a1, residual, np.linalg.norm(residual), scale

        f, K, v1, a1, residual, norm, force_scale = evaluate(dq)
        scale = max(np.linalg.norm(b), np.linalg.norm(self.qa), norm, np.linalg.norm(f),
                    force_scale, 0.0 if start is None else start[1])
        for iteration in range(self.max_iterations + 1):
            noise = 64 * np.finfo(float).eps * (
                ca / dt**2 * np.linalg.norm(dq) + np.linalg.norm(f) + np.linalg.norm(b)
                + ca / dt * np.linalg.norm(self.qd) + np.linalg.norm(self.qa))
            if norm <= self.rtol * scale or norm <= noise:
                break
            assert iteration < self.max_iterations
            delta = np.linalg.solve(base + K, residual)
            fraction = 1.0
            while True:
                trial = evaluate(dq - fraction * delta)
                if trial[5] < norm or fraction <= 1 / 64:
                    break
                fraction *= 0.5
            dq = dq - fraction * delta
            f, K, v1, a1, residual, norm, _ = trial
        return iteration, (dq, v1, a1), scale


# ------------------------------------------------------------------------ tests
@pytest.fixture(scope="module")
def soft():
    return Body()


def test_contact_kernel_matches_reference(soft):
    """Forces, stiffnesses, energy and counts of the compiled contact pass equal the
    vectorised reference (two planes, several poses, with and without the rigid parts)."""
    planes = [ContactPlane((0.0, 0.0, 0.05), (0.0, 0.3, 1.0), 1e4),
              ContactPlane((0.12, 0.0, 0.0), (-1.0, 0.1, 0.0), 3e4)]
    contact = PlaneContact.for_mesh(planes, soft.mesh.points, soft.mesh.tets, soft.U,
                                    center=soft.frame.center)
    rng = np.random.default_rng(11)
    touched = 0
    for _ in range(6):
        q = 0.05 * rng.standard_normal(8)
        center = soft.frame.center + 0.05 * rng.standard_normal(3)
        R = cayley(0.5 * rng.standard_normal(3))
        for rigid in (True, False):
            got = contact.evaluate(center, R, q, rigid=rigid)
            want = ref_contact(contact, center, R, q, rigid=rigid)
            for key in ("force", "torque", "generalized", "stiffness_q", "stiffness_rigid"):
                scale = max(np.abs(want[key]).max(), 1e-300)
                np.testing.assert_allclose(getattr(got, key), want[key], rtol=0,
                                           atol=1e-12 * scale, err_msg=key)
            assert got.active == want["active"]
            assert got.energy == pytest.approx(want["energy"], rel=1e-12, abs=1e-300)
            assert got.depth == pytest.approx(want["depth"], rel=1e-12, abs=1e-300)
        touched += got.active > 0
    assert touched >= 3  # the poses do touch the planes
    far = contact.evaluate(soft.frame.center + np.array([-10.0, 0.0, 10.0]), np.eye(3),
                           np.zeros(8))
    assert far.active == 0 and not far.generalized.any() and contact.skipped >= 1



def test_near_set_evaluation_equals_the_whole_surface(soft):
    """While the body moves less than the near set's margin the face pass takes only
    the faces near a plane, and every output equals an evaluation over the whole surface
    bit for bit (friction, two planes); a larger move makes the set again."""
    planes = [ContactPlane((0.0, 0.0, 0.05), (0.0, 0.3, 1.0), 1e4, 0.4),
              ContactPlane((0.12, 0.0, 0.0), (-1.0, 0.1, 0.0), 3e4, 0.2)]
    near, whole = (PlaneContact.for_mesh(planes, soft.mesh.points, soft.mesh.tets, soft.U,
                                         center=soft.frame.center) for _ in range(2))
    rng = np.random.default_rng(13)
    center, R, q = soft.frame.center.copy(), cayley(np.array([0.1, -0.2, 0.3])), np.zeros(8)
    touched = 0
    for k in range(40):
        step = 0.02 if k % 10 == 9 else 2e-4 * near.margin / near.radius0
        center = center + step * rng.standard_normal(3)
        R = R @ cayley(step * rng.standard_normal(3))
        q = q + step * rng.standard_normal(8)
        motion = (rng.standard_normal(3), rng.standard_normal(3), rng.standard_normal(8))
        whole._near_listed = None  # every vertex, every time
        got = near.evaluate(center, R, q, velocity=motion[0], omega=motion[1],
                            qd=motion[2], rate=50.0)
        want = whole.evaluate(center, R, q, velocity=motion[0], omega=motion[1],
                              qd=motion[2], rate=50.0)
        for field in (f.name for f in dataclasses.fields(ContactResult)):
            np.testing.assert_array_equal(getattr(got, field), getattr(want, field),
                                          err_msg=field)
        np.testing.assert_array_equal(near.coupling, whole.coupling)
        touched += got.active > 0
    assert touched >= 30
    assert near.near_passes >= 25 and 4 <= near.full_passes <= 10, (near.near_passes,
                                                                     near.full_passes)
    assert len(near._near_listed[1]) < near.faces.shape[0]  # it left faces out

def test_frame_kernels_match_the_formulas(soft):
    """Inertia, relative momentum, Euler, centrifugal and Coriolis terms (compiled) equal
    the einsum forms of the fictitious-force formulas."""
    frame = soft.frame
    rng = np.random.default_rng(12)
    q, qd = 0.05 * rng.standard_normal(8), rng.standard_normal(8)
    omega, omega_dot = rng.standard_normal(3), rng.standard_normal(3)
    np.testing.assert_allclose(frame.inertia(q), ref_inertia(frame, q), rtol=1e-13)
    np.testing.assert_allclose(frame.relative_momentum(q, qd), ref_momentum(frame, q, qd),
                               rtol=1e-12, atol=1e-14)
    fe, Ke = frame.euler(q, omega_dot)
    fc, Kc = frame.centrifugal(q, omega)
    f, K = ref_fictitious(frame, q, omega, omega_dot)
    np.testing.assert_allclose(fe + fc, f, rtol=1e-12, atol=1e-12 * np.abs(f).max())
    np.testing.assert_allclose(Ke + Kc, K, rtol=1e-12, atol=1e-12 * np.abs(K).max())
    np.testing.assert_allclose(frame.coriolis(omega), ref_coriolis(frame, omega),
                               rtol=1e-12, atol=1e-14)


def test_rotation_kernel_matches_reference():
    rng = np.random.default_rng(13)
    for _ in range(5):
        A = rng.standard_normal((3, 3))
        inertia = A @ A.T + np.eye(3)
        Pi, h = rng.standard_normal(3), 0.1 * rng.standard_normal(3)
        R0 = cayley(rng.standard_normal(3))
        got = rotate(R0, Pi, inertia, h, 0.05)
        want = ref_rotate(R0, Pi, inertia, h, 0.05)
        for g, w in zip(got, want, strict=True):
            np.testing.assert_allclose(g, w, rtol=1e-12, atol=1e-13)
        np.testing.assert_allclose(cayley(Pi), ref_cayley(Pi), rtol=1e-13, atol=1e-15)
        assert orthonormality_error(got[0]) <= 1e-14


def test_small_dense_kernels_match_lapack():
    """LU with pivoting (Newton system), Jacobi eigenvalue and θ against LAPACK."""
    rng = np.random.default_rng(14)
    for n in (3, 8, 30, 58):
        base, K = rng.standard_normal((n, n)), rng.standard_normal((n, n))
        lu = DenseLU(n)
        assert lu.factor(base, K)
        rhs, x = rng.standard_normal(n), np.zeros(n)
        lu.solve_into(rhs, x)
        np.testing.assert_allclose(x, np.linalg.solve(base + K, rhs), rtol=1e-9, atol=1e-12)
        rows = rng.standard_normal((6, n))  # several right-hand sides, one factorisation
        solved = np.zeros((6, n))
        lu.solve_rows_into(rows, solved)
        for row, got in zip(rows, solved, strict=True):
            lu.solve_into(row, x)
            np.testing.assert_array_equal(got, x)
        np.testing.assert_allclose(solved.T, np.linalg.solve(base + K, rows.T), rtol=1e-9,
                                   atol=1e-12)
        S = rng.standard_normal((n, n))
        S = S + S.T
        assert max_symmetric_eigenvalue(S.copy()) == pytest.approx(
            np.linalg.eigvalsh(S).max(), rel=1e-12)
    singular, lu = np.zeros((4, 4)), DenseLU(4)
    assert not lu.factor(singular, singular)
    assert not lu.factor(np.full((4, 4), np.nan), singular)
    for scale in (1e-2, 1.0, 1e2, 1e4):  # θ in all three regimes
        A = rng.standard_normal((6, 6))
        M6 = A @ A.T + 6 * np.eye(6)
        B = rng.standard_normal((6, 3))
        K6 = scale * B @ B.T
        assert contact_theta(M6, K6, 1e-2) == pytest.approx(ref_theta(M6, K6, 1e-2),
                                                            rel=1e-12, abs=1e-15)


def _push(body: Body) -> FreeLoad:
    """A force ramped up over 0.4 s on the vertices of one end, off the centre: a load
    whose force and torque change within every step."""
    points = body.mesh.points
    pattern = np.zeros_like(points)
    end = points[:, 2] >= points[:, 2].max() - 1e-9
    pattern[end] = np.array([0.5, -0.3, 0.2]) / end.sum()
    return FreeLoad.from_pattern(pattern.ravel(), body.U, points - body.frame.center,
                                 TimeProfile("ramp", 0.0, 0.4))


def _scenario(body: Body, *, integrator: str, push: bool = False):
    """Spinning, falling, example-pulled bar onto a tilted floor: loads, examples, rigid
    kick with θ, contact in the Newton solve, fictitious forces (``push``: and a load
    that changes in time, whose start-of-step value every contact sweep uses)."""
    target = 0.02 * np.linspace(-1.0, 1.0, 8)
    planes = [ContactPlane((0.0, 0.0, -0.02), (0.05, 0.1, 1.0), 2e4 * 225.0)]  # N/m³
    loads = [_gravity(body)] + ([_push(body)] if push else [])
    options = dict(dt=2e-3, integrator=integrator, beta=0.002, loads=loads,
                   k_ex=400.0, velocity=(0.3, 0.0, -0.5), angular_velocity=(1.0, 2.0, 3.0))
    reference = ReferenceFreeBody(
        body.elastic, body.frame, target=target,
        contact=PlaneContact.for_mesh(planes, body.mesh.points, body.mesh.tets, body.U,
                                      center=body.frame.center), **options)
    driver = SimpleNamespace(target=lambda q: SimpleNamespace(q_target=target))
    contact = PlaneContact.for_mesh(planes, body.mesh.points, body.mesh.tets, body.U,
                                    center=body.frame.center)
    # the reference takes whole steps: the engine's sub-steps are off here (they are k
    # steps of Δt/k, tested in test_free_body)
    return reference, body.simulation(driver=driver, contact=contact,
                                      contact_dt=options["dt"], **options), contact


@pytest.mark.parametrize(("integrator", "push"), [("newmark", False),
                                                  ("backward-euler", False),
                                                  ("newmark", True)])
def test_compiled_step_matches_the_reference_step(soft, integrator, push):
    """200 steps (free flight, impact, rolling contact): the compiled path follows the
    numpy reference to round-off, with the same Newton iterations (and sweeps: the
    resting bar's second sweeps are accepted on their estimated error, 326 sweeps of 399)."""
    reference, sim, contact = _scenario(soft, integrator=integrator, push=push)
    worst = dict(q=0.0, c=0.0, R=0.0, p=0.0, L=0.0)
    touched = 0
    for _ in range(200):
        iterations = sim.step()
        assert reference.step() == iterations
        rigid = sim.rigid
        for key, got, want in (("q", sim.q, reference.q), ("c", rigid.center, reference.c),
                               ("R", rigid.rotation, reference.R),
                               ("p", rigid.momentum, reference.p),
                               ("L", rigid.angular_momentum, reference.L)):
            worst[key] = max(worst[key], float(np.abs(got - want).max()
                                               / max(np.abs(want).max(), 1e-12)))
        touched += contact.scalars[1] > 0
    assert touched >= 50, touched  # the bar did land and stay on the floor
    assert reference.estimated > 10  # second sweeps accepted on their estimated error
    assert max(worst.values()) <= 1e-9, worst


def test_contact_reuse_changes_nothing(soft):
    """The contact at a step's start is the previous step's last evaluation: reusing it
    gives the same trajectory bit for bit, with fewer evaluations (at most one per
    Newton evaluation)."""
    runs = []
    for reuse in (True, False):
        _, sim, contact = _scenario(soft, integrator="newmark")
        sim.reuse_contact = reuse
        record = sim.run(150)
        assert record.stable, record.message
        calls = contact.evaluated + contact.skipped
        runs.append((record, calls, sim.total_sweeps))
    (fast, calls_fast, passes), (slow, calls_slow, _) = runs
    assert passes > 150  # the landing steps were swept
    for key in ("states", "centers", "rotations", "momenta", "angular_momenta"):
        np.testing.assert_array_equal(getattr(fast, key), getattr(slow, key), err_msg=key)
    # the first step's start, then per step one evaluation per Newton evaluation (each
    # pass's initial guess and each update; a backtracking halving adds one, rarely)
    newton = 1 + passes + int(fast.newton_iterations.sum())
    assert newton <= calls_fast <= 1.02 * newton, (calls_fast, newton)
    # without reuse: once more at each step's start and for each sampled energy
    assert calls_slow == calls_fast + 149 + 150


def test_phase_record_of_a_run(soft):
    """phase_seconds: one row per step with the parts of PHASES, adding up to the step."""
    _, sim, _ = _scenario(soft, integrator="newmark")
    record = sim.run(40)
    assert sim.phase_seconds.shape == (40, len(PHASES))
    assert (sim.phase_seconds >= 0).all()
    np.testing.assert_allclose(1e3 * sim.phase_seconds.sum(axis=1), record.t_total_ms,
                               rtol=1e-9)
    interp = 1e3 * sim.phase_seconds[:, :2].sum(axis=1)
    np.testing.assert_allclose(interp, record.t_interp_ms, rtol=1e-9, atol=1e-12)

