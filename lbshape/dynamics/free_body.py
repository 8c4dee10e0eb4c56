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
   difference quotient, Newton on a dense r × r system;
5. **contact sweeps**: while a plane touches the body at the end of the step (and its
   contact frequency is resolved, θ = ½), steps 2–4 are repeated with the kick
   ``(M₆ + θ² Δt² K₆) Δν = Δt F_loads + ½ Δt (C₀ + C₁) + θ² Δt² K₆ (ν₁ − ν₀)``, C₁ and
   ν₁ the contact (force, torque) and the velocity at the end of the previous sweep,
   until the end momenta settle (:data:`SWEEP_RTOL`, at most :data:`MAX_CONTACT_SWEEPS`
   passes): the fixed point is the trapezoidal contact impulse ``M₆ Δν = Δt F_loads +
   ½ Δt (C₀ + C₁)`` of the rigid motion and the deformation together. The single pass
   used the contact at t₀ only, with the deformation's share lagging by a step: an
   impact then depended on the step size (the car's rebound off the wall without
   examples: 3.12 m/s at 1 ms, 3.54 m/s at 0.25 ms; swept: 3.692 and 3.689 m/s).

Without loads and contact p and L are conserved to round-off (they change only by
impulses) and R stays on SO(3) (Cayley map). Failures — Newton, a non-finite state,
an energy blow-up (total energy above 10³ × the initial energy plus the absolute
work of loads and contact), a rotation step too large for the spin, or a vertex
pushed through a plane by more than the body's radius — raise
:class:`~lbshape.errors.SolverError` naming the step; :meth:`FreeBodySimulation.run`
turns it into ``stable = False`` with the message. The energy monitor tracks the
elastic energy by the trapezoidal work of the elastic force, ``E(q₁) ≈ E(q₀) +
½ (f(q₀) + f(q₁))·(q₁ − q₀)`` (reset to the exact energy whenever that is computed),
and computes the exact elastic energy when the estimated total reaches
:data:`EXACT_ENERGY_FRACTION` of the limit, so the exact criterion decides every
failure while a normal step stays free of the allocating energy evaluation.

**The step path** is compiled and allocation-free, as in :mod:`lbshape.dynamics.reduced`:
state and work arrays are preallocated and swapped, the weights and target are written
in place, the elastic force and tangent come from
:meth:`~lbshape.elastic.reduced_forces.ReducedForceModel.force_and_tangent_into`, and
numba kernels do the rest: the loads (:func:`loads_into`), the rigid update
(:func:`_rigid_update`, with :func:`~lbshape.dynamics.rigid_frame.rotate_into`), the
frame tensors and fictitious forces (:mod:`lbshape.dynamics.fictitious`), the contact
(:meth:`~lbshape.dynamics.contact.PlaneContact.evaluate_into`, once per Newton
evaluation; the contact at the start of a step is the last evaluation of the previous
step — same configuration, same numbers — and is reused), the Newmark residual and
the LU solve of the Newton system (non-symmetric: the Euler and Coriolis terms are
skew). Each step's wall time is split into :data:`PHASES`
(:attr:`FreeBodySimulation.phase_seconds`).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from lbshape._jit import njit
from lbshape.dynamics.contact import PlaneContact
from lbshape.dynamics.fictitious import (
    FrameTensors,
    coriolis_into,
    fictitious_into,
    inertia_momentum_into,
)
from lbshape.dynamics.loads import TimeProfile
from lbshape.dynamics.record import RunRecord
from lbshape.dynamics.reduced import PHASES as FIXED_PHASES
from lbshape.dynamics.reduced import _axpy, _predict, cholesky_in_place, cholesky_solve_in_place
from lbshape.dynamics.rigid_frame import RigidState, inverse3_into, rotate_into, rotation_error
from lbshape.dynamics.sanity import DeformationBound
from lbshape.errors import LbshapeError, SolverError
from lbshape.shapespace.example_driver import ExampleDriver

log = logging.getLogger(__name__)

#: Newmark / backward-Euler coefficients (c_a, c_v) of dR/dΔq = c_a/Δt² + c_v/Δt D + K
_SCHEMES = {"newmark": (4.0, 2.0), "backward-euler": (1.0, 1.0)}
#: contact sweeps of a step stop when the end momenta move by less than this share of
#: the momenta and the step's impulse
SWEEP_RTOL = 1e-6
#: at most this many contact sweeps per step (the last one is accepted)
MAX_CONTACT_SWEEPS = 12
#: energy blow-up factor of the divergence monitor
ENERGY_FACTOR = 1e3
#: the monitor computes the exact elastic energy from this fraction of the limit on
EXACT_ENERGY_FRACTION = 0.1
#: the parts of a free-body step timed in :attr:`FreeBodySimulation.phase_seconds`: the
#: fixed-object phases (:data:`lbshape.dynamics.reduced.PHASES`, same meaning: the
#: example force is the step's generalized load ``k_ex q* + Uᵀ Rᵀ f_ext``, the internal
#: force and tangent include the fictitious forces) plus the rigid update and the contact
PHASES: tuple[str, ...] = ("weights", "target", "example_force", "rigid", "contact",
                           "internal_force_tangent", "solve", "overhead")
assert set(FIXED_PHASES) <= set(PHASES)


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
        stack = LoadStack([self])
        force, torque, generalized = np.zeros(3), np.zeros(3), np.zeros(self.P.shape[0])
        stack.evaluate_into(np.asarray(rotation, dtype=float), np.asarray(q, dtype=float), t,
                            force, torque, generalized)
        return force, torque, generalized


