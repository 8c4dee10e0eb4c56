"""Reduced simulation of a free body: rigid frame + body-frame deformation (paper §5).

State: the rigid part (:class:`~lbshape.dynamics.rigid_frame.RigidState`: centre of
mass c, linear momentum p, rotation R, angular momentum L, all world) and the
deformation q (r,) with velocity q̇ in the body frame, in the frame convention of
:mod:`lbshape.dynamics.fictitious` (``x_i = c + R (X̄_i + U_i q)``).

One step of length Δt from t₀ to t₁ (staggered; every array is r-, r²- or 3-sized,
contact aside, which touches surface vertices only when the bounding sphere
reaches a plane):

1. **interpolation**: example weights and target ``q*`` from q (as in
   :mod:`lbshape.dynamics.reduced`);
2. **rigid update**: loads (force and torque about c, world) and contact at t₀;
   the generalized rigid velocity ν = (v, ω_world) takes the linearly implicit
   θ-kick ``(M₆ + θ² Δt² K₆) Δν = Δt F₆ − θ Δt² K₆ ν₀`` (``M₆ = diag(m I, R I(q) Rᵀ)``,
   K₆ the contact stiffness; θ = ½, trapezoidal and conservative, while the contact
   frequency is resolved, up to θ = 1, backward Euler, when it is not:
   :func:`contact_theta`; stable for any penalty stiffness), which changes p and L
   by ``M₆ Δν``; then ``c₁ = c₀ + Δt (v₀ + v₁)/2`` (exact for a ballistic throw) and
   the torque-free Cayley–midpoint rotation
   (:func:`~lbshape.dynamics.rigid_frame.rotate`) with I(q₀) and h(q₀, q̇₀);
3. **contact**: the planes' penalty forces on the deformation, implicit in q at
   the new pose (c₁, R₁);
4. **deformation solve**: Newmark (β = ¼, γ = ½) or backward Euler on
   ``q̈ + (D + Γ(ω)) q̇ + f_int(q) + k_ex q + F_euler(q) + F_centrifugal(q) − F_contact(q)
   = Uᵀ R₁ᵀ f_ext(t₁) + k_ex q*``, D = αI + βK₀ (deformation only: rigid motion is
   never damped), ω the midpoint body angular velocity of step 2 and ω̇ its
   difference quotient, Newton on a dense r × r system.

Without loads and contact p and L are conserved to round-off (they change only by
impulses) and R stays on SO(3) (Cayley map). Failures — Newton, a non-finite state,
an energy blow-up (total energy above 10³ × the initial energy plus the absolute
work of loads and contact), a rotation step too large for the spin, or a vertex
pushed through a plane by more than the body's radius — raise
:class:`~lbshape.errors.SolverError` naming the step; :meth:`FreeBodySimulation.run`
turns it into ``stable = False`` with the message.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from lbshape.dynamics.contact import PlaneContact
from lbshape.dynamics.fictitious import LEVI_CIVITA, FrameTensors
from lbshape.dynamics.loads import TimeProfile
from lbshape.dynamics.record import RunRecord
from lbshape.dynamics.rigid_frame import RigidState, rotate
from lbshape.errors import LbshapeError, SolverError
from lbshape.shapespace.example_driver import ExampleDriver

log = logging.getLogger(__name__)

#: Newmark / backward-Euler coefficients (c_a, c_v) of dR/dΔq = c_a/Δt² + c_v/Δt D + K
_SCHEMES = {"newmark": (4.0, 2.0), "backward-euler": (1.0, 1.0)}
#: energy blow-up factor of the divergence monitor
ENERGY_FACTOR = 1e3


@dataclass(frozen=True)
class FreeLoad:
    """A load on a free body, reduced to small tensors (forces f_i are world vectors).

    Attributes:
        force: (3,) total force Σ f_i (N).
        P: (r, 3, 3) ``P[j, b, a] = Σ_i U_ibj f_ia``: ``Uᵀ Rᵀ f = Σ_ab R_ab P[:, b, a]``.
        Z0: (3, 3) ``Σ_i X̄_id f_ia`` (N·m), indices [d, a].
        Z1: (r, 3, 3) ``Σ_i U_idj f_ia``, indices [j, d, a].
        profile: time profile.
    """

    force: np.ndarray
    P: np.ndarray
    Z0: np.ndarray
    Z1: np.ndarray
    profile: TimeProfile

    @classmethod
    def from_pattern(cls, pattern: np.ndarray, U: np.ndarray, body_points: np.ndarray,
                     profile: TimeProfile) -> FreeLoad:
        """Reduce a world nodal force pattern (3n,) N; ``body_points`` (n, 3) = X̄."""
        f = np.asarray(pattern, dtype=float).reshape(-1, 3)
        n, r = f.shape[0], U.shape[1]
        Ur = np.asarray(U).reshape(n, 3, r)
        loaded = np.flatnonzero(np.abs(f).sum(axis=1))
        f, Ur, X = f[loaded], Ur[loaded], body_points[loaded]
        return cls(f.sum(axis=0), np.einsum("ibj,ia->jba", Ur, f), X.T @ f,
                   np.einsum("idj,ia->jda", Ur, f), profile)

    def evaluate(self, rotation: np.ndarray, q: np.ndarray, t: float):
        """``(force (3,) world, torque about c (3,) world, generalized (r,))`` at t."""
        scale = self.profile(t)
        if not scale:
            return np.zeros(3), np.zeros(3), np.zeros(self.P.shape[0])
        W = self.Z0 + np.einsum("j,jda->da", q, self.Z1)
        torque_body = np.einsum("cde,ae,da->c", LEVI_CIVITA, rotation, W)
        generalized = np.einsum("ab,jba->j", rotation, self.P)
        return scale * self.force, scale * (rotation @ torque_body), scale * generalized


@dataclass(frozen=True)
class FreeBodyRecord(RunRecord):
    """What a free-body run produced: the common record plus the rigid frame.

    ``states`` are the body-frame reduced coordinates q; every sampled array below
    is taken at ``times`` (f,), every per-step array has one entry per step (k,).

    Attributes:
        centers: (f, 3) centre of mass (m, world).
        rotations: (f, 3, 3) body-to-world rotations.
        momenta: (f, 3) linear momentum (kg·m/s, world).
        angular_momenta: (f, 3) angular momentum about c (kg·m²/s, world).
        energies: (f,) total energy (J) without the gravity potential.
        t_rigid_ms, t_contact_ms, t_solve_ms: (k,) per-step wall times of the rigid
            update, the contact evaluations and the deformation solve (ms).
        contact_depth: (k,) largest penetration per step (m).
        rest_points: (n, 3) rest positions X (m); ``body_points`` (n, 3) X̄ = X − X_cm.
    """

    centers: np.ndarray | None = None
    rotations: np.ndarray | None = None
    momenta: np.ndarray | None = None
    angular_momenta: np.ndarray | None = None
    energies: np.ndarray | None = None
    t_rigid_ms: np.ndarray | None = None
    t_contact_ms: np.ndarray | None = None
    t_solve_ms: np.ndarray | None = None
    contact_depth: np.ndarray | None = None
    rest_points: np.ndarray | None = None
    body_points: np.ndarray | None = None

    def displacements(self, basis: np.ndarray | None = None) -> np.ndarray:
        """(f, n, 3) world displacements ``x − X = c + R (X̄ + U q) − X`` (m); basis = U."""
        if basis is None or self.rest_points is None:
            raise LbshapeError("free-body displacements need the basis U and the rest points")
        n = self.rest_points.shape[0]
        local = self.body_points[None] + (self.states @ np.asarray(basis).T).reshape(-1, n, 3)
        world = np.einsum("fij,fnj->fni", self.rotations, local) + self.centers[:, None, :]
        return world - self.rest_points[None]

    def breakdown(self, *, warmup: int = 0) -> dict:
        """Per-step mean cost (ms) after ``warmup`` steps: interp, rigid, contact, solve."""
        def mean(values: np.ndarray) -> float:
            data = values[warmup:] if values.size > warmup else values
            return float(data.mean()) if data.size else 0.0

        return {"interp": mean(self.t_interp_ms), "rigid": mean(self.t_rigid_ms),
                "contact": mean(self.t_contact_ms), "solve": mean(self.t_solve_ms)}


class FreeBodySimulation:
    """Reduced free-body dynamics (see the module docstring).

    Args:
        elastic: reduced internal force model (``force_and_tangent(q)``, ``energy(q)``).
        frame: the body's :class:`~lbshape.dynamics.fictitious.FrameTensors`.
        dt: time step (s).
        integrator: ``"newmark"`` or ``"backward-euler"``.
        alpha, beta: Rayleigh coefficients of the deformation (1/s, s).
        loads: loads reduced by :meth:`FreeLoad.from_pattern`.
        driver: example driver or ``None``; ``k_ex``: example stiffness (1/s²).
        contact: penalty contact (body frame centred at the centre of mass) or ``None``.
        velocity: (3,) initial velocity of the centre of mass (m/s, world).
        angular_velocity: (3,) initial angular velocity (rad/s, world).
        q0, qd0: (r,) initial deformation and its rate (default 0).
        newton_rtol: relative Newton tolerance; ``max_iterations`` per step.
        rest_points: (n, 3) rest positions X (m), for the world displacements of the
            record (optional).
    """

    def __init__(
        self,
        elastic,
        frame: FrameTensors,
        *,
        dt: float,
        integrator: str = "newmark",
        alpha: float = 0.0,
        beta: float = 0.0,
        loads: Sequence[FreeLoad] = (),
        driver: ExampleDriver | None = None,
        k_ex: float = 0.0,
        contact: PlaneContact | None = None,
        velocity: Sequence[float] = (0.0, 0.0, 0.0),
        angular_velocity: Sequence[float] = (0.0, 0.0, 0.0),
        q0: np.ndarray | None = None,
        qd0: np.ndarray | None = None,
        newton_rtol: float = 1e-8,
        max_iterations: int = 20,
        rest_points: np.ndarray | None = None,
    ):
        self.rest_points = None if rest_points is None else np.asarray(rest_points, dtype=float)
        if integrator not in _SCHEMES:
            raise LbshapeError(f"integrator must be one of {tuple(_SCHEMES)}, got {integrator!r}")
        if not (np.isfinite(dt) and dt > 0):
            raise LbshapeError(f"time step dt must be > 0 s, got {dt}")
        r = frame.r
        self.elastic, self.frame, self.r = elastic, frame, r
        self.dt, self.scheme = float(dt), integrator
        self.loads = list(loads)
        self.driver = driver if (driver is not None and k_ex > 0.0) else None
        self.k_ex = float(k_ex) if self.driver is not None else 0.0
        self.contact = contact
        self.rtol, self.max_iterations = float(newton_rtol), int(max_iterations)
        self.q_target = np.zeros(r)
        _, K0 = elastic.force_and_tangent(np.zeros(r))
        self.damping = alpha * np.eye(r) + beta * K0
        self.q = np.zeros(r) if q0 is None else np.array(q0, dtype=float)
        self.qd = np.zeros(r) if qd0 is None else np.array(qd0, dtype=float)
        if self.q.shape != (r,) or self.qd.shape != (r,):
            raise LbshapeError(f"q0 and qd0 must have shape ({r},)")
        inertia = frame.inertia(self.q)
        h = frame.relative_momentum(self.q, self.qd)
        omega_world = np.asarray(angular_velocity, dtype=float)
        velocity = np.asarray(velocity, dtype=float)
        if omega_world.shape != (3,) or velocity.shape != (3,):
            raise LbshapeError("initial velocity and angular velocity must be 3-vectors")
        self.rigid = RigidState(frame.center.copy(), frame.mass * velocity, np.eye(3),
                                inertia @ omega_world + h)
        self.time = 0.0
        self.steps_taken = 0
        self._depth, self._contact_energy, self._force_scale = 0.0, 0.0, 0.0
        omega = self.omega()
        f, _ = self._deformation_force(self.q, omega, np.zeros(3), None)
        rhs = self._load_q(self.rigid.rotation, self.time) - (
            self.damping + frame.coriolis(omega)) @ self.qd - f
        self.qa = rhs
        self.energy0 = self.energy()
        self.work = 0.0

    # ------------------------------------------------------------ quantities
    def omega(self) -> np.ndarray:
        """(3,) current body angular velocity (rad/s)."""
        inertia = self.frame.inertia(self.q)
        h = self.frame.relative_momentum(self.q, self.qd)
        return np.linalg.solve(inertia, self.rigid.rotation.T @ self.rigid.angular_momentum - h)

    def energy(self, contact_energy: float | None = None) -> float:
        """Total energy (J): rigid and relative kinetic, elastic, example spring, contact
        (``contact_energy`` in J if already known)."""
        omega = self.omega()
        inertia = self.frame.inertia(self.q)
        h = self.frame.relative_momentum(self.q, self.qd)
        p = self.rigid.momentum
        kinetic = (0.5 * float(p @ p) / self.frame.mass + 0.5 * float(omega @ inertia @ omega)
                   + float(omega @ h) + 0.5 * float(self.qd @ self.qd))
        potential = float(self.elastic.energy(self.q)) + 0.5 * self.k_ex * float(self.q @ self.q)
        if self.contact is not None:
            if contact_energy is None:
                contact_energy = self.contact.evaluate(self.rigid.center, self.rigid.rotation,
                                                       self.q, rigid=False).energy
            potential += contact_energy
        return kinetic + potential

    # ---------------------------------------------------------------- forces
    def _load_q(self, rotation: np.ndarray, t: float) -> np.ndarray:
        total = self.k_ex * self.q_target if self.k_ex else np.zeros(self.r)
        for load in self.loads:
            total = total + load.evaluate(rotation, self.q, t)[2]
        return total

    def _deformation_force(self, q, omega, omega_dot, pose):
        """Position-dependent deformation force (r,) and tangent (r, r); ``pose`` = (c, R)."""
        f, K = self.elastic.force_and_tangent(q)
        f, K = np.array(f, dtype=float), np.array(K, dtype=float)
        self._force_scale = _norm(f)
        if self.k_ex:
            f += self.k_ex * q
            K += self.k_ex * np.eye(self.r)
        fe, Ke = self.frame.euler(q, omega_dot)
        fc, Kc = self.frame.centrifugal(q, omega)
        f += fe + fc
        K += Ke + Kc
        depth = 0.0
        if pose is not None and self.contact is not None:
            res = self.contact.evaluate(pose[0], pose[1], q, rigid=False)
            f -= res.generalized
            K += res.stiffness_q
            depth, self._contact_energy = res.depth, res.energy
            self._force_scale = max(self._force_scale, _norm(res.generalized))
        self._depth = depth
        return f, K

    # ------------------------------------------------------------------ step
    def step(self, index: int | None = None) -> dict:
        """Advance one step; return its timings (ms), Newton iterations and contact depth.

        Raises:
            SolverError: see the module docstring; the state is left unchanged.
        """
        index = self.steps_taken + 1 if index is None else index
        dt, frame, t1 = self.dt, self.frame, self.time + self.dt
        started = time.perf_counter()
        if self.driver is not None:
            self.q_target = self.driver.target(self.q).q_target
        t_interp = time.perf_counter()

        # --- rigid update
        rigid = self.rigid
        R0 = rigid.rotation
        inertia = frame.inertia(self.q)
        h = frame.relative_momentum(self.q, self.qd)
        omega0 = np.linalg.solve(inertia, R0.T @ rigid.angular_momentum - h)
        force, torque = np.zeros(3), np.zeros(3)
        for load in self.loads:
            f_l, tau_l, _ = load.evaluate(R0, self.q, self.time)
            force += f_l
            torque += tau_l
        t_contact0 = time.perf_counter()
        K6 = None
        if self.contact is not None:
            res = self.contact.evaluate(rigid.center, R0, self.q)
            if res.active:
                force += res.force
                torque += res.torque
                K6 = res.stiffness_rigid
        t_contact1 = time.perf_counter()
        m = frame.mass
        inertia_world = R0 @ inertia @ R0.T
        v0 = rigid.momentum / m
        if K6 is None:
            dp, dL = dt * force, dt * torque
        else:
            M6 = np.zeros((6, 6))
            M6[:3, :3] = m * np.eye(3)
            M6[3:, 3:] = inertia_world
            nu0 = np.concatenate([v0, R0 @ omega0])
            theta = contact_theta(M6, K6, dt)
            rhs = dt * np.concatenate([force, torque]) - theta * dt * dt * (K6 @ nu0)
            impulse = M6 @ np.linalg.solve(M6 + theta * theta * dt * dt * K6, rhs)
            dp, dL = impulse[:3], impulse[3:]
        p1 = rigid.momentum + dp
        c1 = rigid.center + 0.5 * dt * (rigid.momentum + p1) / m
        L1 = rigid.angular_momentum + dL
        # inertia and relative momentum at the predicted mid-step deformation
        q_mid = self.q + 0.5 * dt * self.qd + 0.125 * dt * dt * self.qa
        qd_mid = self.qd + 0.5 * dt * self.qa
        inertia_mid = frame.inertia(q_mid)
        h_mid = frame.relative_momentum(q_mid, qd_mid)
        R1, body1, omega_mid = rotate(R0, R0.T @ L1, inertia_mid, h_mid, dt, step=index,
                                      time=t1)
        omega1 = np.linalg.solve(inertia_mid, body1 - h_mid)
        omega_dot = (omega1 - np.linalg.solve(inertia_mid, R0.T @ L1 - h_mid)) / dt
        t_rigid = time.perf_counter()

        # --- deformation solve (contact implicit at the new pose)
        ca, cv = _SCHEMES[self.scheme]
        damping = self.damping + frame.coriolis(omega1)
        b = self._load_q(R1, t1)
        q, qd, qa = self.q, self.qd, self.qa
        dq = dt * qd + 0.5 * dt * dt * qa if self.scheme == "newmark" else dt * qd
        base = ca / dt**2 * np.eye(self.r) + cv / dt * damping
        contact_seconds = 0.0
        scale = max(_norm(b), _norm(qa))

        def evaluate(dq):
            nonlocal contact_seconds
            before = time.perf_counter()
            f, K = self._deformation_force(q + dq, omega1, omega_dot, (c1, R1))
            if self.contact is not None:
                contact_seconds += time.perf_counter() - before
            v1, a1 = self._kinematics(dq, dt)
            residual = a1 + damping @ v1 + f - b
            norm = _norm(residual)
            if not math.isfinite(norm):
                raise SolverError(f"non-finite deformation residual at step {index} "
                                  f"(t = {t1:.6g} s)")
            return f, K, v1, a1, residual, norm

        f, K, v1, a1, residual, norm = evaluate(dq)
        scale = max(scale, norm, _norm(f), self._force_scale)
        for iteration in range(self.max_iterations + 1):
            noise = 64 * np.finfo(float).eps * (ca / dt**2 * _norm(dq) + _norm(f) + _norm(b)
                                                 + ca / dt * _norm(qd) + _norm(qa))
            if norm <= self.rtol * scale or norm <= noise:
                break
            if iteration == self.max_iterations:
                raise SolverError(
                    f"Newton did not converge at step {index} (t = {t1:.6g} s): relative "
                    f"residual {norm / scale:.3e} after {iteration} iterations")
            try:
                delta = sla.solve(base + K, residual, check_finite=False)
            except sla.LinAlgError as exc:
                raise SolverError(f"singular Newton matrix at step {index} "
                                  f"(t = {t1:.6g} s): {exc}") from None
            # backtracking: contact makes the residual only piecewise smooth
            fraction = 1.0
            while True:
                trial = evaluate(dq - fraction * delta)
                if trial[-1] < norm or fraction <= 1.0 / 64:
                    break
                fraction *= 0.5
            dq = dq - fraction * delta
            f, K, v1, a1, residual, norm = trial
        q1 = q + dq
        depth = self._depth
        if self.contact is not None and depth > self.contact.radius0:
            raise SolverError(f"contact failed at step {index} (t = {t1:.6g} s): a vertex is "
                              f"{depth:.3g} m behind a plane (the body's radius is "
                              f"{self.contact.radius0:.3g} m); lower dt or raise the stiffness")
        finished = time.perf_counter()

        # --- commit and monitor
        old = (self.rigid, self.q, self.qd, self.qa)
        self.rigid = RigidState(c1, p1, R1, L1)
        self.q, self.qd, self.qa = q1, v1, a1
        energy = self.energy(self._contact_energy if self.contact is not None else None)
        work = self.work + abs(float(dp @ (v0 + p1 / m))) * 0.5 + abs(
            float(dL @ (R1 @ omega_mid))) + abs(float(b @ (q1 - q)))
        state = np.concatenate([c1, p1, R1.ravel(), L1, q1, v1])
        budget = abs(self.energy0) + work
        if not (np.isfinite(state).all() and math.isfinite(energy)) or (
                budget > 0 and energy > ENERGY_FACTOR * budget):
            self.rigid, self.q, self.qd, self.qa = old
            what = "non-finite state" if not np.isfinite(state).all() else (
                f"energy blew up ({energy:.3e} J > {ENERGY_FACTOR:g} x budget {budget:.3e} J)")
            raise SolverError(f"{what} at step {index} (t = {t1:.6g} s)")
        self.work = work
        self.time, self.steps_taken = t1, index
        contact_ms = 1e3 * (t_contact1 - t_contact0 + contact_seconds)
        return {
            "interp": 1e3 * (t_interp - started),
            "rigid": 1e3 * (t_rigid - t_interp) - 1e3 * (t_contact1 - t_contact0),
            "contact": contact_ms,
            "solve": 1e3 * (finished - t_rigid) - 1e3 * contact_seconds,
            "total": 1e3 * (finished - started),
            "iterations": iteration,
            "depth": depth,
            "energy": energy,
        }

    def _kinematics(self, dq: np.ndarray, dt: float):
        if self.scheme == "newmark":
            return 2.0 / dt * dq - self.qd, 4.0 / dt**2 * (dq - dt * self.qd) - self.qa
        v1 = dq / dt
        return v1, (v1 - self.qd) / dt

    # ------------------------------------------------------------------- run
    def run(self, steps: int, *, stride: int = 1) -> FreeBodyRecord:
        """Advance ``steps`` steps keeping every ``stride``-th state (and the initial one);
        a failure ends the run with ``stable=False`` and the message."""
        stride = int(stride)
        if int(steps) < 1 or stride < 1:
            raise LbshapeError(f"steps and stride must be >= 1, got {steps} and {stride}")
        sampled = {key: [] for key in ("times", "states", "centers", "rotations", "momenta",
                                       "angular_momenta", "energies")}
        per_step = {key: [] for key in ("interp", "rigid", "contact", "solve", "total",
                                        "iterations", "depth")}

        def sample(energy: float) -> None:
            for key, value in (("times", self.time), ("states", self.q),
                               ("centers", self.rigid.center),
                               ("rotations", self.rigid.rotation),
                               ("momenta", self.rigid.momentum),
                               ("angular_momenta", self.rigid.angular_momentum),
                               ("energies", energy)):
                sampled[key].append(np.array(value, dtype=float))

        sample(self.energy())
        stable, message = True, ""
        for index in range(1, int(steps) + 1):
            try:
                info = self.step()
            except SolverError as exc:
                stable, message = False, str(exc)
                log.error("free-body simulation stopped: %s", exc)
                break
            for key in per_step:
                per_step[key].append(info[key])
            if index % stride == 0:
                sample(info["energy"])
        arrays = {key: np.asarray(value) for key, value in sampled.items()}
        times = {key: np.asarray(value, dtype=float) for key, value in per_step.items()}
        return FreeBodyRecord(
            times=arrays["times"], states=arrays["states"], t_interp_ms=times["interp"],
            t_total_ms=times["total"],
            newton_iterations=np.asarray(per_step["iterations"], dtype=np.int64),
            stable=stable, message=message, centers=arrays["centers"],
            rotations=arrays["rotations"], momenta=arrays["momenta"],
            angular_momenta=arrays["angular_momenta"], energies=arrays["energies"],
            t_rigid_ms=times["rigid"], t_contact_ms=times["contact"], t_solve_ms=times["solve"],
            contact_depth=times["depth"], rest_points=self.rest_points,
            body_points=(None if self.rest_points is None
                         else self.rest_points - self.frame.center),
        )


def contact_theta(mass6: np.ndarray, stiffness6: np.ndarray, dt: float) -> float:
    """θ of the rigid contact kick: ½ (trapezoidal, conservative) while the stiffest
    contact frequency is resolved (ω_c Δt ≤ ½), 1 (backward Euler, L-stable, damps the
    unresolved contact oscillation) from ω_c Δt ≥ 3/2, linear in between.

    ω_c² is the largest eigenvalue of ``K₆ v = ω² M₆ v`` (6 × 6).
    """
    omega2 = float(sla.eigh(stiffness6, mass6, eigvals_only=True).max())
    resolved = math.sqrt(max(omega2, 0.0)) * dt
    return 0.5 + 0.5 * float(np.clip(resolved - 0.5, 0.0, 1.0))


def _norm(vector: np.ndarray) -> float:
    return math.sqrt(float(vector @ vector))
