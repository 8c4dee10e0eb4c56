"""The contact's part of a free body's step (:class:`FreeBodyContact`, a part of
:class:`~lbshape.dynamics.free_body.FreeBodySimulation`): the contact at the start of a
step (reused from the previous step's last evaluation when nothing moved), the θ of the
rigid kick (:func:`contact_theta`) and the contact sweeps (steps 2 and 5 of the step in
:mod:`lbshape.dynamics.free_body`).

**Friction** (a plane's μ > 0, :mod:`lbshape.dynamics.contact`): the contact vertices'
world velocities ``v + ω × R y_i + R U_i q̇`` give the regularised Coulomb force. In the
kick it is part of the contact (force, torque) C₀, C₁ and made implicit by its rate
matrix C₆ (``−∂(force, torque)/∂(v, ω)``): the matrix is ``M₆ + θ Δt C₆ + θ² Δt² K₆``,
the sweep's right-hand side gains ``θ Δt C₆ (ν₁ − ν₀)`` (zero at the fixed point).
After a sweep the kick takes the effective rate ``C₆ − rate X J⁻¹ Xᵀ`` (symmetric part;
X the contact's ``coupling`` of ν and q̇, J the deformation's Newton matrix): the
deformation answers a change of the rigid slip, so the friction depends less on ν than
C₆ says (with C₆ alone the car's wall impact ran the 12 sweeps, converging by ~0.8 per
sweep; with it 4–5). The first sweep of a pass takes the last pass's effective rate, C₆
at t₀ only where the contact begins (with C₆ the kicked slip sent half the resting car's
first deformation solves through 2–6 Newton iterations). In the deformation
solve it is evaluated at the pose (c₁, R₁), the kicked rigid velocities and the trial
q̇₁ (the scheme's kinematics of Δq), with its tangent (``∂q̇₁/∂q₁ = c_v/Δt``). With
μ = 0 on every plane nothing of this runs and the step is the frictionless one.
"""

from __future__ import annotations

import math

import numpy as np

from lbshape.dynamics.free_body_kernels import contact_theta_into

#: contact sweeps of a step stop when the end momenta move by less than this share of
#: the momenta and the step's impulse. On the car (no examples, 800 steps) 1e-6, 1e-4 and
#: 1e-3 give the same error against the full reference to 4 digits (14.55 %) at 1.07,
#: 0.90 and 0.80 ms per step (with Newton to 1e-5; the wall impact's steps take most of
#: it): 1e-4 keeps 10× margin over the smallest change that showed (rotation error
#: 12.640° → 12.649° at 1e-3)
SWEEP_RTOL = 1e-4
#: the second sweep is accepted when its error, estimated as ρ/(1 − ρ) times its change,
#: is within this share of SWEEP_RTOL, ρ the sweeps' contraction measured (third sweep's
#: change over the second's) on a pass of the same contact no more than
#: :data:`CONTRACTION_AGE` passes before (resting on the floor with friction the car's
#: sweeps contract by ρ ≈ 0.005). The change test alone allows about 0.1 wherever
#: ρ ≤ 0.1; with the first sweep on the last pass's friction rate 0.1 left the car's wall
#: impact 5.3e-5 from its converged run over 300 steps, 0.03 leaves it 6.8e-6
#: (``docs/decisions.md``)
SWEEP_ERROR_SHARE = 0.03
#: passes a measured contraction is used for before a pass measures it again
CONTRACTION_AGE = 8
#: a contraction above this is not used to accept a second sweep
CONTRACTION_LIMIT = 0.1
#: at most this many contact sweeps per step (the last one is accepted)
MAX_CONTACT_SWEEPS = 12


