"""The compiled free-body step: its named structures and its kernels.

:class:`~lbshape.dynamics.free_body.FreeBodySimulation` keeps every array its step
touches in a few structures, each a ``NamedTuple`` of views of one float buffer
``data`` (the pattern of :mod:`lbshape.dynamics.kernels`):

* :class:`BodyState` — one instant: centre of mass c, momentum p, rotation R, angular
  momentum L (world), deformation q, q̇, q̈ and the elastic force at q. The step writes
  the next instant into a second one; the two swap when the step is accepted;
* :class:`RigidKick` — the rigid update's inputs (the loads and the contact at t₀, the
  contact and the velocity at the end of the last contact sweep) and outputs (ω₀, ω₁,
  ω̇, the midpoint ω, the impulses Δp, ΔL, v₀, θ);
* :class:`DeformationSolve` — the deformation's Newton arrays: the scheme's
  coefficients, D and D + Γ(ω₁), the Newton base matrix, load, force, tangent,
  residual, update;
* :class:`Scratch` — work arrays of the kernels and the energies of the new state;
* :class:`~lbshape.dynamics.fictitious.FrameArrays` — the frame tensors.

A kernel called from Python (:func:`rigid_update`, :func:`deformation_residual`,
:func:`commit_energy`) takes the buffers and rebuilds the named views
(:func:`body_state`, :func:`rigid_kick`, :func:`deformation_solve`, :func:`scratch`,
:func:`~lbshape.dynamics.fictitious.frame_arrays`): one array per structure keeps a
call from Python cheap, and the kernel reads every array by its name, never by its
position in a long argument list. The small kernels (:func:`newton_base`, :func:`trial`,
:func:`loads_into`, :func:`contact_theta_into`) take plain arrays.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from lbshape._jit import njit, py_func
from lbshape.dynamics.fictitious import (
    add_fictitious,
    coriolis_into,
    fictitious_parts_into,
    frame_arrays,
    inertia_momentum_into,
)
from lbshape.dynamics.kernels import (
    check_size,
    cholesky_in_place,
    cholesky_solve_in_place,
    max_symmetric_eigenvalue,
    take,
)
from lbshape.dynamics.rigid_frame import inverse3_into, rotate_into

#: :func:`rigid_update`'s results: done, the rotation did not converge, singular inertia
#: or rigid system
KICK_DONE, KICK_ROTATION_FAILED, KICK_SINGULAR = 0, 1, 2


# ------------------------------------------------------------------ structures
class BodyState(NamedTuple):
    """One instant of a free body: views of the buffer ``data`` (:func:`body_state`)."""

    #: the buffer every field below views
    data: np.ndarray
    #: (3,) centre of mass (m, world)
    c: np.ndarray
    #: (3,) linear momentum (kg·m/s, world)
    p: np.ndarray
    #: (3, 3) body-to-world rotation
    R: np.ndarray
    #: (3,) angular momentum about c (kg·m²/s, world)
    L: np.ndarray
    #: (r,) deformation (body frame)
    q: np.ndarray
    #: (r,) its rate
    qd: np.ndarray
    #: (r,) its acceleration
    qa: np.ndarray
    #: (r,) the elastic force at q
    f_elastic: np.ndarray

    @staticmethod
    def size(r: int) -> int:
        """Floats in the buffer of a basis of r columns."""
        return 18 + 4 * r

    @classmethod
    def allocate(cls, r: int) -> BodyState:
        """A zero state."""
        return py_func(body_state)(np.zeros(cls.size(r)), r)


class RigidKick(NamedTuple):
    """The rigid update of a step (:func:`rigid_update`): views of the buffer ``data``
    (:func:`rigid_kick`). Vectors are world vectors unless said otherwise."""

    #: the buffer every field below views
    data: np.ndarray
    #: (3,) the loads' total force (N), input
    force: np.ndarray
    #: (3,) the loads' torque about c (N·m), input
    torque: np.ndarray
    #: (3,) the contact force at t₀ (N), input
    contact_force: np.ndarray
    #: (3,) the contact torque about c at t₀ (N·m), input
    contact_torque: np.ndarray
    #: (6, 6) the contact stiffness K₆ of the kick, input
    K6: np.ndarray
    #: (6, 6) the friction's rate matrix C₆ of the kick (zero without friction), input
    C6: np.ndarray
    #: (6,) contact (force, torque) at the end of the last sweep, input of a sweep
    contact_end: np.ndarray
    #: (6,) ν₁ = (v, ω) at the end of the last sweep, input of a sweep
    nu_end: np.ndarray
    #: (6,) (p₁, L₁ / radius) at the end of the last sweep (the sweeps' stopping test)
    momentum_end: np.ndarray
    #: (3,) body angular velocity at t₀ (rad/s), output
    omega0: np.ndarray
    #: (3,) body angular velocity at t₁, output
    omega1: np.ndarray
    #: (3,) body angular acceleration over the step (rad/s²), output
    omega_dot: np.ndarray
    #: (3,) midpoint body angular velocity of the rotation, output
    omega_mid: np.ndarray
    #: (3,) impulse on p (N·s), output
    dp: np.ndarray
    #: (3,) impulse on L (N·m·s), output
    dL: np.ndarray
    #: (3,) velocity of c at t₀ (m/s), output
    v0: np.ndarray
    #: (1,) θ of the contact kick (½ without contact), output
    theta: np.ndarray

    @staticmethod
    def size() -> int:
        """Floats in the buffer."""
        return 4 * 3 + 2 * 36 + 3 * 6 + 7 * 3 + 1

    @classmethod
    def allocate(cls) -> RigidKick:
        """Zero arrays."""
        return py_func(rigid_kick)(np.zeros(cls.size()))


class DeformationSolve(NamedTuple):
    """The deformation's Newton solve: views of the buffer ``data``
    (:func:`deformation_solve`)."""

    #: the buffer every field below views
    data: np.ndarray
    #: (5,) the scheme's ``[c_a, k_v, k_a, c_v, j_v]``
    #: (:class:`~lbshape.dynamics.schemes.Scheme`)
    scheme: np.ndarray
    #: (5,) its step rates ``[c_a/h², k_v/h, k_a, c_v/h, j_v]``
    rates: np.ndarray
    #: (r, r) Rayleigh damping ``D = α I + β K₀``
    D: np.ndarray
    #: (r, r) ``D + Γ(ω₁)``
    damping: np.ndarray
    #: (r, r) ``c_a/h² I + c_v/h (D + Γ(ω₁))``
    base: np.ndarray
    #: (r,) the generalized load ``k_ex q* + Uᵀ R₁ᵀ f_ext(t₁)``
    b: np.ndarray
    #: (r,) the force at q₁ (the elastic force on entry to :func:`deformation_residual`)
    f: np.ndarray
    #: (r, r) its tangent
    K: np.ndarray
    #: (r,) the residual
    residual: np.ndarray
    #: (r,) the Newton update
    delta: np.ndarray
    #: (2,) ``[‖f‖, max(‖f_elastic‖, ‖f_contact‖)]`` of the last evaluation
    norms: np.ndarray
    #: (r,) the Euler and centrifugal forces at q = 0 and the kick's (ω₁, ω̇)
    fictitious0: np.ndarray
    #: (r, r) their tangent (the forces are linear in q)
    fictitious_K: np.ndarray

    @staticmethod
    def size(r: int) -> int:
        """Floats in the buffer of a basis of r columns."""
        return 5 + 5 + 5 * r * r + 5 * r + 2

    @classmethod
    def allocate(cls, r: int) -> DeformationSolve:
        """Zero arrays."""
        return py_func(deformation_solve)(np.zeros(cls.size(r)), r)


class Scratch(NamedTuple):
    """Work arrays of the kernels and the energies of the new state: views of the buffer
    ``data`` (:func:`scratch`)."""

    #: the buffer every field below views
    data: np.ndarray
    #: (8, 3, 3) 3 × 3 work: inertia, inverse, I_world, the rotation's (2); the energies'
    #: inertia, inverse and vectors
    m33: np.ndarray
    #: (4, 6) 6-vector work: (h, the ω at t₀ of ω̇), F₆ (then Π½, Π₁), ν₀, right-hand side
    v6: np.ndarray
    #: (4, 6, 6) 6 × 6 work: M₆, the kick's matrix, θ's two
    m66: np.ndarray
    #: (r,) the predicted mid-step deformation
    q_mid: np.ndarray
    #: (r,) its rate
    qd_mid: np.ndarray
    #: (3,) the new state's energies (:func:`commit_energy`)
    energies: np.ndarray
    #: (2, 12) the pass's I (9) and h (3) at its start and at the predicted mid-step:
    #: computed by the kick of its first sweep, reused by the kicks of its other sweeps
    #: (they start from the same state)
    held: np.ndarray

    @staticmethod
    def size(r: int) -> int:
        """Floats in the buffer of a basis of r columns."""
        return 72 + 24 + 144 + 2 * r + 3 + 24

    @classmethod
    def allocate(cls, r: int) -> Scratch:
        """Zero arrays."""
        return py_func(scratch)(np.zeros(cls.size(r)), r)


# ------------------------------------------------------------------ view functions
@njit
def body_state(data, r):
    """The :class:`BodyState` views of a buffer of :meth:`BodyState.size` floats."""
    c, at = take(data, 0, 3)
    p, at = take(data, at, 3)
    R, at = take(data, at, 9)
    L, at = take(data, at, 3)
    q, at = take(data, at, r)
    qd, at = take(data, at, r)
    qa, at = take(data, at, r)
    f_elastic, at = take(data, at, r)
    check_size(data, at)
    return BodyState(data, c, p, R.reshape((3, 3)), L, q, qd, qa, f_elastic)


@njit
def rigid_kick(data):
    """The :class:`RigidKick` views of a buffer of :meth:`RigidKick.size` floats."""
    force, at = take(data, 0, 3)
    torque, at = take(data, at, 3)
    contact_force, at = take(data, at, 3)
    contact_torque, at = take(data, at, 3)
    K6, at = take(data, at, 36)
    C6, at = take(data, at, 36)
    contact_end, at = take(data, at, 6)
    nu_end, at = take(data, at, 6)
    momentum_end, at = take(data, at, 6)
    omega0, at = take(data, at, 3)
    omega1, at = take(data, at, 3)
    omega_dot, at = take(data, at, 3)
    omega_mid, at = take(data, at, 3)
    dp, at = take(data, at, 3)
    dL, at = take(data, at, 3)
    v0, at = take(data, at, 3)
    theta, at = take(data, at, 1)
    check_size(data, at)
    return RigidKick(data, force, torque, contact_force, contact_torque, K6.reshape((6, 6)),
                     C6.reshape((6, 6)), contact_end, nu_end, momentum_end, omega0, omega1,
                     omega_dot, omega_mid, dp, dL, v0, theta)


@njit
def deformation_solve(data, r):
    """The :class:`DeformationSolve` views of a buffer of :meth:`DeformationSolve.size`
    floats."""
    scheme, at = take(data, 0, 5)
    rates, at = take(data, at, 5)
    D, at = take(data, at, r * r)
    damping, at = take(data, at, r * r)
    base, at = take(data, at, r * r)
    b, at = take(data, at, r)
    f, at = take(data, at, r)
    K, at = take(data, at, r * r)
    residual, at = take(data, at, r)
    delta, at = take(data, at, r)
    norms, at = take(data, at, 2)
    fictitious0, at = take(data, at, r)
    fictitious_K, at = take(data, at, r * r)
    check_size(data, at)
    square = (r, r)
    return DeformationSolve(data, scheme, rates, D.reshape(square), damping.reshape(square),
                            base.reshape(square), b, f, K.reshape(square), residual, delta,
                            norms, fictitious0, fictitious_K.reshape(square))


@njit
def scratch(data, r):
    """The :class:`Scratch` views of a buffer of :meth:`Scratch.size` floats."""
    m33, at = take(data, 0, 72)
    v6, at = take(data, at, 24)
    m66, at = take(data, at, 144)
    q_mid, at = take(data, at, r)
    qd_mid, at = take(data, at, r)
    energies, at = take(data, at, 3)
    held, at = take(data, at, 24)
    check_size(data, at)
    return Scratch(data, m33.reshape((8, 3, 3)), v6.reshape((4, 6)), m66.reshape((4, 6, 6)),
                   q_mid, qd_mid, energies, held.reshape((2, 12)))


# ------------------------------------------------------------------ step kernels
@njit
def rigid_update(r, dt, active, sweep, frame_data, start_data, end_data, kick_data, solve_data,
                 scratch_data):
    """The rigid update (step 2 of :mod:`lbshape.dynamics.free_body`) from the state
    ``start`` to the rigid part (c₁, p₁, R₁, L₁) of ``end``, then ``D + Γ(ω₁)`` into
    ``solve.damping`` and the Euler and centrifugal forces' parts at (ω₁, ω̇) into
    ``solve.fictitious0``, ``solve.fictitious_K``. Returns :data:`KICK_DONE`,
    :data:`KICK_ROTATION_FAILED` or :data:`KICK_SINGULAR`.

    ``active``: the contact at t₀ acts (or a sweep). With ``sweep`` (a contact sweep) the
    kick is ``(M₆ + θ Δt C₆ + θ² Δt² K₆) Δν = Δt F_loads + ½ Δt (C₀ + C₁) + (θ Δt C₆ +
    θ² Δt² K₆) (ν₁ − ν₀)`` with the contact (force, torque) C₀ at t₀, C₁ =
    ``kick.contact_end`` and ν₁ = ``kick.nu_end`` at the end of the previous sweep: its
    fixed point is the trapezoidal rule ``M₆ Δν = Δt F_loads + ½ Δt (C₀ + C₁)``. C₆ is
    the friction's rate matrix (``kick.C6``, zero without friction): the friction of
    C₀, C₁ depends on the velocities, and C₆ makes that dependence implicit. A sweep
    starts from the state its pass's first kick started from, so it takes that kick's
    I and h (at t₀ and mid-step, ``scratch.held``) instead of computing them again.
    """
    frame = frame_arrays(frame_data, r)
    start, end = body_state(start_data, r), body_state(end_data, r)
    kick = rigid_kick(kick_data)
    work = scratch(scratch_data, r)
    mass = frame.mass[0]
    inertia, inverse, world = work.m33[0], work.m33[1], work.m33[2]
    h, before = work.v6[0, :3], work.v6[0, 3:]
    R0, L0, p0 = start.R, start.L, start.p
    _pass_inertia(start.q, start.qd, frame, sweep, work.held[0], inertia, h)
    if not inverse3_into(inertia, inverse):
        return KICK_SINGULAR
    omega0, dp, dL, v0 = kick.omega0, kick.dp, kick.dL, kick.v0
    body_angular_velocity_into(R0, L0, h, inverse, omega0)
    for a in range(3):
        v0[a] = p0[a] / mass
    F6 = work.v6[1]
    for a in range(3):
        F6[a] = kick.force[a] + (kick.contact_force[a] if active else 0.0)
        F6[3 + a] = kick.torque[a] + (kick.contact_torque[a] if active else 0.0)
    kick.theta[0] = 0.5
    if not active:
        for a in range(3):
            dp[a] = dt * F6[a]
            dL[a] = dt * F6[3 + a]
    elif not _contact_impulse(dt, mass, sweep, R0, inertia, omega0, F6, kick, work, world):
        return KICK_SINGULAR
    c1, p1, L1 = end.c, end.p, end.L
    for a in range(3):
        p1[a] = p0[a] + dp[a]
        c1[a] = start.c[a] + 0.5 * dt * (p0[a] + p1[a]) / mass
        L1[a] = L0[a] + dL[a]
    # inertia and relative momentum at the predicted mid-step deformation
    q_mid, qd_mid = work.q_mid, work.qd_mid
    for j in range(r):
        q_mid[j] = start.q[j] + 0.5 * dt * start.qd[j] + 0.125 * dt * dt * start.qa[j]
        qd_mid[j] = start.qd[j] + 0.5 * dt * start.qa[j]
    _pass_inertia(q_mid, qd_mid, frame, sweep, work.held[1], inertia, h)
    # half the impulse, the torque-free rotation, the other half (Strang): Π = R₀ᵀ L½
    body = work.v6[1, :3]
    for a in range(3):
        body[a] = 0.5 * (R0[0, a] * (L0[0] + L1[0]) + R0[1, a] * (L0[1] + L1[1])
                         + R0[2, a] * (L0[2] + L1[2]))
    body1 = work.v6[1, 3:]
    R1 = end.R
    if not rotate_into(R0, body, inertia, h, dt, R1, body1, kick.omega_mid, work.m33[3:5]):
        return KICK_ROTATION_FAILED
    if not inverse3_into(inertia, inverse):
        return KICK_SINGULAR
    # ω at t₁ and its difference quotient over the step (mid-step I and h)
    omega1, omega_dot = kick.omega1, kick.omega_dot
    body_angular_velocity_into(R1, L1, h, inverse, omega1)
    body_angular_velocity_into(R0, L0, h, inverse, before)
    for a in range(3):
        omega_dot[a] = (omega1[a] - before[a]) / dt
    solve = deformation_solve(solve_data, r)
    coriolis_into(omega1, frame, solve.D, solve.damping)
    fictitious_parts_into(omega1, omega_dot, frame, solve.fictitious0, solve.fictitious_K)
    return KICK_DONE


@njit
def _pass_inertia(q, qd, frame, sweep, held, inertia, h):
    """I(q) (3, 3) into ``inertia`` and h(q, q̇) (3,) into ``h``: computed and kept in
    ``held`` (12,) by a pass's first kick, taken from it by the pass's sweeps."""
    if sweep:
        for a in range(3):
            for b in range(3):
                inertia[a, b] = held[3 * a + b]
            h[a] = held[9 + a]
        return
    inertia_momentum_into(q, qd, frame, inertia, h)
    for a in range(3):
        for b in range(3):
            held[3 * a + b] = inertia[a, b]
        held[9 + a] = h[a]


@njit
def _contact_impulse(dt, mass, sweep, R0, inertia, omega0, F6, kick, work, world):
    """The impulses ``kick.dp``, ``kick.dL`` of the linearly implicit contact kick
    ``M₆ Δν`` (see :func:`rigid_update`) and its θ; False if the kick's matrix is not
    positive definite. ``world`` (3, 3) receives ``R₀ I Rᵀ₀``. The first pass is
    ``(M₆ + θ Δt C₆ + θ² Δt² K₆) Δν = Δt F₆ − θ Δt² K₆ ν₀`` (F₆ with the contact and its
    friction at t₀)."""
    M6, A = work.m66[0], work.m66[1]
    nu0 = work.v6[2]
    K6, C6, dp, dL = kick.K6, kick.C6, kick.dp, kick.dL
    for a in range(3):  # I_world = R I Rᵀ
        for b in range(3):
            value = 0.0
            for k in range(3):
                for m in range(3):
                    value += R0[a, k] * inertia[k, m] * R0[b, m]
            world[a, b] = value
    M6[:, :] = 0.0
    for a in range(3):
        M6[a, a] = mass
        for b in range(3):
            M6[3 + a, 3 + b] = world[a, b]
        nu0[a] = kick.v0[a]
        nu0[3 + a] = R0[a, 0] * omega0[0] + R0[a, 1] * omega0[1] + R0[a, 2] * omega0[2]
    theta = contact_theta_into(M6, K6, dt, work.m66[2], work.m66[3])
    kick.theta[0] = theta
    rhs = work.v6[3]
    k = theta * theta * dt * dt
    c = theta * dt
    for i in range(6):
        value = 0.0
        rate = 0.0
        for j in range(6):
            if sweep:
                value += K6[i, j] * (kick.nu_end[j] - nu0[j])
                rate += C6[i, j] * (kick.nu_end[j] - nu0[j])
            else:
                value += K6[i, j] * nu0[j]
            A[i, j] = M6[i, j] + k * K6[i, j] + c * C6[i, j]
        if sweep:
            contact0 = kick.contact_force[i] if i < 3 else kick.contact_torque[i - 3]
            rhs[i] = (dt * F6[i] + 0.5 * dt * (kick.contact_end[i] - contact0) + k * value
                      + c * rate)
        else:
            rhs[i] = dt * F6[i] - theta * dt * dt * value
    if not cholesky_in_place(A):
        return False
    cholesky_solve_in_place(A, rhs)
    for i in range(3):  # impulse M₆ Δν
        dp[i] = mass * rhs[i]
        dL[i] = world[i, 0] * rhs[3] + world[i, 1] * rhs[4] + world[i, 2] * rhs[5]
    return True


@njit
def deformation_residual(r, dt, k_ex, active, start_data, end_data, solve_data, dq,
                         contact_generalized, contact_stiffness):
    """The deformation's residual at ``end.q`` = q₁ = q₀ + ``dq``; returns its norm.

    Completes ``solve.f``, ``solve.K`` (the elastic force and tangent on entry; the
    elastic force is copied to ``end.f_elastic``) with the example spring, the Euler and
    centrifugal forces (``solve.fictitious0``, ``solve.fictitious_K``: the kick's ω₁, ω̇)
    and, if ``active``, the contact
    (``contact_generalized`` (r,), ``contact_stiffness`` (r, r)); writes the kinematics
    ``end.qd``, ``end.qa`` of ``dq`` (:func:`end_rates_into`), the residual
    ``a₁ + (D + Γ) v₁ + f − b`` into ``solve.residual`` and
    ``solve.norms = [‖f‖, max(‖f_elastic‖, ‖f_contact‖)]``.
    """
    start, end = body_state(start_data, r), body_state(end_data, r)
    solve = deformation_solve(solve_data, r)
    q1, f, K = end.q, solve.f, solve.K
    elastic2 = 0.0
    for j in range(r):
        elastic2 += f[j] * f[j]
        end.f_elastic[j] = f[j]
    if k_ex != 0.0:
        for j in range(r):
            f[j] += k_ex * q1[j]
            K[j, j] += k_ex
    add_fictitious(q1, solve.fictitious0, solve.fictitious_K, f, K)
    contact2 = 0.0
    if active:
        for j in range(r):
            f[j] -= contact_generalized[j]
            contact2 += contact_generalized[j] * contact_generalized[j]
            for k in range(r):
                K[j, k] += contact_stiffness[j, k]
    total2 = 0.0
    for j in range(r):
        total2 += f[j] * f[j]
    solve.norms[0] = np.sqrt(total2)
    solve.norms[1] = np.sqrt(max(elastic2, contact2))
    v1, a1 = end.qd, end.qa
    end_rates_into(solve.scheme, dt, dq, start.qd, start.qa, v1, a1)
    norm2 = 0.0
    for j in range(r):
        value = a1[j] + f[j] - solve.b[j]
        for k in range(r):
            value += solve.damping[j, k] * v1[k]
        solve.residual[j] = value
        norm2 += value * value
    return np.sqrt(norm2)


@njit
def end_rates_into(c, dt, dq, qd, qa, v1, a1):
    """v₁, a₁ of the increment ``dq`` from q̇, q̈ with the scheme's coefficients ``c`` =
    ``[c_a, k_v, k_a, c_v, j_v]``: a second-order scheme (k_a ≠ 0, Newmark, k_v = c_a) as
    ``v₁ = c_v/h Δq − j_v q̇``, ``a₁ = c_a/h² (Δq − h q̇) − k_a q̈``, a first-order one
    (backward Euler) as the difference quotients ``v₁ = Δq/h``, ``a₁ = (v₁ − q̇)/h``."""
    if c[2] != 0.0:
        for j in range(dq.shape[0]):
            v1[j] = c[3] / dt * dq[j] - c[4] * qd[j]
            a1[j] = c[0] / (dt * dt) * (dq[j] - dt * qd[j]) - c[2] * qa[j]
    else:
        for j in range(dq.shape[0]):
            v1[j] = dq[j] / dt
            a1[j] = (v1[j] - qd[j]) / dt


@njit
def body_angular_velocity_into(R, L, h, inverse, out):
    """The body angular velocity ``ω = I⁻¹ (Rᵀ L − h)`` (3,) rad/s into ``out``: R (3, 3)
    the body-to-world rotation, L (3,) the world angular momentum about c (kg·m²/s), h
    (3,) the deformation's relative momentum and ``inverse`` (3, 3) I⁻¹ (body frame)."""
    b0 = R[0, 0] * L[0] + R[1, 0] * L[1] + R[2, 0] * L[2] - h[0]
    b1 = R[0, 1] * L[0] + R[1, 1] * L[1] + R[2, 1] * L[2] - h[1]
    b2 = R[0, 2] * L[0] + R[1, 2] * L[1] + R[2, 2] * L[2] - h[2]
    for a in range(3):
        out[a] = inverse[a, 0] * b0 + inverse[a, 1] * b1 + inverse[a, 2] * b2


@njit
def newton_base(damping1, ca_dt2, cv_dt, base):
    """base = c_a/Δt² I + c_v/Δt (D + Γ)."""
    r = base.shape[0]
    for j in range(r):
        for k in range(r):
            base[j, k] = cv_dt * damping1[j, k]
        base[j, j] += ca_dt2


@njit
def trial(q, dq, delta, fraction, dq_trial, q1):
    """Δq_trial = Δq − fraction δ, q₁ = q + Δq_trial."""
    for j in range(q.shape[0]):
        dq_trial[j] = dq[j] - fraction * delta[j]
        q1[j] = q[j] + dq_trial[j]


@njit
def commit_energy(r, k_ex, contact_energy, frame_data, start_data, end_data, kick_data,
                  solve_data, scratch_data):
    """Energies of the new state ``end`` into ``scratch.energies``: [kinetic + example
    spring + contact (J), work of the step (J), trapezoidal work of the elastic force
    ½ (f₀ + f₁)·(q₁ − q₀) (J)]; False if the state or the first energy is not finite."""
    frame = frame_arrays(frame_data, r)
    start, end = body_state(start_data, r), body_state(end_data, r)
    kick = rigid_kick(kick_data)
    solve = deformation_solve(solve_data, r)
    work = scratch(scratch_data, r)
    mass = frame.mass[0]
    p1, R1, L1, c1, q1, v1 = end.p, end.R, end.L, end.c, end.q, end.qd
    finite = True
    for a in range(3):
        finite = finite and np.isfinite(p1[a]) and np.isfinite(L1[a]) and np.isfinite(c1[a])
        for b_ in range(3):
            finite = finite and np.isfinite(R1[a, b_])
    for j in range(r):
        finite = finite and np.isfinite(q1[j]) and np.isfinite(v1[j])
    if not finite:
        return False
    inertia, inverse, tmp = work.m33[5], work.m33[6], work.m33[7]
    h = tmp[0]
    inertia_momentum_into(q1, v1, frame, inertia, h)
    if not inverse3_into(inertia, inverse):
        return False
    omega = tmp[2]
    body_angular_velocity_into(R1, L1, h, inverse, omega)
    kinetic = 0.0
    for a in range(3):
        kinetic += 0.5 * p1[a] * p1[a] / mass + omega[a] * h[a]
        for b_ in range(3):
            kinetic += 0.5 * omega[a] * inertia[a, b_] * omega[b_]
    spring = 0.0
    for j in range(r):
        kinetic += 0.5 * v1[j] * v1[j]
        spring += 0.5 * k_ex * q1[j] * q1[j]
    rigid_work = 0.0
    turn_work = 0.0
    omega_mid = kick.omega_mid
    for a in range(3):
        rigid_work += kick.dp[a] * (kick.v0[a] + p1[a] / mass)
        turn_work += kick.dL[a] * (R1[a, 0] * omega_mid[0] + R1[a, 1] * omega_mid[1]
                                   + R1[a, 2] * omega_mid[2])
    load_work = 0.0
    elastic_work = 0.0
    q0, f0, f1 = start.q, start.f_elastic, end.f_elastic
    for j in range(r):
        load_work += solve.b[j] * (q1[j] - q0[j])
        elastic_work += 0.5 * (f0[j] + f1[j]) * (q1[j] - q0[j])
    energies = work.energies
    energies[0] = kinetic + spring + contact_energy
    energies[1] = 0.5 * abs(rigid_work) + abs(turn_work) + abs(load_work)
    energies[2] = elastic_work
    return np.isfinite(energies[0])


@njit
def contact_theta_into(M6, K6, dt, L, A):
    """θ of the contact kick (:func:`lbshape.dynamics.free_body.contact_theta`) with work
    arrays L, A (6, 6): ω_c² = λ_max(L⁻¹ K₆ L⁻ᵀ), ``M₆ = L Lᵀ``."""
    n = M6.shape[0]
    for i in range(n):
        for j in range(n):
            L[i, j] = M6[i, j]
    if not cholesky_in_place(L):
        return 1.0
    for j in range(n):  # A = L⁻¹ K₆ (column by column), then A ← L⁻¹ Aᵀ
        for i in range(n):
            value = K6[i, j]
            for k in range(i):
                value -= L[i, k] * A[k, j]
            A[i, j] = value / L[i, i]
    for i in range(n):
        for j in range(i):
            A[i, j], A[j, i] = A[j, i], A[i, j]
    for j in range(n):
        for i in range(n):
            value = A[i, j]
            for k in range(i):
                value -= L[i, k] * A[k, j]
            A[i, j] = value / L[i, i]
    omega2 = max_symmetric_eigenvalue(A)
    resolved = np.sqrt(max(omega2, 0.0)) * dt
    return 0.5 + 0.5 * min(max(resolved - 0.5, 0.0), 1.0)


@njit
def loads_into(rotation, q, scales, forces, P, Z0, Z1, force, torque, generalized, work):
    """Σ_l scale_l · (force (3,) world, torque about c (3,) world, generalized (r,)) of the
    stacked loads (:class:`~lbshape.dynamics.free_body.FreeLoad` fields with a leading
    load axis) at (R, q).

    ``Uᵀ Rᵀ f = Σ_ab R_ab P[:, b, a]``; torque ``R (ε : (W Rᵀ... ))``: body torque
    ``τ_c = ε_cde Σ_a W_da R_ae`` with ``W = Z0 + Σ_j q_j Z1_j``. ``work`` (2, 3, 3).
    """
    r = generalized.shape[0]
    force[:] = 0.0
    torque[:] = 0.0
    generalized[:] = 0.0
    W, B = work[0], work[1]
    for load in range(scales.shape[0]):
        s = scales[load]
        if s == 0.0:
            continue
        for a in range(3):
            force[a] += s * forces[load, a]
        for j in range(r):
            value = 0.0
            for a in range(3):
                for b in range(3):
                    value += rotation[a, b] * P[load, j, b, a]
            generalized[j] += s * value
        for d in range(3):
            for a in range(3):
                value = Z0[load, d, a]
                for j in range(r):
                    value += q[j] * Z1[load, j, d, a]
                W[d, a] = value
        for d in range(3):
            for e in range(3):
                B[d, e] = W[d, 0] * rotation[0, e] + W[d, 1] * rotation[1, e] + \
                    W[d, 2] * rotation[2, e]
        t0, t1, t2 = B[1, 2] - B[2, 1], B[2, 0] - B[0, 2], B[0, 1] - B[1, 0]
        for a in range(3):
            torque[a] += s * (rotation[a, 0] * t0 + rotation[a, 1] * t1 + rotation[a, 2] * t2)