class LoadStack:
    """Several :class:`FreeLoad` as stacked arrays for :func:`loads_into` (no allocation
    per evaluation)."""

    def __init__(self, loads: Sequence[FreeLoad], r: int | None = None):
        loads = list(loads)
        r = loads[0].P.shape[0] if loads else int(r or 0)
        self.forces = np.array([load.force for load in loads], dtype=float).reshape(-1, 3)
        self.P = np.array([load.P for load in loads], dtype=float).reshape(-1, r, 3, 3)
        self.Z0 = np.array([load.Z0 for load in loads], dtype=float).reshape(-1, 3, 3)
        self.Z1 = np.array([load.Z1 for load in loads], dtype=float).reshape(-1, r, 3, 3)
        self.profiles = [load.profile for load in loads]
        self.scales = np.zeros(len(loads))
        self._work = np.zeros((2, 3, 3))

    def evaluate_into(self, rotation: np.ndarray, q: np.ndarray, t: float, force: np.ndarray,
                      torque: np.ndarray, generalized: np.ndarray) -> None:
        """Total force (3,) and torque about c (3,) (world) and generalized force (r,) at t."""
        for index, profile in enumerate(self.profiles):
            self.scales[index] = profile(t)
        loads_into(rotation, q, self.scales, self.forces, self.P, self.Z0, self.Z1, force,
                   torque, generalized, self._work)


@dataclass(frozen=True)
class FreeBodyRecord(RunRecord):
    """What a free-body run produced: the common record plus the rigid frame.

    ``states`` are the body-frame reduced coordinates q; every sampled array below
    is taken at ``times`` (f,), every per-step array has one entry per step (k,).
    The split of each step's time into :data:`PHASES` is the simulation's
    :attr:`FreeBodySimulation.phase_seconds`.

    Attributes:
        centers: (f, 3) centre of mass (m, world).
        rotations: (f, 3, 3) body-to-world rotations.
        momenta: (f, 3) linear momentum (kg·m/s, world).
        angular_momenta: (f, 3) angular momentum about c (kg·m²/s, world).
        energies: (f,) total energy (J) without the gravity potential.
        contact_depth: (k,) largest penetration per step (m).
        rest_points: (n, 3) rest positions X (m); ``body_points`` (n, 3) X̄ = X − X_cm.
    """

    centers: np.ndarray | None = None
    rotations: np.ndarray | None = None
    momenta: np.ndarray | None = None
    angular_momenta: np.ndarray | None = None
    energies: np.ndarray | None = None
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


