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
   by ``M₆ Δν``; then ``c₁ = c₀ + Δt (v₀ + v₁)/2`` (exact for a ballistic throw) and,
   split about the impulse (half of ΔL either side), the torque-free Cayley–midpoint
   rotation (:func:`~lbshape.dynamics.rigid_frame.rotate`) with ``R₀ᵀ (L₀ + L₁)/2``
   and I, h at the predicted mid-step deformation: second order under a torque;
3. **contact**: the planes' penalty forces on the deformation, implicit in q at (c₁, R₁);
4. **deformation solve**: Newmark (β = ¼, γ = ½) or backward Euler on
   ``q̈ + (D + Γ(ω)) q̇ + f_int(q) + k_ex q + F_euler(q) + F_centrifugal(q) − F_contact(q)
   = Uᵀ R₁ᵀ f_ext(t₁) + k_ex q*``, D = αI + βK₀ (deformation only: rigid motion is
   never damped), ω = ``I⁻¹ (R₁ᵀ L₁ − h)`` and ω̇ the difference quotient of
   ``I⁻¹ (Rᵀ L − h)`` over the step, Newton on a dense r × r system;
5. **contact sweeps**: while a plane touches the body at the end of the step (and its
   contact frequency is resolved, θ = ½), steps 2–4 are repeated with the kick
   ``(M₆ + θ² Δt² K₆) Δν = Δt F_loads + ½ Δt (C₀ + C₁) + θ² Δt² K₆ (ν₁ − ν₀)``, C₁ and
   ν₁ the contact (force, torque) and the velocity at the end of the previous sweep
   (its Newton from the previous sweep's Δq), until the end momenta settle
   (:data:`SWEEP_RTOL`, or a second sweep's error estimated from a recent contraction,
   :data:`SWEEP_ERROR_SHARE`; at most :data:`MAX_CONTACT_SWEEPS` passes): the fixed
   point is the trapezoidal contact impulse ``M₆ Δν = Δt F_loads + ½ Δt (C₀ + C₁)`` of
   the rigid motion and the deformation together (why: ``docs/decisions.md``, free
   bodies).

**Passes**: a step of Δt is one or more passes of steps 1–5, each committed: in flight
as many as resolve the deformation's highest frequency (the example spring's included),
while a plane touches the body :attr:`~FreeBodySimulation.contact_substeps` of ``Δt / k``
≤ ``contact_dt`` (the example target interpolated again in each), a flight pass that
touches a plane taken again so: :mod:`lbshape.dynamics.free_body_passes`.