class FreeBodyContact:
    """The contact sweeps and the contact at the start of a step, for
    :class:`~lbshape.dynamics.free_body.FreeBodySimulation` (which holds the arrays the
    methods read: ``contact``, ``_now``, ``_next``, ``_kick_arrays``, ``_solve`` …)."""

    def _forget_contraction(self) -> None:
        """No contraction measured yet (:meth:`_sweep_converged`'s state: the last
        measured contraction, the passes since, and the last sweep's squared change)."""
        self._contraction, self._contraction_age, self._sweep_change = 1.0, CONTRACTION_AGE, 0.0

    def _contact_fresh(self) -> bool:
        """The contact's arrays hold the evaluation at the current state (c, R, q)."""
        contact = self.contact
        return (self.reuse_contact and contact is not None
                and contact.evaluated + contact.skipped == self._contact_calls)

    def _start_of_step(self) -> tuple[bool, float]:
        """The loads and the contact at t₀ into the kick's inputs; returns (the contact
        acts, the seconds the contact took)."""
        kick, state = self._kick_arrays, self._now
        self._loads.evaluate_into(state.R, state.q, self.time, kick.force, kick.torque,
                                  self._gen)
        started = self._clock()
        contact = self.contact
        active = False
        if contact is not None:
            if not self._contact_fresh():
                if contact.has_friction:  # the motion at t₀ (allocates; rare: not reused)
                    self._velocity[:] = state.p / self.frame.mass
                    self._omega[:] = state.R @ self.omega()
                contact.evaluate_into(state.c, state.R, state.q, True, self._velocity,
                                      self._omega, state.qd, self._cv_dt)
            active = contact.scalars[1] > 0
            kick.contact_force[:] = contact.force
            kick.contact_torque[:] = contact.torque
            kick.K6[:] = contact.stiffness_rigid
            if not (active and self._rate_held):
                kick.C6[:] = contact.damping_rigid
        self._rate_held = False
        return active, self._clock() - started

    def _sweep_again(self, sweeps: int) -> bool:
        """Whether the step needs another contact sweep: the contact acts at the end of the
        step, its frequency is resolved (θ = ½), and the end momenta (p₁, L₁ / radius) moved
        since the last sweep by more than :data:`SWEEP_RTOL` of the size of the momenta and
        the step's impulse (Δp, ΔL / radius) together (stops after
        :data:`MAX_CONTACT_SWEEPS`). Stores the contact and ν₁ the next sweep uses."""
        contact, kick, end = self.contact, self._kick_arrays, self._next
        if contact is None or contact.scalars[1] == 0 or kick.theta[0] != 0.5:
            self._contraction_age = CONTRACTION_AGE  # a new contact measures it afresh
            return False
        momentum, radius = kick.momentum_end, contact.radius0
        p1, L1, dp, dL = end.p, end.L, kick.dp, kick.dL
        change = 0.0
        size = 0.0
        for a in range(3):
            change += (p1[a] - momentum[a]) ** 2 + ((L1[a] / radius - momentum[3 + a]) ** 2)
            size += (p1[a] ** 2 + (L1[a] / radius) ** 2 + dp[a] ** 2 + (dL[a] / radius) ** 2)
            momentum[a], momentum[3 + a] = p1[a], L1[a] / radius
        if sweeps > 1 and self._sweep_converged(sweeps, change, size):
            return False
        if sweeps >= MAX_CONTACT_SWEEPS:
            return False
        kick.contact_end[:3] = contact.force
        kick.contact_end[3:] = contact.torque
        if sweeps == 1 and not np.any(kick.K6):  # the contact began within the step
            kick.K6[:] = contact.stiffness_rigid
        if contact.has_friction:  # the friction's rate at the end of this sweep
            self._effective_friction_rate(kick.C6)
            self._rate_held = True
        omega_body, R1, nu1 = kick.omega1, end.R, kick.nu_end
        for a in range(3):
            nu1[a] = p1[a] / self.frame.mass
            nu1[3 + a] = (R1[a, 0] * omega_body[0] + R1[a, 1] * omega_body[1]
                          + R1[a, 2] * omega_body[2])
        return True

    def _sweep_converged(self, sweeps: int, change: float, size: float) -> bool:
        """Whether sweep ``sweeps`` (≥ 2), which moved the end momenta by √``change``
        against their size √``size``, is accepted: by the change test
        (:data:`SWEEP_RTOL`), or, the second sweep, by its error estimated from a recent
        contraction (:data:`SWEEP_ERROR_SHARE`). A third sweep measures the contraction."""
        if sweeps == 3 and self._sweep_change > 0.0:
            self._contraction = math.sqrt(change / self._sweep_change)
            self._contraction_age = 0
        self._sweep_change = change
        if change <= (SWEEP_RTOL**2) * size:
            return True
        if sweeps != 2 or self._contraction_age >= CONTRACTION_AGE:
            return False
        ratio = self._contraction
        if ratio > CONTRACTION_LIMIT:
            return False
        self._contraction_age += 1
        estimate = ratio / (1.0 - ratio)
        return estimate * estimate * change <= (SWEEP_ERROR_SHARE * SWEEP_RTOL) ** 2 * size

    def _effective_friction_rate(self, out: np.ndarray) -> None:
        """The friction's rate matrix on the rigid velocity with the deformation's answer:
        a change δν of (v, ω) changes the slip, the deformation solve answers with
        ``δq̇ = −rate J⁻¹ Xᵀ δν`` (J its Newton matrix, X the contact's ``coupling``), so
        the friction (force, torque) changes by ``−(C₆ − rate X J⁻¹ Xᵀ) δν``; its
        symmetric part into ``out`` (6, 6). With C₆ alone the sweeps converged by ~0.8
        per sweep on the car's wall impact (the deformation takes the slip)."""
        contact, solve = self.contact, self._solve
        X, Y, product = contact.coupling, self._coupling_work, self._rate6
        if not self._lu.factor(solve.base, solve.K):
            out[:] = contact.damping_rigid
            return
        self._lu.solve_rows_into(X, Y)
        np.dot(X, Y.T, out=product)
        np.add(product, product.T, out=out)
        out *= -0.5 * self._cv_dt
        out += contact.damping_rigid


def contact_theta(mass6: np.ndarray, stiffness6: np.ndarray, dt: float) -> float:
    """θ of the rigid contact kick: ½ (trapezoidal, conservative) while the stiffest
    contact frequency is resolved (ω_c Δt ≤ ½), 1 (backward Euler, L-stable, damps the
    unresolved contact oscillation) from ω_c Δt ≥ 3/2, linear in between.

    ω_c² is the largest eigenvalue of ``K₆ v = ω² M₆ v`` (6 × 6, M₆ positive definite).
    """
    work = np.zeros((2, 6, 6))
    return float(contact_theta_into(np.asarray(mass6, dtype=float),
                                    np.asarray(stiffness6, dtype=float), float(dt), work[0],
                                    work[1]))