class FreeBodySimulation:
    """Reduced free-body dynamics (see the module docstring).

    Args:
        elastic: reduced internal force model (``force_and_tangent(q)``, ``energy(q)``;
            ``force_and_tangent_into(q, f, K)`` for the compiled path).
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
        reuse_contact: reuse the previous step's last contact evaluation at the start
            of a step (same configuration; ``False`` evaluates it again, for checks).
        deformation_bound: the object's :class:`~lbshape.dynamics.sanity.DeformationBound`
            on the body-frame deformation q (a state beyond it stops the run), or ``None``.

    Attributes:
        q, qd, qa: (r,) deformation, its rate and acceleration at :attr:`time`.
        phase_seconds: (steps, len(PHASES)) wall time of each part of each step of the
            last :meth:`run` (s).
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
        reuse_contact: bool = True,
        deformation_bound: DeformationBound | None = None,
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
        self._loads = LoadStack(self.loads, r)
        self.driver = driver if (driver is not None and k_ex > 0.0) else None
        self.k_ex = float(k_ex) if self.driver is not None else 0.0
        self._in_place = self.driver is not None and hasattr(self.driver, "weights_into") \
            and hasattr(self.driver, "target_from_weights_into")
        self.contact = contact
        self.reuse_contact = bool(reuse_contact)
        self.deformation_bound = deformation_bound
        self.rtol, self.max_iterations = float(newton_rtol), int(max_iterations)
        self._into = hasattr(elastic, "force_and_tangent_into")
        self.q_target = np.zeros(r)
        _, K0 = elastic.force_and_tangent(np.zeros(r))
        self.damping = alpha * np.eye(r) + beta * np.asarray(K0, dtype=float)
        q = np.zeros(r) if q0 is None else np.array(q0, dtype=float)
        qd = np.zeros(r) if qd0 is None else np.array(qd0, dtype=float)
        if q.shape != (r,) or qd.shape != (r,):
            raise LbshapeError(f"q0 and qd0 must have shape ({r},)")
        omega_world = np.asarray(angular_velocity, dtype=float)
        velocity = np.asarray(velocity, dtype=float)
        if omega_world.shape != (3,) or velocity.shape != (3,):
            raise LbshapeError("initial velocity and angular velocity must be 3-vectors")
        self._allocate(r)
        self.q[:], self.qd[:] = q, qd
        self._c[:] = frame.center
        self._p[:] = frame.mass * velocity
        self._R[:] = np.eye(3)
        self._L[:] = frame.inertia(q) @ omega_world + frame.relative_momentum(q, qd)
        self.time = 0.0
        self.steps_taken = 0
        self.phase_seconds = np.zeros((0, len(PHASES)))
        self._contact_calls = -1  # contact calls when the last evaluation was committed
        self.sweeps = 0  # rigid kick + deformation solve passes of the last step (1: no sweep)
        self.total_sweeps = 0  # the same, summed over every step taken
        # initial acceleration: q̈ = b − (D + Γ(ω)) q̇ − f(q) (no contact, ω̇ = 0)
        omega = self.omega()
        f, _ = elastic.force_and_tangent(q)
        self._f_elastic0[:] = f
        f = np.array(f, dtype=float) + self.k_ex * q
        fe, _ = frame.centrifugal(q, omega)
        self._load_q(self._R, 0.0, self._b)
        self.qa[:] = self._b - (self.damping + frame.coriolis(omega)) @ qd - (f + fe)
        self._elastic_energy = 0.0  # the monitor's elastic energy at the committed state (J)
        self.energy0 = self.energy()
        self.work = 0.0

    def _allocate(self, r: int) -> None:
        """The state, its next-step copy and every work array of the step."""
        self.q, self.qd, self.qa = np.zeros(r), np.zeros(r), np.zeros(r)
        self._q1, self._v1, self._a1 = np.zeros(r), np.zeros(r), np.zeros(r)
        self._c, self._p, self._R, self._L = np.zeros(3), np.zeros(3), np.zeros((3, 3)), np.zeros(3)
        self._c1, self._p1, self._R1, self._L1 = (np.zeros(3), np.zeros(3), np.zeros((3, 3)),
                                                  np.zeros(3))
        self._dq, self._dqt = np.zeros(r), np.zeros(r)  # accepted and trial increments
        self._delta, self._b = np.zeros(r), np.zeros(r)
        self._f, self._K, self._res = np.zeros(r), np.zeros((r, r)), np.zeros(r)
        # elastic force at q₁ (last evaluation) and at q (the committed state)
        self._f_elastic, self._f_elastic0 = np.zeros(r), np.zeros(r)
        self._J = np.zeros((r, r))
        self._base = np.zeros((r, r))  # c_a/Δt² I + c_v/Δt (D + Γ(ω₁))
        self._damping1 = np.zeros((r, r))  # D + Γ(ω₁)
        self._force, self._torque, self._gen = np.zeros(3), np.zeros(3), np.zeros(r)
        #: rigid update outputs: ω₀, ω₁ (body, end of step), ω̇, ω_mid, Δp, ΔL, v₀, [θ, 0, 0]
        self._rigid_out = np.zeros((8, 3))
        #: contact sweeps: contact (force, torque) at t₀ and at the end of the last sweep,
        #: the contact stiffness K₆ of the kick, ν₁ of the last sweep, its (p₁, L₁ / radius)
        self._contact0_force, self._contact0_torque = np.zeros(3), np.zeros(3)
        self._contact1, self._K6 = np.zeros(6), np.zeros((6, 6))
        self._nu1, self._momentum1 = np.zeros(6), np.zeros(6)
        self._work33, self._work6 = np.zeros((8, 3, 3)), np.zeros((4, 6))
        self._work66 = np.zeros((4, 6, 6))
        self._contact_zero6 = np.zeros((6, 6))
        #: [‖f‖, max(‖f_elastic‖, ‖contact force‖)] of the last evaluation
        self._norms = np.zeros(2)
        #: [internal force, contact, rigid, generalized load, solve] seconds of a step
        self._seconds = np.zeros(5)
        self._energies = np.zeros(3)
        self._marks = np.zeros(len(PHASES) + 1)
        self._clock = time.perf_counter
        self._predictor = np.array([0.0, 0.0, 1.0 if self.scheme == "newmark" else 0.0])
        self._scheme_code = 0 if self.scheme == "newmark" else 1
        self._frame_arrays = self.frame.kernel_arrays

    # ------------------------------------------------------------ quantities
    @property
    def rigid(self) -> RigidState:
        """A copy of the rigid state (centre of mass, momenta, rotation) at :attr:`time`."""
        return RigidState(self._c.copy(), self._p.copy(), self._R.copy(), self._L.copy())

    def omega(self) -> np.ndarray:
        """(3,) current body angular velocity (rad/s)."""
        inertia = self.frame.inertia(self.q)
        h = self.frame.relative_momentum(self.q, self.qd)
        return np.linalg.solve(inertia, self._R.T @ self._L - h)

    def energy(self, contact_energy: float | None = None) -> float:
        """Total energy (J): rigid and relative kinetic, elastic, example spring, contact
        (``contact_energy`` in J if already known)."""
        omega = self.omega()
        inertia = self.frame.inertia(self.q)
        h = self.frame.relative_momentum(self.q, self.qd)
        p = self._p
        kinetic = (0.5 * float(p @ p) / self.frame.mass + 0.5 * float(omega @ inertia @ omega)
                   + float(omega @ h) + 0.5 * float(self.qd @ self.qd))
        self._elastic_energy = float(self.elastic.energy(self.q))
        potential = self._elastic_energy + 0.5 * self.k_ex * float(self.q @ self.q)
        if self.contact is not None:
            if contact_energy is None:
                if self._contact_fresh():
                    contact_energy = float(self.contact.scalars[0])
                else:
                    contact_energy = self.contact.evaluate(self._c, self._R, self.q,
                                                           rigid=False).energy
            potential += contact_energy
        return kinetic + potential

    # ---------------------------------------------------------------- pieces
    def _load_q(self, rotation: np.ndarray, t: float, out: np.ndarray) -> None:
        """The generalized load ``k_ex q* + Σ Uᵀ Rᵀ f_l(t)`` (r,) into ``out``."""
        self._loads.evaluate_into(rotation, self.q, t, self._force, self._torque, out)
        if self.k_ex:
            _axpy(self.k_ex, self.q_target, out)

    def _contact_fresh(self) -> bool:
        """The contact's arrays hold the evaluation at the current state (c, R, q)."""
        contact = self.contact
        return (self.reuse_contact and contact is not None
                and contact.evaluated + contact.skipped == self._contact_calls)

    def _evaluate(self, index: int, t1: float, times: np.ndarray) -> float:
        """Deformation force, tangent and residual at ``q₁ = q + Δq`` (``self._q1``) and the
        new pose; returns ‖residual‖. ``times`` accumulates [internal, contact] seconds."""
        clock = self._clock
        started = clock()
        if self._into:
            self.elastic.force_and_tangent_into(self._q1, self._f, self._K)
        else:
            f, K = self.elastic.force_and_tangent(self._q1)
            self._f[:] = f
            self._K[:] = K
        middle = clock()
        active = False
        contact = self.contact
        if contact is not None:
            active = contact.evaluate_into(self._c1, self._R1, self._q1, True) > 0
        after = clock()
        frame_arrays = self._frame_arrays
        out = self._rigid_out
        norm = _deformation_residual(
            self._q1, self._dqt, self.qd, self.qa, self.dt, self._scheme_code, self.k_ex,
            out[1], out[2], frame_arrays[1], frame_arrays[2], frame_arrays[3], frame_arrays[4],
            frame_arrays[5], frame_arrays[6], active,
            contact.generalized if contact is not None else self._gen,
            contact.stiffness_q if contact is not None else self._K,
            self._damping1, self._b, self._f, self._K, self._v1, self._a1, self._res,
            self._norms, self._f_elastic)
        finished = clock()
        times[0] += (middle - started) + (finished - after)
        times[1] += after - middle
        if not math.isfinite(norm):
            raise SolverError(f"non-finite deformation residual at step {index} "
                              f"(t = {t1:.6g} s)")
        return norm

    def _kick(self, index: int, t1: float, active: bool, *, sweep: bool,
              times: np.ndarray) -> None:
        """The rigid update (:func:`_rigid_update`) to (c₁, p₁, R₁, L₁) and the deformation
        damping D + Γ(ω₁); a ``sweep`` uses the contact at the end of the previous sweep."""
        started = self._clock()
        frame, arrays = self.frame, self._frame_arrays
        contact = self.contact
        cforce = self._contact0_force if contact is not None else self._force
        ctorque = self._contact0_torque if contact is not None else self._torque
        K6 = self._K6 if contact is not None else self._contact_zero6
        state = _rigid_update(
            self.dt, frame.mass, self.q, self.qd, self.qa, self._c, self._p, self._R, self._L,
            self._force, self._torque, active or sweep, cforce, ctorque, K6, sweep,
            self._contact1, self._nu1, arrays[0], arrays[1], arrays[2], arrays[3], arrays[4],
            self._c1, self._p1, self._R1, self._L1, self._rigid_out, self._work33, self._work6,
            self._work66, self._q1, self._v1)
        if state == 1:
            raise rotation_error(self.dt, self._rigid_out[3], index, t1)
        if state == 2:
            raise SolverError(f"singular inertia at step {index} (t = {t1:.6g} s)")
        coriolis_into(self._rigid_out[1], arrays[3], self.damping, self._damping1)
        rigid_done = self._clock()
        self._load_q(self._R1, t1, self._b)
        times[2] += rigid_done - started
        times[3] += self._clock() - rigid_done

    def _solve_deformation(self, index: int, t1: float, times: np.ndarray) -> int:
        """Newton on the deformation at the kicked pose (contact implicit in q₁); returns
        the iterations. ``times`` accumulates [internal force, contact, -, -, solve] s."""
        started = self._clock()
        before = times[0] + times[1]
        dt = self.dt
        ca, cv = _SCHEMES[self.scheme]
        _newton_base(self._damping1, ca / dt**2, cv / dt, self._base)
        _predict(self.q, self.qd, self.qa, dt, self._dqt, self._predictor)
        np.add(self.q, self._dqt, out=self._q1)
        b_norm, qa_norm, qd_norm = _norm(self._b), _norm(self.qa), _norm(self.qd)
        scale = max(b_norm, qa_norm)
        norm = self._evaluate(index, t1, times)
        self._dq, self._dqt = self._dqt, self._dq
        scale = max(scale, norm, self._norms[0], self._norms[1])
        eps64 = 64 * np.finfo(float).eps
        iteration = 0
        while True:
            noise = eps64 * (ca / dt**2 * _norm(self._dq) + self._norms[0] + b_norm
                             + ca / dt * qd_norm + qa_norm)
            if norm <= self.rtol * scale or norm <= noise:
                break
            if iteration == self.max_iterations:
                raise SolverError(
                    f"Newton did not converge at step {index} (t = {t1:.6g} s): relative "
                    f"residual {norm / scale:.3e} after {iteration} iterations")
            if not _lu_solve(self._base, self._K, self._res, self._J, self._delta):
                raise SolverError(f"singular Newton matrix at step {index} "
                                  f"(t = {t1:.6g} s)")
            # backtracking: contact makes the residual only piecewise smooth; the last
            # trial is the accepted one
            fraction = 1.0
            while True:
                _trial(self.q, self._dq, self._delta, fraction, self._dqt, self._q1)
                trial = self._evaluate(index, t1, times)
                if trial < norm or fraction <= 1.0 / 64:
                    break
                fraction *= 0.5
            self._dq, self._dqt = self._dqt, self._dq
            norm = trial
            iteration += 1
        times[4] += self._clock() - started - (times[0] + times[1] - before)
        return iteration

    def _sweep_again(self, sweeps: int) -> bool:
        """Whether the step needs another contact sweep: the contact acts at the end of the
        step, its frequency is resolved (θ = ½), and the end momenta (p₁, L₁ / radius) moved
        since the last sweep by more than :data:`SWEEP_RTOL` of the size of the momenta and
        the step's impulse (Δp, ΔL / radius) together (stops after
        :data:`MAX_CONTACT_SWEEPS`). Stores the contact and ν₁ the next sweep uses."""
        contact = self.contact
        if contact is None or contact.scalars[1] == 0 or self._rigid_out[7, 0] != 0.5:
            return False
        momentum, radius = self._momentum1, contact.radius0
        dp, dL = self._rigid_out[4], self._rigid_out[5]
        change = 0.0
        size = 0.0
        for a in range(3):
            change += (self._p1[a] - momentum[a]) ** 2 + ((self._L1[a] / radius
                                                           - momentum[3 + a]) ** 2)
            size += (self._p1[a] ** 2 + (self._L1[a] / radius) ** 2 + dp[a] ** 2
                     + (dL[a] / radius) ** 2)
            momentum[a], momentum[3 + a] = self._p1[a], self._L1[a] / radius
        if sweeps > 1 and change <= (SWEEP_RTOL**2) * size:
            return False
        if sweeps >= MAX_CONTACT_SWEEPS:
            return False
        self._contact1[:3] = contact.force
        self._contact1[3:] = contact.torque
        if sweeps == 1 and not np.any(self._K6):  # the contact began within the step
            self._K6[:] = contact.stiffness_rigid
        omega_body, R1, nu1 = self._rigid_out[1], self._R1, self._nu1
        for a in range(3):
            nu1[a] = self._p1[a] / self.frame.mass
            nu1[3 + a] = (R1[a, 0] * omega_body[0] + R1[a, 1] * omega_body[1]
                          + R1[a, 2] * omega_body[2])
        return True

    # ------------------------------------------------------------------ step
    def step(self, index: int | None = None) -> int:
        """Advance one step; return the Newton iterations. The wall time of its parts
        (:data:`PHASES`, s) is left in ``_marks`` for :meth:`run`.

        Raises:
            SolverError: see the module docstring; the state is left unchanged.
        """
        clock, marks = self._clock, self._marks
        marks[0] = clock()
        index = self.steps_taken + 1 if index is None else index
        frame, t1 = self.frame, self.time + self.dt
        if self._in_place:
            self.driver.weights_into(self.q)
            marks[1] = clock()
            self.driver.target_from_weights_into(self.q_target)
        elif self.driver is not None:  # a driver without the in-place methods
            marks[1] = marks[0]
            self.q_target[:] = self.driver.target(self.q).q_target
        else:
            marks[1] = marks[0]
        marks[2] = clock()

        # --- rigid update (loads and contact at t₀, impulse, rotation), then the
        # deformation solve (contact implicit at the new pose); in contact, sweeps
        self._loads.evaluate_into(self._R, self.q, self.time, self._force, self._torque,
                                  self._gen)
        rigid_started = clock()
        contact = self.contact
        active = False
        if contact is not None:
            if not self._contact_fresh():
                contact.evaluate_into(self._c, self._R, self.q, True)
            active = contact.scalars[1] > 0
            self._contact0_force[:] = contact.force
            self._contact0_torque[:] = contact.torque
            self._K6[:] = contact.stiffness_rigid
        contact_t0 = clock() - rigid_started
        times = self._seconds
        times[:] = 0.0  # [internal force, contact, rigid, generalized load, solve] seconds
        iterations = sweeps = 0
        while True:
            self._kick(index, t1, active, sweep=sweeps > 0, times=times)
            iterations += self._solve_deformation(index, t1, times)
            sweeps += 1
            if not self._sweep_again(sweeps):
                break
        self.sweeps = sweeps
        self.total_sweeps += sweeps
        depth = float(contact.scalars[2]) if contact is not None else 0.0
        self._depth = depth
        if contact is not None and depth > contact.radius0:
            raise SolverError(f"contact failed at step {index} (t = {t1:.6g} s): a vertex is "
                              f"{depth:.3g} m behind a plane (the body's radius is "
                              f"{contact.radius0:.3g} m); lower dt or raise the stiffness")

        # --- commit and monitor
        arrays = self._frame_arrays
        energies = self._energies
        contact_energy = float(contact.scalars[0]) if contact is not None else 0.0
        finite = _commit_energy(frame.mass, self._p1, self._R1, self._L1, self._q1, self._v1,
                                self._c1, self.k_ex, contact_energy, self._rigid_out, self.q,
                                self._b, self._f_elastic0, self._f_elastic, arrays[0],
                                arrays[1], arrays[2], arrays[3], arrays[4], self._work33,
                                energies)
        work = self.work + energies[1]
        budget = abs(self.energy0) + work
        if not finite:
            raise SolverError(f"non-finite state at step {index} (t = {t1:.6g} s)")
        if self.deformation_bound is not None:
            self.deformation_bound.check(self._q1, index, t1)
        elastic = max(self._elastic_energy + energies[2], 0.0)
        energy = energies[0] + elastic
        limit = ENERGY_FACTOR * budget
        if not math.isfinite(energy) or (budget > 0 and energy > EXACT_ENERGY_FRACTION * limit):
            elastic = float(self.elastic.energy(self._q1))
            energy = energies[0] + elastic
            if not math.isfinite(energy) or (budget > 0 and energy > limit):
                raise SolverError(f"energy blew up ({energy:.3e} J > {ENERGY_FACTOR:g} x "
                                  f"budget {budget:.3e} J) at step {index} (t = {t1:.6g} s)")
        self._elastic_energy = elastic
        self._f_elastic0, self._f_elastic = self._f_elastic, self._f_elastic0
        self.work = work
        self._swap()
        if contact is not None:
            self._contact_calls = contact.evaluated + contact.skipped
        self.time, self.steps_taken = t1, index
        finished = clock()
        marks[3] = marks[2] + times[3]  # example force (generalized load)
        marks[4] = marks[3] + times[2]  # rigid update
        marks[5] = marks[4] + contact_t0 + times[1]
        marks[6] = marks[5] + times[0]
        marks[7] = marks[6] + times[4]
        marks[8] = finished
        return iterations

    def _swap(self) -> None:
        self.q, self._q1 = self._q1, self.q
        self.qd, self._v1 = self._v1, self.qd
        self.qa, self._a1 = self._a1, self.qa
        self._c, self._c1 = self._c1, self._c
        self._p, self._p1 = self._p1, self._p
        self._R, self._R1 = self._R1, self._R
        self._L, self._L1 = self._L1, self._L

    # ------------------------------------------------------------------- run
    def run(self, steps: int, *, stride: int = 1,
            on_step: Callable[[int, float, np.ndarray], None] | None = None
            ) -> FreeBodyRecord:
        """Advance ``steps`` steps keeping every ``stride``-th state (and the initial one);
        a failure ends the run with ``stable=False`` and the message. ``on_step`` is
        called after each step (outside its timing) with (step index from 0, time in s,
        q (r,))."""
        stride = int(stride)
        if int(steps) < 1 or stride < 1:
            raise LbshapeError(f"steps and stride must be >= 1, got {steps} and {stride}")
        steps = int(steps)
        sampled = {key: [] for key in ("times", "states", "centers", "rotations", "momenta",
                                       "angular_momenta", "energies")}
        phases = np.zeros((steps, len(PHASES)))
        interp, total = np.zeros(steps), np.zeros(steps)
        iterations, depth = np.zeros(steps, dtype=np.int64), np.zeros(steps)
        self.phase_seconds = phases[:0]

        def sample() -> None:
            for key, value in (("times", self.time), ("states", self.q), ("centers", self._c),
                               ("rotations", self._R), ("momenta", self._p),
                               ("angular_momenta", self._L), ("energies", self.energy())):
                sampled[key].append(np.array(value, dtype=float))

        sample()
        stable, message, done = True, "", 0
        marks = self._marks
        for index in range(steps):
            try:
                iterations[index] = self.step()
            except SolverError as exc:
                stable, message = False, str(exc)
                log.error("free-body simulation stopped: %s", exc)
                break
            np.subtract(marks[1:], marks[:-1], out=phases[index])
            interp[index] = marks[2] - marks[0]
            total[index] = marks[-1] - marks[0]
            depth[index] = self._depth
            done = index + 1
            self.phase_seconds = phases[:done]
            if done % stride == 0:
                sample()
            if on_step is not None:
                on_step(index, self.time, self.q)
        arrays = {key: np.asarray(value) for key, value in sampled.items()}
        return FreeBodyRecord(
            times=arrays["times"], states=arrays["states"], t_interp_ms=1e3 * interp[:done],
            t_total_ms=1e3 * total[:done], newton_iterations=iterations[:done],
            stable=stable, message=message, centers=arrays["centers"],
            rotations=arrays["rotations"], momenta=arrays["momenta"],
            angular_momenta=arrays["angular_momenta"], energies=arrays["energies"],
            contact_depth=depth[:done], rest_points=self.rest_points,
            body_points=(None if self.rest_points is None
                         else self.rest_points - self.frame.center),
        )


