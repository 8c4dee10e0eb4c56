"""Reduced real-time simulation with example-driven forces (paper run-time steps 1–3, 5).

Equation of motion in mass-orthonormal reduced coordinates q (r,):
``q̈ + D q̇ + f_int(q) + k_ex (q − q*) = Uᵀ f_ext(t)``, with ``f_int`` from the
cubature (:class:`~lbshape.elastic.reduced_forces.ReducedForceModel`), Rayleigh damping
``D = α I + β K₀`` (K₀ the elastic tangent at rest), and the target ``q*``
recomputed once per step from the state at the start of the step (weights and
target: :class:`~lbshape.shapespace.example_driver.ExampleDriver`). The example force is
split, as in the full-space reference, into a spring ``k_ex q`` (position
dependent, potential ``½ k_ex |q|²``) and a pull ``k_ex q*`` held constant within
the step and applied as an external load, so the energy monitor counts the pull
as external work and Newton does not fight two cancelling large terms near the
target. The step itself only
touches r-, m- and s-sized arrays; full-space displacements ``U q`` are formed
only for output frames, outside the timed step.

**The step path** (:meth:`ReducedSimulation.step`) is allocation-free: every array
it writes is preallocated, the weights and the tabulated target are written in place
(:meth:`~lbshape.shapespace.example_driver.ExampleDriver.target_into`), the elastic
force and tangent come from the compiled element kernel
(:meth:`~lbshape.elastic.reduced_forces.ReducedForceModel.force_and_tangent_into`), and
one compiled kernel forms the Newmark (or backward Euler) residual and Newton matrix
— the scheme's coefficients from :data:`~lbshape.dynamics.schemes.SCHEMES` — and
solves it by Cholesky (:mod:`lbshape.dynamics.kernels`). **Newton runs until the
relative residual, measured at the state the step accepts, is below** ``rtol``
(:data:`REALTIME_RTOL` for real time). Its first update solves the step with the
elastic force linearised at the start of the step — whose force and tangent are the
previous step's last evaluation — so a step that meets the tolerance after one update
costs one force and tangent evaluation, at the new state, and that evaluation starts
the next step (updates per step and the error at 1 ms and at 20–60 Hz:
``results/large_steps.md``).
``newton_iterations`` instead fixes the updates per step from the predictor, residual
unchecked (only for studies of that choice). Each step's wall time is split into
:data:`PHASES` (:attr:`ReducedSimulation.phase_seconds`).

**Divergence** (:mod:`lbshape.dynamics.sanity`). A non-finite load, residual or state, a
Newton matrix that is not positive definite and cannot be solved, a Newton that does not
reach ``rtol`` in ``max_iterations``, a kinetic plus elastic energy above ``energy_factor``
times the energy made available (initial energy plus the accumulated work of the loads,
the example pull and a drag), or, for a material that forbids inversion, an inverted
cubature element (det F ≤ 0, checked on the s cubature elements) raise
:class:`~lbshape.errors.SolverError` naming the step; the state stays at the last good
step. How large the state is never stops a run (a buckled bar folds beyond its size).
:meth:`ReducedSimulation.run` adds the likely cause to the message
(:func:`~lbshape.dynamics.sanity.failure_advice`: a load far beyond what the object
carries, or a step coarse against ``omega_max``).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence

import numpy as np
import scipy.linalg as sla

from lbshape._jit import njit
from lbshape.dynamics.contact import PlaneContact
from lbshape.dynamics.drag import DragSpring
from lbshape.dynamics.engine import (
    Drag,
    EngineState,
    NewtonSettings,
    OnStep,
    basis_rows,
    check_run,
    collector_paused,
    forget_warm_starts,
    restore_arrays,
    snapshot,
)
from lbshape.dynamics.example_ramp import check_ramp, ramp_factor
from lbshape.dynamics.kernels import (
    all_finite,
    axpy,
    cholesky_in_place,
    cholesky_solve_in_place,
    dot_sum,
    predict,
    quadratic_form,
)
from lbshape.dynamics.kernels import norm as _norm
from lbshape.dynamics.loads import TimedLoad
from lbshape.dynamics.record import RunRecord, RunRecorder
from lbshape.dynamics.sanity import (
    ENERGY_FACTOR,
    checks_inversion,
    inverted_message,
    step_warnings,
    stop_message,
)
from lbshape.dynamics.schemes import get_scheme
from lbshape.errors import LbshapeError, SolverError
from lbshape.shapespace.example_driver import ExampleDriver

log = logging.getLogger(__name__)

#: the frame of a fixed object: world = object frame
_ORIGIN, _IDENTITY3 = np.zeros(3), np.eye(3)
#: relative Newton residual at which a real-time step is accepted: the trajectories stay
#: within ~1e-6 (relative, mass norm) of converged Newton at 1 to 50 ms steps
#: (``results/step_breakdown.md``, ``results/large_steps.md``)
REALTIME_RTOL = 1e-5
#: the real-time Newton settings of the reduced engines
REALTIME_NEWTON = NewtonSettings(REALTIME_RTOL, 20)
#: the energy monitor computes the exact potential from this fraction of its limit on
#: (below it the potential tracked by the work of the elastic force decides)
EXACT_ENERGY_FRACTION = 0.5
#: the parts of a step timed in :attr:`ReducedSimulation.phase_seconds`
PHASES: tuple[str, ...] = ("weights", "target", "example_force", "internal_force_tangent",
                           "solve", "overhead")


class ReducedSimulation:
    """Implicit reduced dynamics with optional example forces (see the module docstring).

    Args:
        elastic: reduced internal force model (``force_and_tangent(q)`` and, for the
            compiled path, ``force_and_tangent_into(q, f, K)``; ``energy(q)``).
        r: reduced dimension.
        dt: time step (s).
        integrator: ``"newmark"`` or ``"backward-euler"``.
        alpha, beta: Rayleigh coefficients (1/s, s).
        loads: reduced loads (patterns ``Uᵀ f`` (r,)).
        driver: the example driver, or ``None`` (no example machinery at all). A
            driver with a ``spring`` attribute (r, r) (local examples,
            :class:`~lbshape.shapespace.local_driver.LocalExampleDriver`) uses it in
            place of the identity in the spring ``k_ex S q``. A driver without the
            in-place methods (``weights_into``, ``target_from_weights_into``) is called
            through ``target(q)``.
        k_ex: example stiffness (1/s²); 0 disables the example force.
        example_ramp: T in s of ``k_ex(t) = k_ex s(min(1, t/T))``
            (:mod:`lbshape.dynamics.example_ramp`); 0 (default): k_ex from t = 0.
        contact: penalty contact with planes (:class:`~lbshape.dynamics.contact.PlaneContact`
            built on the rest positions, ``x = X + U q``), implicit in q; or ``None``.
            Frictionless: friction is modelled on free bodies only.
        newton_iterations: ``None`` (default): iterate until the relative residual at the
            accepted state is below ``newton.rtol``; a number: that many updates from the
            predictor, residual unchecked (studies only).
        newton: the :class:`~lbshape.dynamics.engine.NewtonSettings` (default
            :data:`REALTIME_NEWTON`: :data:`REALTIME_RTOL`, 20 updates before the step
            fails, ``None`` mode).
        energy_factor: blow-up factor of the energy monitor (default
            :data:`~lbshape.dynamics.sanity.ENERGY_FACTOR`); ``None`` disables it.
        omega_max: the highest vibration frequency the basis holds (rad/s; the largest
            linear mode's), for the coarse-step warning and the failure advice; or ``None``.
        load_reach: ``() -> LoadReach | None``, the loads' linear static strains
            (:class:`~lbshape.dynamics.sanity.LoadReach`, loads in order), evaluated only
            once a run stopped, for the failure advice; or ``None``.
        basis: (3n, r) the basis U (m per unit of q), for :meth:`displacement` and
            :meth:`set_drag`; optional.
        rest_points: (n, 3) the rest positions X (m), for :meth:`set_drag`; optional.

    Attributes:
        x, v, a: (r,) state at :attr:`time`.
        q_target: (r,) the last target ``q*``.
        drag: the user's :class:`~lbshape.dynamics.drag.DragSpring` (:meth:`set_drag`) or
            ``None``: its spring part is in the force and tangent, its pull in the loads.
        last_residual: relative Newton residual at the state the last step accepted
            (``None`` mode).
        warnings: one-line warnings about the run's set-up (a coarse step,
            :func:`~lbshape.dynamics.sanity.coarse_step`), logged once when it is built.
        phase_seconds: (steps, len(PHASES)) wall time of each part of each step of the
            last :meth:`run` (s).
    """

    #: the parts of a step timed in ``phase_seconds``
    phases: tuple[str, ...] = PHASES

    def __init__(
        self,
        elastic,
        *,
        r: int,
        dt: float,
        integrator: str = "newmark",
        alpha: float = 0.0,
        beta: float = 0.0,
        loads: Sequence[TimedLoad] = (),
        driver: ExampleDriver | None = None,
        k_ex: float = 0.0, example_ramp: float = 0.0,
        contact: PlaneContact | None = None,
        newton_iterations: int | None = None,
        newton: NewtonSettings = REALTIME_NEWTON,
        energy_factor: float | None = ENERGY_FACTOR,
        omega_max: float | None = None,
        load_reach=None,
        basis: np.ndarray | None = None,
        rest_points: np.ndarray | None = None,
    ):
        scheme = get_scheme(integrator)
        if not (np.isfinite(dt) and dt > 0):
            raise LbshapeError(f"time step dt must be > 0 s, got {dt}")
        if newton_iterations is not None and int(newton_iterations) < 1:
            raise LbshapeError(f"newton_iterations must be >= 1 or None, got {newton_iterations}")
        if contact is not None and contact.has_friction:
            raise LbshapeError("contact friction acts on free bodies only; this object is "
                               "fixed (give its planes friction = 0)")
        self.elastic = elastic
        self.contact = contact
        self.drag: DragSpring | None = None
        self.r = r = int(r)
        self.dt = h = float(dt)
        self.integrator = integrator
        self.loads = list(loads)
        self.driver = driver if (driver is not None and k_ex > 0.0) else None
        self.k_ex = float(k_ex) if self.driver is not None else 0.0
        self.newton_iterations = None if newton_iterations is None else int(newton_iterations)
        self.newton = newton
        self.basis = None if basis is None else np.asarray(basis, dtype=float)
        self.rest_points = None if rest_points is None else np.asarray(rest_points, dtype=float)
        self._setup_checks(energy_factor, omega_max, load_reach, example_ramp)
        # [c_a/h², k_v/h, k_a, c_v/h, j_v, k_ex]: the scheme's step rates and the spring
        rates = scheme.step_rates(h)
        self._coefficients = np.array([*rates, self.k_ex])

        _, K0 = elastic.force_and_tangent(np.zeros(r))
        self.damping = alpha * np.eye(r) + beta * np.asarray(K0)
        self._base = rates[0] * np.eye(r) + rates[3] * self.damping
        self._patterns = [np.ascontiguousarray(load.pattern, dtype=float) for load in self.loads]
        self._profiles = [load.profile for load in self.loads]
        self._into = hasattr(elastic, "force_and_tangent_into")
        # state and work arrays (the step allocates nothing)
        self.x, self.v, self.a = np.zeros(r), np.zeros(r), np.zeros(r)
        self.q_target = np.zeros(r)
        self._fext, self._fext_old = np.zeros(r), np.zeros(r)
        self._dx, self._x1, self._v1, self._a1 = (np.zeros(r) for _ in range(4))
        self._f, self._K = np.zeros(r), np.zeros((r, r))
        self._R, self._J = np.zeros(r), np.zeros((r, r))
        self._norms = np.zeros(4)
        self.time, self.steps_taken = 0.0, 0
        self.phase_seconds = np.zeros((0, len(PHASES)))
        self._clock = time.perf_counter
        self._marks = np.zeros(len(PHASES) + 1)
        # initial acceleration (M = I): a0 = f_ext(0) − D v0 − f(x0) (x0 = v0 = 0)
        self._external_into(0.0, self._fext)
        self.a[:] = self._fext
        self._fext_old[:] = self._fext
        self._work, self._initial_energy = 0.0, 0.0
        self._f_norm = 0.0
        self.last_residual = 0.0
        # force and tangent at the start of the step (the linearisation of the first update)
        self._f_start, self._K_start = np.zeros(r), np.zeros((r, r))
        self._force_and_tangent(self.x)
        self._f_start[:], self._K_start[:] = self._f, self._K
        self._held_energy = self._potential(self.x)  # tracked by _finish's energy monitor
        self._initial = self.state

    def _setup_checks(self, energy_factor: float | None, omega_max: float | None,
                      load_reach, example_ramp: float) -> None:
        """The divergence checks, the warnings and the example force as configured
        (``_examples``, with the full k_ex) and ramped (``k_ex``: the current step's)."""
        self.example_ramp = check_ramp(example_ramp)
        self._examples = (self.driver, self.k_ex)  # the configured example force
        self._k_full, self.k_ex = self.k_ex, self.k_ex * ramp_factor(0.0, self.example_ramp)
        self.energy_factor = energy_factor
        self.omega_max = None if omega_max is None else float(omega_max)
        self.load_reach = load_reach
        self._inversion = checks_inversion(self.elastic)  # det F <= 0 stops the run
        self.warnings = step_warnings(self.omega_max, self.dt, log)

    @property
    def driver(self):
        """The example driver (None: no example force); assigning one re-reads its spring
        and whether it has the in-place methods."""
        return self._driver

    @driver.setter
    def driver(self, driver) -> None:
        self._driver = driver
        spring = getattr(driver, "spring", None)
        self._spring = np.eye(self.r) if spring is None else np.array(spring, dtype=float)
        self._in_place = hasattr(driver, "weights_into") and hasattr(
            driver, "target_from_weights_into")

    def set_drag(self, drag: Drag | None) -> None:
        """A user's point pull (:class:`~lbshape.dynamics.engine.Drag`) from the next step
        on, or ``None`` to release it: a :class:`~lbshape.dynamics.drag.DragSpring` on the
        vertex's rows of the basis, implicit in the step (needs ``basis`` and
        ``rest_points``). A drag on the same vertex with the same stiffness moves the
        spring's target."""
        if drag is None:
            self.drag = None
        elif (self.drag is not None and self.drag.vertex == drag.vertex
              and self.drag.stiffness == drag.stiffness):
            self.drag.move(drag.target)
        else:
            rows = basis_rows(self.basis, drag.vertex, "a drag")
            if self.rest_points is None:
                raise LbshapeError("a drag needs the rest points (give rest_points=...)")
            self.drag = DragSpring(drag.vertex, rows, self.rest_points[drag.vertex],
                                   drag.stiffness, drag.target)
        self._relinearise()

    def set_examples(self, on: bool) -> bool:
        """The configured example force (the constructor's ``driver``, ``k_ex``) on or off
        from the next step on; returns whether it acts."""
        driver, k_ex = self._examples if on else (None, 0.0)
        self.set_example_force(driver, k_ex)
        return self.driver is not None

    def set_example_force(self, driver, k_ex: float) -> None:
        """Switch the example force: ``driver`` and ``k_ex`` (1/s²) as in the
        constructor (``None`` or 0: no example force) from the next step on."""
        self.driver = driver if (driver is not None and k_ex > 0.0) else None
        self._k_full = float(k_ex) if self.driver is not None else 0.0
        self.k_ex = self._k_full * ramp_factor(self.time, self.example_ramp)
        self._coefficients[5] = self.k_ex
        self._relinearise()

    def _relinearise(self) -> None:
        """The force and tangent at the current state again (the next step's first Newton
        update starts from them), after a change of the forces; the potential the change
        puts in or takes out at this state (a drag grabbing) is work for the energy monitor."""
        self._force_and_tangent(self.x)
        self._f_start[:], self._K_start[:] = self._f, self._K
        held = self._potential(self.x) - self._spring_energy(self.x)
        self._work, self._held_energy = self._work + abs(held - self._held_energy), held

    @property
    def stepper(self) -> ReducedSimulation:
        """The simulation itself (it is its own stepper: ``x``, ``time``, ``newton`` …)."""
        return self

    # ------------------------------------------------------------ protocol
    def displacement(self) -> np.ndarray:
        """(n, 3) world displacement ``U q`` of every vertex (m); needs ``basis``."""
        if self.basis is None:
            raise LbshapeError("displacement() needs the basis U (give basis=...)")
        return (self.basis @ self.x).reshape(-1, 3)

    def displacements(self, record: RunRecord) -> np.ndarray:
        """(f, n, 3) the world displacements ``U q`` (m) of a record of this engine."""
        if self.basis is None:
            raise LbshapeError("displacements() needs the basis U (give basis=...)")
        return record.displacements(self.basis)

    def _live_arrays(self) -> dict[str, np.ndarray]:
        """The arrays that carry state from one step to the next, by role."""
        return {"x": self.x, "v": self.v, "a": self.a, "q_target": self.q_target,
                "fext_old": self._fext_old, "f_start": self._f_start,
                "K_start": self._K_start}

    _SCALARS = ("time", "steps_taken", "_work", "_initial_energy", "_held_energy", "_f_norm",
                "last_residual")

    @property
    def state(self) -> EngineState:
        """A snapshot (copies) of the state and the step's caches."""
        scalars = {name: getattr(self, name) for name in self._SCALARS}
        scalars["dragged"] = self.drag is not None  # the drag is in f_start, K_start
        return snapshot(self.time, self._live_arrays(), scalars)

    def reset(self, state: EngineState | None = None) -> None:
        """Back to ``state`` (from :attr:`state`) or, with ``None``, to the initial state at
        t = 0 (the example target's warm start forgotten); examples and drag stay as
        switched (the force at the start of the step is evaluated again under a drag)."""
        if state is None:
            state = self._initial
            forget_warm_starts(self.driver)
            forget_warm_starts(self._examples[0])
        scalars = restore_arrays(state, self._live_arrays())
        for name in self._SCALARS:
            setattr(self, name, type(getattr(self, name))(scalars[name]))
        self.phase_seconds = np.zeros((0, len(PHASES)))
        if self.drag is not None or scalars["dragged"]:
            self._relinearise()

    # --------------------------------------------------------------- pieces
    def _external_into(self, t: float, out: np.ndarray) -> None:
        """Loads at time t plus the example pull ``k_ex q*`` and a drag's pull (r,),
        written into ``out``."""
        if self.k_ex:
            np.multiply(self.q_target, self.k_ex, out=out)
        else:
            out[:] = 0.0
        for pattern, profile in zip(self._patterns, self._profiles, strict=True):
            scale = profile(t)
            if scale:
                axpy(scale, pattern, out)
        if self.drag is not None:
            self.drag.pull_into(out)

    def _force_and_tangent(self, q: np.ndarray) -> None:
        if self._into:
            self.elastic.force_and_tangent_into(q, self._f, self._K)
        else:
            f, K = self.elastic.force_and_tangent(q)
            self._f[:] = f
            self._K[:] = K
        if self.contact is not None:  # contact may touch surface vertices (n-sized)
            if self.contact.evaluate_into(_ORIGIN, _IDENTITY3, q, False):
                self._f -= self.contact.generalized
                self._K += self.contact.stiffness_q
        if self.drag is not None:
            self.drag.spring_into(q, self._f, self._K)

    def _ramp_examples(self, t1: float) -> None:
        """k_ex(t₁) of the ramp, in the pull and the spring; the spring energy the change
        adds at the current state is work for the energy monitor."""
        before = self._spring_energy(self.x)
        self.k_ex = self._coefficients[5] = self._k_full * ramp_factor(t1, self.example_ramp)
        self._work += self._spring_energy(self.x) - before

    def _spring_energy(self, q: np.ndarray) -> float:
        """The example spring's potential ``½ k_ex qᵀ S q`` (J; r²-sized, no allocation)."""
        return 0.5 * self.k_ex * float(quadratic_form(self._spring, q)) if self.k_ex else 0.0

    def _potential(self, q: np.ndarray) -> float:
        energy = float(self.elastic.energy(q))
        if self.k_ex:
            energy += 0.5 * self.k_ex * float(q @ (self._spring @ q))
        if self.contact is not None:
            self.contact.evaluate_into(_ORIGIN, _IDENTITY3, q, False)
            energy += float(self.contact.scalars[0])
        if self.drag is not None:
            energy += self.drag.energy(q)
        return energy

    # ----------------------------------------------------------------- step
    def step(self) -> int:
        """Advance one time step; return the Newton updates used.

        Raises:
            SolverError: see the module docstring; the state stays at the last step.
        """
        clock, marks = self._clock, self._marks
        marks[0] = clock()
        index = self.steps_taken + 1
        t1 = self.time + self.dt
        if self._in_place:
            self.driver.weights_into(self.x)
            marks[1] = clock()
            self.driver.target_from_weights_into(self.q_target)
            marks[2] = clock()
        elif self.driver is not None:  # e.g. local examples: one call, allocating
            marks[1] = marks[0]
            self.q_target[:] = self.driver.target(self.x).q_target
            marks[2] = clock()
        else:
            marks[1] = marks[2] = marks[0]
        if self.example_ramp and self.driver is not None:
            self._ramp_examples(t1)
        self._external_into(t1, self._fext)
        marks[3] = clock()
        coefficients = self._coefficients
        predict(self.v, self.a, self.dt, self._dx, coefficients)
        if self.newton_iterations is None:
            forces, solves, updates = self._solve_to_tolerance(index, t1)
        else:
            forces, solves, updates = self._fixed_updates(index, t1)
        marks[4] = marks[3] + forces
        marks[5] = marks[4] + solves
        self._finish(index, t1)
        marks[6] = clock()
        return updates

    def _solve_to_tolerance(self, index: int, t1: float) -> tuple[float, float, int]:
        """Newton until the relative residual is below ``rtol``; (force s, solve s, updates).

        The first update solves the step's equation with the elastic force linearised at
        the start of the step (its force and tangent are the last evaluation of the
        previous step), so a step whose first update already meets the tolerance costs
        one force and tangent evaluation — at the new state, where the residual is
        measured — and hands that evaluation on to the next step.
        """
        clock, norms = self._clock, self._norms
        started = clock()
        _linear_force(self._f_start, self._K_start, self._dx, self._f)
        self._K[:] = self._K_start
        np.add(self.x, self._dx, out=self._x1)
        self._residual_into()
        scale = max(norms[0], norms[2], norms[3], self._f_norm, _norm(self.a))
        self._update(index, t1)
        forces, solves, updates = 0.0, clock() - started, 1
        while True:
            forces += self._evaluate_trial()
            middle = clock()
            if not np.isfinite(norms[0]):
                raise SolverError(f"non-finite residual at step {index} (t = {t1:.6g} s)")
            self.last_residual = norms[0] / scale if scale > 0 else 0.0
            if norms[0] <= max(self.newton.rtol * scale, norms[1]):
                solves += clock() - middle
                break
            if updates == self.newton.max_iterations:
                raise SolverError(
                    f"Newton did not converge at step {index} (t = {t1:.6g} s): relative "
                    f"residual {self.last_residual:.3e} after {updates} iterations "
                    f"(rtol {self.newton.rtol:g})")
            self._update(index, t1)
            updates += 1
            solves += clock() - middle
        # the new state's force and tangent start the next step
        self._f, self._f_start = self._f_start, self._f
        self._K, self._K_start = self._K_start, self._K
        return forces, solves, updates

    def _fixed_updates(self, index: int, t1: float) -> tuple[float, float, int]:
        """Exactly ``newton_iterations`` updates from the predictor, residual unchecked
        (for studies of the update count); (force s, solve s, updates)."""
        clock = self._clock
        forces = solves = 0.0
        for _ in range(self.newton_iterations):
            forces += self._evaluate_trial()
            middle = clock()
            self._update(index, t1)
            solves += clock() - middle
        _kinematics(self._dx, self.x, self.v, self.a, self._coefficients, self._x1, self._v1,
                    self._a1)
        self._f_start[:] = self._f  # the force at the last evaluation (for the next step)
        self._K_start[:] = self._K
        return forces, solves, self.newton_iterations

    def _evaluate_trial(self) -> float:
        """Force, tangent and residual at the trial state ``x + dx`` (into ``_x1``, ``_f``,
        ``_K``, ``_R``, ``_norms``); returns the seconds the force and tangent took."""
        started = self._clock()
        np.add(self.x, self._dx, out=self._x1)
        self._force_and_tangent(self._x1)
        seconds = self._clock() - started
        self._residual_into()
        return seconds

    def _residual_into(self) -> None:
        """The step's residual at ``x + dx`` with the current force and tangent into
        ``_R`` and its norms into ``_norms`` (also sets ``_v1``, ``_a1``)."""
        _end_rates(self._dx, self.v, self.a, self._coefficients, self._v1, self._a1)
        _residual(self._x1, self._v1, self._a1, self._f, self._fext, self.damping,
                  self._spring, self._coefficients, self._R, self._norms)

    def _update(self, index: int, t1: float) -> None:
        """One Newton update of ``dx`` from ``_R`` and the tangent ``_K``."""
        if not _newton_update(self._base, self._K, self._spring, self._coefficients, self._R,
                              self._J, self._dx):
            self._dense_update(index, t1)

    def _dense_update(self, index: int, t1: float) -> None:
        """Newton update with a symmetric indefinite solve (Cholesky failed)."""
        J = self._base + self._K + self.k_ex * self._spring
        try:
            delta = sla.solve(J, self._R, assume_a="sym", check_finite=False)
        except (sla.LinAlgError, ValueError) as exc:
            raise SolverError(f"singular Newton matrix at step {index} (t = {t1:.6g} s): "
                              f"{exc}") from None
        self._dx -= delta

    def _finish(self, index: int, t1: float) -> None:
        """Checks, energy monitor and the swap to the new state (no allocation)."""
        if not all_finite(self._x1, self._v1, self._a1):
            raise SolverError(f"non-finite state at step {index} (t = {t1:.6g} s)")
        if self._inversion:
            jacobian = self.elastic.min_jacobian_into(self._x1)
            if not jacobian > 0.0:
                raise SolverError(inverted_message(index, t1, jacobian, "a cubature element"))
        work = self._work + abs(0.5 * dot_sum(self._fext_old, self._fext, self._dx))
        # _held_energy: the potential of the forces in f (elastic, contact, drag; not the
        # example spring), tracked by the trapezoidal work of f and made exact whenever the
        # monitor computes it: f(x₀) is in _f and f(x₁) in _f_start after a converged step;
        # the fixed updates (studies) never evaluate f(x₁): their potential is exact
        exact = self.newton_iterations is not None
        held = self._held_energy + 0.5 * dot_sum(self._f, self._f_start, self._dx)
        if exact:
            held = self._potential(self._x1) - self._spring_energy(self._x1)
        if self.energy_factor is not None:
            budget = self._initial_energy + work
            kinetic = 0.5 * dot_sum(self._v1, None, self._v1)
            energy = kinetic + held + self._spring_energy(self._x1)
            limit = self.energy_factor * budget
            if budget > 0 and not energy <= EXACT_ENERGY_FRACTION * limit:
                if not exact:  # confirm with the exact potential (rare: allocates)
                    held = self._potential(self._x1) - self._spring_energy(self._x1)
                    energy = kinetic + held + self._spring_energy(self._x1)
                if not energy <= limit:
                    raise SolverError(
                        f"energy blew up at step {index} (t = {t1:.6g} s): {energy:.3e} J "
                        f"exceeds {self.energy_factor:g} x budget {budget:.3e} J (the "
                        "initial energy and the work of the loads and the example pull)")
        self._held_energy = held
        self.x, self._x1 = self._x1, self.x
        self.v, self._v1 = self._v1, self.v
        self.a, self._a1 = self._a1, self.a
        self._fext_old, self._fext = self._fext, self._fext_old
        self._work = work
        self.time = t1
        self.steps_taken = index
        self._f_norm = _norm(self._f_start)

    # ------------------------------------------------------------------ run
    def run(self, steps: int, *, stride: int = 1, on_step: OnStep | None = None) -> RunRecord:
        """Advance ``steps`` steps keeping every ``stride``-th state (≥ 1; and the initial
        one); a solver failure ends the run with ``stable=False``. ``on_step`` is called
        after each step with (step index from 0, time in s, q (r,)). Returns the
        :class:`~lbshape.dynamics.record.RunRecord` of the reduced coordinates q (r,);
        the split of each step's time into :data:`PHASES` is kept in
        :attr:`phase_seconds`."""
        steps, stride = check_run(steps, stride)
        recorder = RunRecorder(stride=stride)
        recorder.start(self.time, self.x)
        phases = np.zeros((steps, len(PHASES)))
        self.phase_seconds = phases[:0]
        marks = self._marks
        with collector_paused():
            for index in range(steps):
                try:
                    iterations = self.step()
                except SolverError as exc:
                    message = stop_message(
                        exc, load_reach=self.load_reach, omega_max=self.omega_max,
                        dt=self.dt,
                        scales=[profile(self.time + self.dt) for profile in self._profiles])
                    log.error("reduced simulation stopped: %s", message)
                    return recorder.record(stable=False, message=message)
                row = phases[index]
                row[:5] = np.diff(marks[:6])
                row[5] = (marks[6] - marks[0]) - row[:5].sum()
                self.phase_seconds = phases[:index + 1]
                recorder.step(self.time, self.x, interp_seconds=marks[2] - marks[0],
                              total_seconds=marks[6] - marks[0], iterations=iterations)
                if on_step is not None:
                    on_step(index, self.time, self.x)
        return recorder.record()


# ---------------------------------------------------------------- compiled kernels
@njit
def _linear_force(f0, K0, dx, out):
    """out = f0 + K0 dx: the elastic force linearised at the start of the step."""
    n = dx.shape[0]
    for i in range(n):
        value = f0[i]
        for j in range(n):
            value += K0[i, j] * dx[j]
        out[i] = value


@njit
def _kinematics(dx, x, v, a, c, x1, v1, a1):
    """x₁ = x + Δx and the end-of-step a₁, v₁ from the step rates ``c`` =
    ``[c_a/h², k_v/h, k_a, c_v/h, j_v, k_ex]`` (:class:`~lbshape.dynamics.schemes.Scheme`)."""
    for i in range(dx.shape[0]):
        x1[i] = x[i] + dx[i]
        a1[i] = c[0] * dx[i] - c[1] * v[i] - c[2] * a[i]
        v1[i] = c[3] * dx[i] - c[4] * v[i]


@njit
def _end_rates(dx, v, a, c, v1, a1):
    """The end-of-step a₁, v₁ of the increment Δx from the step rates ``c``
    (as :func:`_kinematics`, without x₁)."""
    for i in range(dx.shape[0]):
        a1[i] = c[0] * dx[i] - c[1] * v[i] - c[2] * a[i]
        v1[i] = c[3] * dx[i] - c[4] * v[i]


@njit
def _residual(x1, v1, a1, f, fext, D, S, c, R, norms):
    """R = a₁ + D v₁ + f + k_ex S x₁ − f_ext (M = I, S the example spring) and its norms,
    at the state x₁ with the end-of-step rates v₁, a₁ (:func:`_end_rates`).

    norms: [‖R‖, round-off level of R, ‖f_ext‖, ‖f‖].
    """
    n = x1.shape[0]
    r2 = noise = fe2 = f2 = 0.0
    for i in range(n):
        damping = 0.0
        pull = 0.0
        for j in range(n):
            damping += D[i, j] * v1[j]
            pull += S[i, j] * x1[j]
        spring = f[i] + c[5] * pull
        value = a1[i] + damping + spring - fext[i]
        R[i] = value
        r2 += value * value
        noise += abs(a1[i]) + abs(damping) + abs(spring) + abs(fext[i])
        fe2 += fext[i] * fext[i]
        f2 += f[i] * f[i]
    norms[0] = np.sqrt(r2)
    norms[1] = 64.0 * 2.220446049250313e-16 * noise
    norms[2] = np.sqrt(fe2)
    norms[3] = np.sqrt(f2)


@njit
def _newton_update(base, K, S, c, R, J, dx):
    """dx −= (base + K + k_ex S)⁻¹ R by Cholesky in J; False if J is not positive definite."""
    n = R.shape[0]
    for i in range(n):
        for j in range(i + 1):
            J[i, j] = base[i, j] + 0.5 * (K[i, j] + K[j, i]) + 0.5 * c[5] * (S[i, j] + S[j, i])
    if not cholesky_in_place(J):
        return False
    cholesky_solve_in_place(J, R)
    for i in range(n):
        dx[i] -= R[i]
    return True