**Friction** (a plane's μ > 0): see :mod:`lbshape.dynamics.free_body_contact`, where the
contact's part of the step lives.

Without loads and contact p and L are conserved to round-off (they change only by
impulses) and R stays on SO(3) (Cayley map). Failures — Newton, a non-finite state,
energy above :data:`~lbshape.dynamics.sanity.ENERGY_FACTOR` × the initial energy plus the
work of loads and contact, an inverted cubature element (Neo-Hookean), a rotation step too
large for the spin, a vertex pushed through a plane by more than the body's radius — raise
:class:`~lbshape.errors.SolverError` naming the step; :meth:`FreeBodySimulation.run`
turns it into ``stable = False`` with the message. The energy monitor tracks the
elastic energy by the trapezoidal work of the elastic force, ``E(q₁) ≈ E(q₀) +
½ (f(q₀) + f(q₁))·(q₁ − q₀)`` (reset to the exact energy whenever that is computed),
and computes the exact elastic energy when the estimated total reaches
:data:`EXACT_ENERGY_FRACTION` of the limit, so the exact criterion decides every
failure while a normal step stays free of the allocating energy evaluation.

**The step path** is compiled and allocation-free, as in :mod:`lbshape.dynamics.reduced`:
state and work arrays live in a few named structures
(:mod:`lbshape.dynamics.free_body_kernels`; the state at t₀ and the state being computed,
:class:`~lbshape.dynamics.free_body_kernels.BodyState`, swap when a step is accepted), the
weights and target are written in place, the elastic force and tangent come from
:meth:`~lbshape.elastic.reduced_forces.ReducedForceModel.force_and_tangent_into`, and
numba kernels do the rest: loads (:func:`~lbshape.dynamics.free_body_kernels.loads_into`),
rigid update (:func:`~lbshape.dynamics.free_body_kernels.rigid_update`), frame tensors and
fictitious forces (:mod:`lbshape.dynamics.fictitious`), contact
(:meth:`~lbshape.dynamics.contact.PlaneContact.evaluate_into`, once per Newton evaluation;
at a step's start the previous step's last evaluation, same configuration, is reused),
the residual (:func:`~lbshape.dynamics.free_body_kernels.deformation_residual`) and the
LU solve (:class:`~lbshape.dynamics.dense_lu.DenseLU`; the Euler and Coriolis terms are
skew). Each step's wall time is split into :data:`PHASES`
(:attr:`FreeBodySimulation.phase_seconds`).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Sequence

import numpy as np

from lbshape.dynamics import sanity
from lbshape.dynamics.contact import PlaneContact
from lbshape.dynamics.dense_lu import DenseLU
from lbshape.dynamics.drag import DragSpring
from lbshape.dynamics.engine import (
    EngineState,
    NewtonSettings,
    OnStep,
    check_run,
    collector_paused,
    forget_warm_starts,
    restore_arrays,
    snapshot,
)
from lbshape.dynamics.fictitious import FrameTensors
from lbshape.dynamics.free_body_contact import FreeBodyContact
from lbshape.dynamics.free_body_drag import FreeBodyDrag
from lbshape.dynamics.free_body_kernels import (
    KICK_ROTATION_FAILED,
    KICK_SINGULAR,
    BodyState,
    DeformationSolve,
    RigidKick,
    Scratch,
    commit_energy,
    deformation_residual,
    end_rates_into,
    newton_base,
    rigid_update,
    trial,
)
from lbshape.dynamics.free_body_loads import FreeLoad, LoadStack
from lbshape.dynamics.free_body_passes import FreeBodyPasses
from lbshape.dynamics.free_body_record import FreeBodyRecord, FreeBodyRecorder, world_displacements
from lbshape.dynamics.kernels import axpy, predict
from lbshape.dynamics.kernels import norm as _norm
from lbshape.dynamics.reduced import PHASES as FIXED_PHASES
from lbshape.dynamics.reduced import REALTIME_NEWTON
from lbshape.dynamics.rigid_frame import RigidState, rotation_error
from lbshape.dynamics.schemes import Scheme, get_scheme
from lbshape.errors import LbshapeError, SolverError
from lbshape.shapespace.example_driver import ExampleDriver

log = logging.getLogger(__name__)

#: the monitor computes the exact elastic energy from this fraction of the limit on
EXACT_ENERGY_FRACTION = 0.5
#: 64 ε: the round-off level of the residual, relative to its terms
_EPS64 = 64 * np.finfo(float).eps
#: the parts of a free-body step timed in :attr:`FreeBodySimulation.phase_seconds`: the
#: fixed-object phases (:data:`lbshape.dynamics.reduced.PHASES`, same meaning: the
#: example force is the step's generalized load ``k_ex q* + Uᵀ Rᵀ f_ext``, the internal
#: force and tangent include the fictitious forces) plus the rigid update and the contact
PHASES: tuple[str, ...] = ("weights", "target", "example_force", "rigid", "contact",
                           "internal_force_tangent", "solve", "overhead")
assert set(FIXED_PHASES) <= set(PHASES)


class FreeBodySimulation(FreeBodyPasses, FreeBodyContact, FreeBodyDrag):
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
        newton: the :class:`~lbshape.dynamics.engine.NewtonSettings` (default the fixed
            objects' real-time :data:`~lbshape.dynamics.reduced.REALTIME_NEWTON`).
        rest_points: (n, 3) rest positions X (m), for the world displacements of the
            record, :meth:`displacement` and :meth:`set_drag` (optional).
        basis: (3n, r) the basis U, for :meth:`displacement` and :meth:`set_drag`
            (optional).
        reuse_contact: reuse the previous step's last contact evaluation at the start
            of a step (same configuration; ``False`` evaluates it again, for checks).
        omega_max, load_reach: the basis's highest vibration frequency (rad/s) and the
            loads' reach for the coarse-step warning and the stop message, as
            :class:`~lbshape.dynamics.reduced.ReducedSimulation`'s; or ``None``.
        contact_dt: the longest step in s while a plane touches the body: a step of dt is
            ``ceil(dt / contact_dt)`` sub-steps (``None``: ``CONTACT_DT``, 1/3 ms).
        flight_dt: the longest pass in s while no plane touches the body (``None``: the
            pass that resolves the deformation's highest frequency,
            :func:`~lbshape.dynamics.free_body_passes.resolved_pass`).

    Attributes:
        q, qd, qa: (r,) deformation, its rate and acceleration at :attr:`time`.
        drag: a user's :class:`~lbshape.dynamics.drag.DragSpring` (:meth:`set_drag`) or
            ``None``: a world point force, one more load evaluated at each step's start.
        damping: (r, r) the deformation's Rayleigh damping ``α I + β K₀``.
        phase_seconds: (steps, len(PHASES)) wall time of each part of each step of the
            last :meth:`run` (s).
    """

    phases: tuple[str, ...] = PHASES  #: the parts of a step timed in ``phase_seconds``

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
        newton: NewtonSettings = REALTIME_NEWTON,
        rest_points: np.ndarray | None = None,
        reuse_contact: bool = True,
        omega_max: float | None = None, load_reach=None,
        basis: np.ndarray | None = None,
        contact_dt: float | None = None,
        flight_dt: float | None = None,
    ):
        self.rest_points = None if rest_points is None else np.asarray(rest_points, dtype=float)
        scheme = get_scheme(integrator)
        if not (np.isfinite(dt) and dt > 0):
            raise LbshapeError(f"time step dt must be > 0 s, got {dt}")
        r = frame.r
        self.elastic, self.frame, self.r = elastic, frame, r
        self.dt, self.scheme = float(dt), integrator
        self._set_passes(contact_dt, flight_dt)
        self.loads = list(loads)
        self._loads = LoadStack(self.loads, r)
        self.drag: DragSpring | None = None
        self._drag_stiffness = 0.0  # the stiffness asked for (the spring's may be capped)
        self.driver = driver if (driver is not None and k_ex > 0.0) else None
        self.k_ex = float(k_ex) if self.driver is not None else 0.0
        self._in_place = self.driver is not None and hasattr(self.driver, "weights_into") \
            and hasattr(self.driver, "target_from_weights_into")
        self.contact, self.reuse_contact = contact, bool(reuse_contact)
        self.omega_max, self.load_reach = omega_max, load_reach
        self._inversion = sanity.checks_inversion(elastic)  # det F <= 0 stops the run
        self.warnings = sanity.step_warnings(omega_max, self.dt / self.flight_passes, log)
        self.newton = newton
        self.basis = None if basis is None else np.asarray(basis, dtype=float)
        self._examples = (self.driver, self.k_ex)  # the configured example force
        self._into = hasattr(elastic, "force_and_tangent_into")
        self.q_target = np.zeros(r)
        q = np.zeros(r) if q0 is None else np.array(q0, dtype=float)
        qd = np.zeros(r) if qd0 is None else np.array(qd0, dtype=float)
        if q.shape != (r,) or qd.shape != (r,):
            raise LbshapeError(f"q0 and qd0 must have shape ({r},)")
        omega_world = np.asarray(angular_velocity, dtype=float)
        velocity = np.asarray(velocity, dtype=float)
        if omega_world.shape != (3,) or velocity.shape != (3,):
            raise LbshapeError("initial velocity and angular velocity must be 3-vectors")
        self._allocate(r)
        self._set_scheme(scheme)
        _, K0 = elastic.force_and_tangent(np.zeros(r))
        self._solve.D[:] = alpha * np.eye(r) + beta * np.asarray(K0, dtype=float)
        self.time = 0.0
        self.steps_taken = 0
        self.phase_seconds = np.zeros((0, len(PHASES)))
        self._contact_calls = -1  # contact calls when the last evaluation was committed
        self.sweeps = 0  # rigid kick + deformation solve passes of the last step (1: no sweep)
        self.substeps = 1  # the sub-steps the last step took
        self.total_sweeps = 0  # the same, summed over every step taken
        self._forget_contraction()
        self._rate_held = False  # kick.C6 holds the last pass's effective friction rate
        self._sweep_scale = 0.0  # the residual scale of the step's first deformation solve
        self._initial_state(q, qd, velocity, omega_world)
        self._initial = self.state

    def _allocate(self, r: int) -> None:
        """The structures of the step (:mod:`lbshape.dynamics.free_body_kernels`) and the
        few arrays outside them."""
        #: the state at :attr:`time` and the state the step computes (swapped on accept)
        self._now, self._next = BodyState.allocate(r), BodyState.allocate(r)
        self._kick_arrays = RigidKick.allocate()
        self._solve = DeformationSolve.allocate(r)
        self._lu = DenseLU(r)  # the Newton matrix's factors
        self._scratch = Scratch.allocate(r)
        self._frame_arrays = self.frame.kernel_arrays
        self._dq, self._dqt = np.zeros(r), np.zeros(r)  # accepted and trial increments
        self._gen = np.zeros(r)  # the loads' generalized force at t₀ (not used by the step)
        self._q_guess = np.zeros(r)  # the predicted q₁ of the example target
        # the rigid motion the contact's friction reads: velocity of c and world ω
        self._velocity, self._omega = np.zeros(3), np.zeros(3)
        # the friction's effective rigid rate: J⁻¹ Xᵀ (6, r) and X J⁻¹ Xᵀ (6, 6)
        self._coupling_work, self._rate6 = np.zeros((6, r)), np.zeros((6, 6))
        # the loads' force and torque at the end of the step (not used by the step)
        self._end_force, self._end_torque = np.zeros(3), np.zeros(3)
        #: [internal force, contact, rigid, generalized load, solve, weights, target]
        #: seconds of a step (its sub-steps summed)
        self._seconds = np.zeros(7)
        self._marks = np.zeros(len(PHASES) + 1)
        self._clock = time.perf_counter

    def _set_scheme(self, scheme: Scheme) -> None:
        """The scheme's coefficients (:class:`~lbshape.dynamics.schemes.Scheme`) in the
        Newton solve; the step length is :attr:`dt`."""
        self._scheme_coefficients = scheme
        self._solve.scheme[:] = scheme.array
        self._set_step_length(self.dt)

    def _set_step_length(self, h: float) -> None:
        """The length h (s) of the steps taken from now on (:attr:`dt`, or a sub-step of
        it): the scheme's step rates, the factors of the Newton matrix and the round-off
        level."""
        scheme = self._scheme_coefficients
        self._h = h
        self._solve.rates[:] = scheme.step_rates(h)
        self._ca_dt2, self._ca_dt, self._cv_dt = scheme.ca / h**2, scheme.ca / h, scheme.cv / h

    def _initial_state(self, q: np.ndarray, qd: np.ndarray, velocity: np.ndarray,
                       omega_world: np.ndarray) -> None:
        """The state at t = 0: rest frame at the centre of mass, the given velocities and
        the initial acceleration ``q̈ = b − (D + Γ(ω)) q̇ − f(q)`` (no contact, ω̇ = 0)."""
        frame, state = self.frame, self._now
        state.q[:], state.qd[:] = q, qd
        state.c[:] = frame.center
        state.p[:] = frame.mass * velocity
        state.R[:] = np.eye(3)
        state.L[:] = frame.inertia(q) @ omega_world + frame.relative_momentum(q, qd)
        omega = self.omega()
        f, _ = self.elastic.force_and_tangent(q)
        state.f_elastic[:] = f
        f = np.array(f, dtype=float) + self.k_ex * q
        fe, _ = frame.centrifugal(q, omega)
        self._load_q(state.R, 0.0, self._solve.b)
        state.qa[:] = self._solve.b - (self.damping + frame.coriolis(omega)) @ qd - (f + fe)
        self._elastic_energy = 0.0  # the monitor's elastic energy at the committed state (J)
        self.energy0 = self.energy()
        self.work = 0.0

    def set_examples(self, on: bool) -> bool:
        """The configured example force (the constructor's ``driver``, ``k_ex``) on or off
        from the next step on; returns whether it acts."""
        driver, k_ex = self._examples if on else (None, 0.0)
        self.set_example_force(driver, k_ex)
        return self.driver is not None

    def displacement(self) -> np.ndarray:
        """(n, 3) world displacement ``c + R (X̄ + U q) − X`` (m); needs basis, rest_points."""
        state = self._now
        body = None if self.rest_points is None else self.rest_points - self.frame.center
        return world_displacements(state.c[None], state.R[None], state.q[None], self.basis,
                                   self.rest_points, body)[0]

    def displacements(self, record: FreeBodyRecord) -> np.ndarray:
        """(f, n, 3) the world displacements ``c + R (X̄ + U q) − X`` (m) of a record."""
        return record.displacements(self.basis)

    def _live_arrays(self) -> dict[str, np.ndarray]:
        """The arrays that carry state and caches from one step to the next, by role."""
        return {"now": self._now.data, "next": self._next.data,
                "kick": self._kick_arrays.data, "solve": self._solve.data,
                "scratch": self._scratch.data, "q_target": self.q_target, "dq": self._dq,
                "dqt": self._dqt, "velocity": self._velocity, "omega": self._omega,
                "rate6": self._rate6}

    _SCALARS = ("time", "steps_taken", "work", "energy0", "_elastic_energy",
                "_contact_calls", "sweeps", "total_sweeps", "substeps", "_contraction",
                "_contraction_age", "_sweep_change", "_rate_held", "_sweep_scale")

    @property
    def state(self) -> EngineState:
        """A snapshot (copies) of the state and the step's caches."""
        return snapshot(self.time, self._live_arrays(),
                        {name: getattr(self, name) for name in self._SCALARS})

    def reset(self, state: EngineState | None = None) -> None:
        """Back to ``state`` (from :attr:`state`) or, with ``None``, to the initial state at
        t = 0 (the example target's warm start forgotten); examples and drag stay as
        switched. The contact is evaluated afresh at the next step."""
        if state is None:
            state = self._initial
            forget_warm_starts(self.driver)
            forget_warm_starts(self._examples[0])
        scalars = restore_arrays(state, self._live_arrays())
        for name in self._SCALARS:
            setattr(self, name, type(getattr(self, name))(scalars[name]))
        self._contact_calls = -1  # the contact's arrays hold another configuration
        self.phase_seconds = np.zeros((0, len(PHASES)))

    def set_example_force(self, driver, k_ex: float) -> None:
        """Switch the example force: ``driver`` and ``k_ex`` (1/s²) as in the
        constructor (``None`` or 0: no example force) from the next step on."""
        self.driver = driver if (driver is not None and k_ex > 0.0) else None
        self.k_ex = float(k_ex) if self.driver is not None else 0.0
        self._in_place = self.driver is not None and hasattr(self.driver, "weights_into") \
            and hasattr(self.driver, "target_from_weights_into")

    # ------------------------------------------------------------ quantities
    @property
    def q(self) -> np.ndarray:
        """(r,) deformation at :attr:`time` (body frame)."""
        return self._now.q

    @property
    def qd(self) -> np.ndarray:
        """(r,) its rate."""
        return self._now.qd

    @property
    def qa(self) -> np.ndarray:
        """(r,) its acceleration."""
        return self._now.qa

    @property
    def damping(self) -> np.ndarray:
        """(r, r) Rayleigh damping of the deformation ``α I + β K₀``."""
        return self._solve.D

    @property
    def rigid(self) -> RigidState:
        """A copy of the rigid state (centre of mass, momenta, rotation) at :attr:`time`."""
        state = self._now
        return RigidState(state.c.copy(), state.p.copy(), state.R.copy(), state.L.copy())

    def omega(self) -> np.ndarray:
        """(3,) current body angular velocity (rad/s)."""
        inertia = self.frame.inertia(self.q)
        h = self.frame.relative_momentum(self.q, self.qd)
        return np.linalg.solve(inertia, self._now.R.T @ self._now.L - h)

    def energy(self, contact_energy: float | None = None) -> float:
        """Total energy (J): rigid and relative kinetic, elastic, example spring, contact
        (``contact_energy`` in J if already known)."""
        omega = self.omega()
        inertia = self.frame.inertia(self.q)
        h = self.frame.relative_momentum(self.q, self.qd)
        p = self._now.p
        kinetic = (0.5 * float(p @ p) / self.frame.mass + 0.5 * float(omega @ inertia @ omega)
                   + float(omega @ h) + 0.5 * float(self.qd @ self.qd))
        self._elastic_energy = float(self.elastic.energy(self.q))
        potential = self._elastic_energy + 0.5 * self.k_ex * float(self.q @ self.q)
        if self.contact is not None:
            if contact_energy is None:
                if self._contact_fresh():
                    contact_energy = float(self.contact.scalars[0])
                else:
                    contact_energy = self.contact.evaluate(self._now.c, self._now.R, self.q,
                                                           rigid=False).energy
            potential += contact_energy
        return kinetic + potential

    # ---------------------------------------------------------------- pieces
    def _load_q(self, rotation: np.ndarray, t: float, out: np.ndarray) -> None:
        """The generalized load ``k_ex q* + Σ Uᵀ Rᵀ f_l(t)`` (r,) into ``out``. The loads'
        force and torque at t go to scratch: the kick's ``force``, ``torque`` stay those
        at the step's start, which every contact sweep of the step uses."""
        self._loads.evaluate_into(rotation, self._now.q, t, self._end_force,
                                  self._end_torque, out)
        if self.k_ex:
            axpy(self.k_ex, self.q_target, out)

    def _interpolate(self, times: np.ndarray) -> None:
        """Step 1: weights and target ``q*`` at the predicted ``q₁ = q + h q̇ + ½ k_a h² q̈``,
        where the step's other forces act (their seconds added to ``times[5]``,
        ``times[6]``)."""
        clock, guess, state = self._clock, self._q_guess, self._now
        started = clock()
        predict(state.qd, state.qa, self._h, guess, self._solve.rates)
        guess += state.q
        weighted = started
        if self._in_place:
            self.driver.weights_into(guess)
            weighted = clock()
            self.driver.target_from_weights_into(self.q_target)
        elif self.driver is not None:  # a driver without the in-place methods
            self.q_target[:] = self.driver.target(guess).q_target
        finished = clock()
        times[5] += weighted - started
        times[6] += finished - weighted

    def _evaluate(self, index: int, t1: float, times: np.ndarray) -> float:
        """Deformation force, tangent and residual at ``q₁ = q + Δq`` (the next state's q)
        and the new pose; returns ‖residual‖. ``times`` accumulates [internal, contact]
        seconds."""
        clock = self._clock
        started = clock()
        end, solve = self._next, self._solve
        if self._into:
            self.elastic.force_and_tangent_into(end.q, solve.f, solve.K)
        else:
            f, K = self.elastic.force_and_tangent(end.q)
            solve.f[:] = f
            solve.K[:] = K
        middle = clock()
        active = False
        contact = self.contact
        if contact is not None:
            if contact.has_friction:  # the friction reads q̇₁ of this trial
                end_rates_into(solve.scheme, self._h, self._dqt, self._now.qd, self._now.qa,
                               end.qd, end.qa)
            active = contact.evaluate_into(end.c, end.R, end.q, True, self._velocity,
                                           self._omega, end.qd, self._cv_dt) > 0
        after = clock()
        norm = deformation_residual(
            self.r, self._h, self.k_ex, active, self._now.data, end.data, solve.data,
            self._dqt,
            contact.generalized if contact is not None else self._gen,
            contact.stiffness_q if contact is not None else solve.K)
        finished = clock()
        times[0] += (middle - started) + (finished - after)
        times[1] += after - middle
        if not math.isfinite(norm):
            raise SolverError(f"non-finite deformation residual at step {index} "
                              f"(t = {t1:.6g} s)")
        return norm

    def _kick(self, index: int, t1: float, active: bool, *, sweep: bool,
              times: np.ndarray) -> None:
        """The rigid update (:func:`~lbshape.dynamics.free_body_kernels.rigid_update`) to
        (c₁, p₁, R₁, L₁), the deformation damping D + Γ(ω₁) and the generalized load at
        t₁; a ``sweep`` uses the contact at the end of the previous sweep."""
        started = self._clock()
        result = rigid_update(self.r, self._h, active or sweep, sweep, self._frame_arrays.data,
                              self._now.data, self._next.data, self._kick_arrays.data,
                              self._solve.data, self._scratch.data)
        if result == KICK_ROTATION_FAILED:
            raise rotation_error(self._h, self._kick_arrays.omega_mid, index, t1)
        if result == KICK_SINGULAR:
            raise SolverError(f"singular inertia at step {index} (t = {t1:.6g} s)")
        if self.contact is not None and self.contact.has_friction:
            # the rigid motion at t₁ the friction of the deformation solve reads
            np.divide(self._next.p, self.frame.mass, out=self._velocity)
            np.dot(self._next.R, self._kick_arrays.omega1, out=self._omega)
        rigid_done = self._clock()
        self._load_q(self._next.R, t1, self._solve.b)
        times[2] += rigid_done - started
        times[3] += self._clock() - rigid_done

    def _solve_deformation(self, index: int, t1: float, times: np.ndarray, *,
                           sweep: bool = False) -> int:
        """Newton on the deformation at the kicked pose (contact implicit in q₁); returns
        the iterations. A ``sweep`` starts from the last sweep's Δq and keeps its residual
        scale (the same step's problem, moved by the kick). ``times`` accumulates
        [internal force, contact, -, -, solve] s."""
        started = self._clock()
        before = times[0] + times[1]
        dt, state, solve = self._h, self._now, self._solve
        newton_base(solve.damping, self._ca_dt2, self._cv_dt, solve.base)
        if sweep:
            self._dqt[:] = self._dq
        else:
            predict(state.qd, state.qa, dt, self._dqt, solve.rates)
        np.add(state.q, self._dqt, out=self._next.q)
        b_norm, qa_norm, qd_norm = _norm(solve.b), _norm(state.qa), _norm(state.qd)
        scale = max(b_norm, qa_norm, self._sweep_scale if sweep else 0.0)
        norm = self._evaluate(index, t1, times)
        self._dq, self._dqt = self._dqt, self._dq
        scale = self._sweep_scale = max(scale, norm, solve.norms[0], solve.norms[1])
        # in contact the residual is not monotone where a vertex touches a plane to
        # round-off (its penalty force, and its friction, switch with the gap's last
        # bits): the contact's round-off joins the noise level. Without it a frictionless
        # wall impact of the car, barely deformed, cycled at 4e-12 (round-off) against a
        # scale of 5e-10 and stopped
        touching = self.contact is not None
        iteration = 0
        while True:
            noise = _EPS64 * (self._ca_dt2 * _norm(self._dq) + solve.norms[0] + b_norm
                              + self._ca_dt * qd_norm + qa_norm)
            if touching:
                noise += self.contact.round_off(self._next.c, self._next.q)
            if norm <= self.newton.rtol * scale or norm <= noise:
                break
            if iteration == self.newton.max_iterations:
                raise SolverError(
                    f"Newton did not converge at step {index} (t = {t1:.6g} s): relative "
                    f"residual {norm / scale:.3e} after {iteration} iterations")
            if not self._lu.factor(solve.base, solve.K):
                raise SolverError(f"singular Newton matrix at step {index} "
                                  f"(t = {t1:.6g} s)")
            self._lu.solve_into(solve.residual, solve.delta)
            # backtracking: contact makes the residual only piecewise smooth; the last
            # trial is the accepted one
            fraction = 1.0
            while True:
                trial(state.q, self._dq, solve.delta, fraction, self._dqt, self._next.q)
                trial_norm = self._evaluate(index, t1, times)
                if trial_norm < norm or fraction <= 1.0 / 64:
                    break
                fraction *= 0.5
            self._dq, self._dqt = self._dqt, self._dq
            norm = trial_norm
            iteration += 1
        times[4] += self._clock() - started - (times[0] + times[1] - before)
        return iteration

    def _sweeps(self, index: int, t1: float, active: bool, times: np.ndarray) -> int:
        """Steps 2–5: the rigid kick and the deformation solve, repeated while contact
        sweeps are needed; returns the Newton iterations of all sweeps."""
        iterations = sweeps = 0
        while True:
            self._kick(index, t1, active, sweep=sweeps > 0, times=times)
            iterations += self._solve_deformation(index, t1, times, sweep=sweeps > 0)
            sweeps += 1
            if not self._sweep_again(sweeps):
                break
        self.sweeps += sweeps
        self.total_sweeps += sweeps
        contact = self.contact
        self._depth = depth = float(contact.scalars[2]) if contact is not None else 0.0
        if contact is not None and depth > contact.radius0:
            raise SolverError(f"contact failed at step {index} (t = {t1:.6g} s): a vertex is "
                              f"{depth:.3g} m behind a plane (the body's radius is "
                              f"{contact.radius0:.3g} m); lower dt or raise the stiffness")
        return iterations

    def _commit(self, index: int, t1: float) -> None:
        """Check the new state (finite, energy monitor, inversion) and make it current."""
        contact = self.contact
        contact_energy = float(contact.scalars[0]) if contact is not None else 0.0
        finite = commit_energy(self.r, self.k_ex, contact_energy, self._frame_arrays.data,
                               self._now.data, self._next.data, self._kick_arrays.data,
                               self._solve.data, self._scratch.data)
        energies = self._scratch.energies
        work = self.work + energies[1]
        budget = abs(self.energy0) + work
        if not finite:
            raise SolverError(f"non-finite state at step {index} (t = {t1:.6g} s)")
        if self._inversion and not (jacobian := self.elastic.min_jacobian_into(self._next.q)) > 0:
            raise SolverError(sanity.inverted_message(index, t1, jacobian, "a cubature element"))
        elastic = self._elastic_energy + energies[2]  # tracked by the elastic force's work
        energy = energies[0] + max(elastic, 0.0)
        limit = sanity.ENERGY_FACTOR * budget
        if not math.isfinite(energy) or (budget > 0 and max(
                energy, -elastic) > EXACT_ENERGY_FRACTION * limit):
            elastic = float(self.elastic.energy(self._next.q))
            energy = energies[0] + elastic
            if not math.isfinite(energy) or (budget > 0 and energy > limit):
                raise SolverError(f"energy blew up ({energy:.3e} J > {sanity.ENERGY_FACTOR:g} x "
                                  f"budget {budget:.3e} J) at step {index} (t = {t1:.6g} s)")
            if budget > 0 and elastic < -limit:
                raise SolverError(sanity.negative_energy_message(index, t1, elastic, budget))
        self._elastic_energy = elastic
        self.work = work
        self._now, self._next = self._next, self._now
        if contact is not None:
            self._contact_calls = contact.evaluated + contact.skipped
        self.time, self.steps_taken = t1, index

    # ------------------------------------------------------------------ step
    def _advance(self, index: int, t1: float, times: np.ndarray) -> int:
        """Steps 1–5 from :attr:`time` to ``t1`` (a step or sub-step of length ``_h``) into
        the next state, not committed; returns the Newton iterations (seconds to ``times``)."""
        if self.drag is not None:
            self._drag_load()
        self._interpolate(times)
        active, contact_t0 = self._start_of_step()
        times[1] += contact_t0
        return self._sweeps(index, t1, active, times)

    # ------------------------------------------------------------------- run
    def run(self, steps: int, *, stride: int = 1, on_step: OnStep | None = None) -> FreeBodyRecord:
        """Advance ``steps`` steps keeping every ``stride``-th state (and the initial one);
        a failure ends the run with ``stable=False`` and the message. ``on_step`` is
        called after each step (outside its timing) with (step index from 0, time in s,
        q (r,))."""
        return run_free_body(self, steps, stride, on_step)


def run_free_body(body, steps: int, stride: int, on_step: OnStep | None) -> FreeBodyRecord:
    """The run of a free body's engine (:meth:`FreeBodySimulation.run`, or an engine of
    two bases, :mod:`lbshape.dynamics.impact_switch`): its ``step()`` ``steps`` times,
    every ``stride``-th state recorded, the parts of each step (its ``_marks``) into
    ``phase_seconds``; a failure ends the record with ``stable=False`` and the message."""
    steps, stride = check_run(steps, stride)
    recorder = FreeBodyRecorder(body, steps, stride)
    phases = np.zeros((steps, len(PHASES)))
    body.phase_seconds = phases[:0]
    with collector_paused():
        for index in range(steps):
            try:
                iterations = body.step()
            except SolverError as exc:
                scales = [load.profile(body.time + body.dt) for load in body.loads]
                message = sanity.stop_message(exc, load_reach=body.load_reach,
                                              scales=scales, omega_max=body.omega_max,
                                              dt=body.dt)
                log.error("free-body simulation stopped: %s", message)
                return recorder.record(stable=False, message=message)
            marks = body._marks
            np.subtract(marks[1:], marks[:-1], out=phases[index])
            body.phase_seconds = phases[:index + 1]
            recorder.step(iterations, marks[2] - marks[0], marks[-1] - marks[0],
                          body._depth)
            if on_step is not None:
                on_step(index, body.time, body.q)
    return recorder.record()