def contact_theta(mass6: np.ndarray, stiffness6: np.ndarray, dt: float) -> float:
    """θ of the rigid contact kick: ½ (trapezoidal, conservative) while the stiffest
    contact frequency is resolved (ω_c Δt ≤ ½), 1 (backward Euler, L-stable, damps the
    unresolved contact oscillation) from ω_c Δt ≥ 3/2, linear in between.

    ω_c² is the largest eigenvalue of ``K₆ v = ω² M₆ v`` (6 × 6, M₆ positive definite).
    """
    work = np.zeros((2, 6, 6))
    return float(_contact_theta(np.asarray(mass6, dtype=float),
                                np.asarray(stiffness6, dtype=float), float(dt), work[0], work[1]))


def _norm(vector: np.ndarray) -> float:
    return math.sqrt(float(vector @ vector))


# ------------------------------------------------------------------ compiled kernels
@njit
def loads_into(rotation, q, scales, forces, P, Z0, Z1, force, torque, generalized, work):
    """Σ_l scale_l · (force (3,) world, torque about c (3,) world, generalized (r,)) of the
    stacked loads (:class:`FreeLoad` fields with a leading load axis) at (R, q).

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


@njit
def _max_symmetric_eigenvalue(A):
    """Largest eigenvalue of the symmetric matrix A (n, n) by cyclic Jacobi (A destroyed)."""
    n = A.shape[0]
    for _ in range(50):
        off = 0.0
        total = 0.0
        for i in range(n):
            for j in range(n):
                total += A[i, j] * A[i, j]
                if i != j:
                    off += A[i, j] * A[i, j]
        if off <= 1e-30 * total:
            break
        for p in range(n - 1):
            for q in range(p + 1, n):
                apq = A[p, q]
                if apq == 0.0:
                    continue
                tau = (A[q, q] - A[p, p]) / (2.0 * apq)
                t = (1.0 if tau >= 0.0 else -1.0) / (abs(tau) + np.sqrt(1.0 + tau * tau))
                c = 1.0 / np.sqrt(1.0 + t * t)
                s = t * c
                for k in range(n):  # columns p, q
                    akp, akq = A[k, p], A[k, q]
                    A[k, p] = c * akp - s * akq
                    A[k, q] = s * akp + c * akq
                for k in range(n):  # rows p, q
                    apk, aqk = A[p, k], A[q, k]
                    A[p, k] = c * apk - s * aqk
                    A[q, k] = s * apk + c * aqk
    largest = A[0, 0]
    for i in range(1, n):
        largest = max(largest, A[i, i])
    return largest


@njit
def _contact_theta(M6, K6, dt, L, A):
    """:func:`contact_theta` with work arrays L, A (6, 6): ω_c² = λ_max(L⁻¹ K₆ L⁻ᵀ),
    ``M₆ = L Lᵀ``."""
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
    omega2 = _max_symmetric_eigenvalue(A)
    resolved = np.sqrt(max(omega2, 0.0)) * dt
    return 0.5 + 0.5 * min(max(resolved - 0.5, 0.0), 1.0)


@njit
def _rigid_update(dt, mass, q, qd, qa, c0, p0, R0, L0, force, torque, active, cforce, ctorque,
                  K6, sweep, end6, nu_end, Y0, G9, C9, S3, H, c1, p1, R1, L1, out, w33, w6, w66,
                  q_mid, qd_mid):
    """Step 2 of the module docstring. ``out`` rows: ω₀, ω₁, ω̇ (body), ω_mid, Δp, ΔL, v₀,
    [θ, 0, 0]. With ``sweep`` (a contact sweep of :meth:`FreeBodySimulation.step`) the
    kick is ``(M₆ + θ² Δt² K₆) Δν = Δt F_loads + ½ Δt (C₀ + C₁) + θ² Δt² K₆ (ν₁ − ν₀)``
    with the contact (force, torque) C₀ = (cforce, ctorque) at t₀, C₁ = ``end6`` (6,) and
    ν₁ = ``nu_end`` (6,) at the end of the previous sweep: its fixed point is the
    trapezoidal rule ``M₆ Δν = Δt F_loads + ½ Δt (C₀ + C₁)``. ``q_mid``, ``qd_mid`` (r,)
    are scratch. Returns 0, 1 (rotation did not converge) or 2 (singular inertia or rigid
    system)."""
    inertia, inverse, world = w33[0], w33[1], w33[2]
    h, tmp = w6[0, :3], w6[0, 3:]
    inertia_momentum_into(q, qd, Y0, G9, C9, S3, H, inertia, h)
    if not inverse3_into(inertia, inverse):
        return 2
    for a in range(3):
        tmp[a] = R0[0, a] * L0[0] + R0[1, a] * L0[1] + R0[2, a] * L0[2] - h[a]
    omega0, dp, dL, v0 = out[0], out[4], out[5], out[6]
    for a in range(3):
        omega0[a] = inverse[a, 0] * tmp[0] + inverse[a, 1] * tmp[1] + inverse[a, 2] * tmp[2]
        v0[a] = p0[a] / mass
    F6, nu0 = w6[1], w6[2]
    for a in range(3):
        F6[a] = force[a] + (cforce[a] if active else 0.0)
        F6[3 + a] = torque[a] + (ctorque[a] if active else 0.0)
    out[7, 0] = 0.5
    if not active:
        for a in range(3):
            dp[a] = dt * F6[a]
            dL[a] = dt * F6[3 + a]
    else:
        M6, A = w66[0], w66[1]
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
            nu0[a] = v0[a]
            nu0[3 + a] = R0[a, 0] * omega0[0] + R0[a, 1] * omega0[1] + R0[a, 2] * omega0[2]
        theta = _contact_theta(M6, K6, dt, w66[2], w66[3])
        out[7, 0] = theta
        rhs = w6[3]
        k = theta * theta * dt * dt
        for i in range(6):
            value = 0.0
            for j in range(6):
                if sweep:
                    value += K6[i, j] * (nu_end[j] - nu0[j])
                else:
                    value += K6[i, j] * nu0[j]
                A[i, j] = M6[i, j] + k * K6[i, j]
            if sweep:
                contact0 = cforce[i] if i < 3 else ctorque[i - 3]
                rhs[i] = dt * F6[i] + 0.5 * dt * (end6[i] - contact0) + k * value
            else:
                rhs[i] = dt * F6[i] - theta * dt * dt * value
        if not cholesky_in_place(A):
            return 2
        cholesky_solve_in_place(A, rhs)
        for i in range(3):  # impulse M₆ Δν
            dp[i] = mass * rhs[i]
            dL[i] = world[i, 0] * rhs[3] + world[i, 1] * rhs[4] + world[i, 2] * rhs[5]
    for a in range(3):
        p1[a] = p0[a] + dp[a]
        c1[a] = c0[a] + 0.5 * dt * (p0[a] + p1[a]) / mass
        L1[a] = L0[a] + dL[a]
    # inertia and relative momentum at the predicted mid-step deformation
    for j in range(q.shape[0]):
        q_mid[j] = q[j] + 0.5 * dt * qd[j] + 0.125 * dt * dt * qa[j]
        qd_mid[j] = qd[j] + 0.5 * dt * qa[j]
    inertia_momentum_into(q_mid, qd_mid, Y0, G9, C9, S3, H, inertia, h)
    body = w6[1, :3]  # Π = R₀ᵀ L₁
    for a in range(3):
        body[a] = R0[0, a] * L1[0] + R0[1, a] * L1[1] + R0[2, a] * L1[2]
    body1 = w6[1, 3:]
    if not rotate_into(R0, body, inertia, h, dt, R1, body1, out[3], w33[3:5]):
        return 1
    if not inverse3_into(inertia, inverse):
        return 2
    omega1, omega_dot = out[1], out[2]
    for a in range(3):
        omega1[a] = (inverse[a, 0] * (body1[0] - h[0]) + inverse[a, 1] * (body1[1] - h[1])
                     + inverse[a, 2] * (body1[2] - h[2]))
        before = (inverse[a, 0] * (body[0] - h[0]) + inverse[a, 1] * (body[1] - h[1])
                  + inverse[a, 2] * (body[2] - h[2]))
        omega_dot[a] = (omega1[a] - before) / dt
    return 0


@njit
def _deformation_residual(q1, dq, qd, qa, dt, scheme, k_ex, omega1, omega_dot, G9, C9, S3, H,
                          G_trace, C_trace, active, cgen, cKq, damping1, b, f, K, v1, a1, res,
                          norms, f_elastic):
    """Complete f, K (the elastic force and tangent on entry) with the example spring, the
    Euler and centrifugal forces and the contact; kinematics v₁, a₁ of Δq (Newmark or
    backward Euler); residual ``a₁ + (D + Γ) v₁ + f − b`` into ``res``; returns its norm.
    norms ← [‖f‖, max(‖f_elastic‖, ‖f_contact‖)]; the elastic force is copied to
    ``f_elastic``."""
    r = q1.shape[0]
    elastic2 = 0.0
    for j in range(r):
        elastic2 += f[j] * f[j]
        f_elastic[j] = f[j]
    if k_ex != 0.0:
        for j in range(r):
            f[j] += k_ex * q1[j]
            K[j, j] += k_ex
    fictitious_into(q1, omega1, omega_dot, G9, C9, S3, H, G_trace, C_trace, f, K)
    contact2 = 0.0
    if active:
        for j in range(r):
            f[j] -= cgen[j]
            contact2 += cgen[j] * cgen[j]
            for k in range(r):
                K[j, k] += cKq[j, k]
    total2 = 0.0
    for j in range(r):
        total2 += f[j] * f[j]
    norms[0] = np.sqrt(total2)
    norms[1] = np.sqrt(max(elastic2, contact2))
    for j in range(r):
        if scheme == 0:
            v1[j] = 2.0 / dt * dq[j] - qd[j]
            a1[j] = 4.0 / (dt * dt) * (dq[j] - dt * qd[j]) - qa[j]
        else:
            v1[j] = dq[j] / dt
            a1[j] = (v1[j] - qd[j]) / dt
    norm2 = 0.0
    for j in range(r):
        value = a1[j] + f[j] - b[j]
        for k in range(r):
            value += damping1[j, k] * v1[k]
        res[j] = value
        norm2 += value * value
    return np.sqrt(norm2)


@njit
def _newton_base(damping1, ca_dt2, cv_dt, base):
    """base = c_a/Δt² I + c_v/Δt (D + Γ)."""
    r = base.shape[0]
    for j in range(r):
        for k in range(r):
            base[j, k] = cv_dt * damping1[j, k]
        base[j, j] += ca_dt2


@njit
def _trial(q, dq, delta, fraction, dq_trial, q1):
    """Δq_trial = Δq − fraction δ, q₁ = q + Δq_trial."""
    for j in range(q.shape[0]):
        dq_trial[j] = dq[j] - fraction * delta[j]
        q1[j] = q[j] + dq_trial[j]


@njit
def _lu_solve(base, K, rhs, J, x):
    """x = (base + K)⁻¹ rhs by LU with partial pivoting in J; False if singular."""
    n = rhs.shape[0]
    for i in range(n):
        x[i] = rhs[i]
        for j in range(n):
            J[i, j] = base[i, j] + K[i, j]
    for k in range(n):
        pivot, big = k, abs(J[k, k])
        for i in range(k + 1, n):
            if abs(J[i, k]) > big:
                pivot, big = i, abs(J[i, k])
        if not (big > 0.0 and np.isfinite(big)):
            return False
        if pivot != k:
            for j in range(n):
                J[k, j], J[pivot, j] = J[pivot, j], J[k, j]
            x[k], x[pivot] = x[pivot], x[k]
        for i in range(k + 1, n):
            factor = J[i, k] / J[k, k]
            J[i, k] = factor
            for j in range(k + 1, n):
                J[i, j] -= factor * J[k, j]
            x[i] -= factor * x[k]
    for i in range(n - 1, -1, -1):
        value = x[i]
        for j in range(i + 1, n):
            value -= J[i, j] * x[j]
        x[i] = value / J[i, i]
    return True


@njit
def _commit_energy(mass, p1, R1, L1, q1, v1, c1, k_ex, contact_energy, out, q0, b, f0, f1,
                   Y0, G9, C9, S3, H, w33, energies):
    """Energies of the new state: energies ← [kinetic + example spring + contact (J),
    work of the step (J), trapezoidal work of the elastic force ½ (f₀ + f₁)·(q₁ − q₀) (J)];
    False if the state or the first energy is not finite."""
    finite = True
    for a in range(3):
        finite = finite and np.isfinite(p1[a]) and np.isfinite(L1[a]) and np.isfinite(c1[a])
        for b_ in range(3):
            finite = finite and np.isfinite(R1[a, b_])
    for j in range(q1.shape[0]):
        finite = finite and np.isfinite(q1[j]) and np.isfinite(v1[j])
    if not finite:
        return False
    inertia, inverse, tmp = w33[5], w33[6], w33[7]
    h = tmp[0]
    inertia_momentum_into(q1, v1, Y0, G9, C9, S3, H, inertia, h)
    if not inverse3_into(inertia, inverse):
        return False
    body, omega = tmp[1], tmp[2]
    for a in range(3):
        body[a] = R1[0, a] * L1[0] + R1[1, a] * L1[1] + R1[2, a] * L1[2] - h[a]
    for a in range(3):
        omega[a] = inverse[a, 0] * body[0] + inverse[a, 1] * body[1] + inverse[a, 2] * body[2]
    kinetic = 0.0
    for a in range(3):
        kinetic += 0.5 * p1[a] * p1[a] / mass + omega[a] * h[a]
        for b_ in range(3):
            kinetic += 0.5 * omega[a] * inertia[a, b_] * omega[b_]
    spring = 0.0
    for j in range(q1.shape[0]):
        kinetic += 0.5 * v1[j] * v1[j]
        spring += 0.5 * k_ex * q1[j] * q1[j]
    dp, dL, v0, omega_mid = out[4], out[5], out[6], out[3]
    rigid_work = 0.0
    turn_work = 0.0
    for a in range(3):
        rigid_work += dp[a] * (v0[a] + p1[a] / mass)
        turn_work += dL[a] * (R1[a, 0] * omega_mid[0] + R1[a, 1] * omega_mid[1]
                              + R1[a, 2] * omega_mid[2])
    load_work = 0.0
    elastic_work = 0.0
    for j in range(q1.shape[0]):
        load_work += b[j] * (q1[j] - q0[j])
        elastic_work += 0.5 * (f0[j] + f1[j]) * (q1[j] - q0[j])
    energies[0] = kinetic + spring + contact_energy
    energies[1] = 0.5 * abs(rigid_work) + abs(turn_work) + abs(load_work)
    energies[2] = elastic_work
    return np.isfinite(energies[0])
