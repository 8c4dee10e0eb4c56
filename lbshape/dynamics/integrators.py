"""Implicit time integration of ``M a + D v + f(x) = f_ext(t)``.

One stepper class serves both the reduced runtime (dense r×r matrices, ``M = I``
in mass-normalised coordinates; nothing n-sized is touched) and the full-space
reference (scipy sparse 3n×3n matrices). The caller supplies:

* ``mass`` M: (N, N) dense ``ndarray`` or scipy sparse matrix; its type selects the
  linear solver (dense: :func:`scipy.linalg.solve`, symmetric ``LDLᵀ`` by default;
  sparse: :func:`scipy.sparse.linalg.splu`);
* ``force_and_tangent(x) -> (f (N,), K (N, N))``: every position-dependent force
  (internal elastic force, example-driven force, contact …) with the sign
  ``f = +∂E/∂x`` and its tangent ``K = ∂f/∂x``;
* ``external(t) -> (N,)``: the applied load at time t (s);
* Rayleigh coefficients: ``D = α M + β K₀``.

**Damping choice.** ``K₀`` is the tangent at rest (``x = 0``), or the matrix the caller
passes as ``damping_stiffness`` (e.g. the elastic tangent without the example term). A
constant ``D`` keeps the damping force linear in ``v``, so the Newton matrix below is exact,
linear mode i is damped with the textbook ratio ``ζ_i = α/(2ω_i) + βω_i/2``, and damping
never turns into an energy source when the current tangent becomes indefinite under large
deformation.

**Schemes.** :data:`~lbshape.dynamics.schemes.SCHEMES` holds each scheme's coefficients once;
every engine reads them from there (this stepper, :mod:`lbshape.dynamics.reduced`,
:mod:`lbshape.dynamics.free_body`). With the displacement increment
``Δx = x_{n+1} − x_n`` unknown:

* ``newmark`` (average acceleration, β = ¼, γ = ½; second order, unconditionally
  stable, no numerical damping; period elongation
  ``T_num/T = ωΔt / (2 atan(ωΔt/2))``):
  ``a_{n+1} = 4/Δt² (Δx − Δt v_n) − a_n``, ``v_{n+1} = 2/Δt Δx − v_n``;
* ``backward-euler`` (first order, L-stable, dissipates):
  ``v_{n+1} = Δx/Δt``, ``a_{n+1} = (v_{n+1} − v_n)/Δt``.

Both solve ``R(Δx) = M a_{n+1} + D v_{n+1} + f(x_{n+1}) − f_ext(t_{n+1}) = 0`` by Newton's
method with the matrix ``c_a M + c_v D + K(x_{n+1})`` (``c_a = 4/Δt², c_v = 2/Δt`` for
Newmark, ``1/Δt², 1/Δt`` for backward Euler), starting from the constant-acceleration
(Newmark) or constant-velocity (backward Euler) predictor. Convergence: ``‖R‖ ≤ max(rtol ·
scale, atol, noise)``, ``scale`` being the largest of ``‖R‖`` at the predictor, ``‖f_ext‖``,
``‖f(x_n)‖``, ``‖f(predictor)‖`` and ``‖M a_n‖`` (the size of the forces in balance in this
step), and ``noise`` the round-off level of evaluating R: ``64 ε`` times the sum of the
magnitudes of its terms (the inertial term ``c_a M Δx ≈ (4/Δt) M v`` grows like 1/Δt, so
with small steps a tight ``rtol`` could otherwise never be met).

**Divergence.** A non-finite force, tangent, residual or Newton update, a Newton iteration
that does not converge, or an energy blow-up raises :class:`~lbshape.errors.SolverError`
naming the step and time; the stepper keeps its last good state so the caller can save what
was computed. Energy blow-up: the total energy ``½ vᵀMv + potential(x)`` exceeds
``energy_factor`` times the energy made available to the system so far, ``budget = E₀ +
W_ext + energy_budget``: ``E₀`` the initial energy (without a supplied potential,
``½|f(x₀)·x₀|`` stands in for the initial potential energy), ``W_ext`` the accumulated
absolute work of the external load (trapezoidal rule) plus what the caller credits between
steps (:meth:`ImplicitStepper.credit_work`: a supplied potential it changes at a fixed
state). A conservative or dissipative system stays below ``budget`` (Newmark conserves the
energy of linear systems exactly); a non-conservative force that feeds energy in (example
forces chasing a moving target, follower forces, fictitious forces) eventually exceeds it.
With a zero budget (starting at rest and unloaded) the monitor is inactive; pass
``energy_budget`` to arm it. ``check_state`` lets the caller refuse a converged state that
is wrong for another reason (an inverted element of a material that forbids inversion)
before it is accepted.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from lbshape.dynamics.kernels import norm as _norm
from lbshape.dynamics.linear_solvers import woodbury_solve
from lbshape.dynamics.sanity import ENERGY_FACTOR
from lbshape.dynamics.schemes import SCHEMES, Scheme, get_scheme
from lbshape.errors import LbshapeError, NewtonFailure, SolverError

log = logging.getLogger(__name__)

Matrix = np.ndarray | sp.spmatrix

#: the contraction ``‖R_new‖ / ‖R‖`` a kept tangent's update must achieve (default)
TANGENT_CONTRACTION = 0.1

ForceAndTangent = Callable[[np.ndarray], tuple[np.ndarray, Matrix]]


@dataclass(frozen=True)
class StepInfo:
    """What one time step did.

    Attributes:
        step: 1-based index of the step just taken.
        time: time at the end of the step (s).
        iterations: Newton iterations (linear solves) used.
        residual: final relative residual ``‖R‖ / scale``.
        residuals: relative residual before each Newton update and at the end,
            ``len == iterations + 1``.
        energy: total energy ``½ vᵀMv + potential(x)`` at the end of the step (J).
    """

    step: int
    time: float
    iterations: int
    residual: float
    residuals: tuple[float, ...]
    energy: float


class ImplicitStepper:
    """Implicit stepper for ``M a + D v + f(x) = f_ext(t)`` (see the module docstring).

    Subclasses fix the scheme: its coefficients (:attr:`scheme`, a :class:`Scheme` of
    :data:`SCHEMES`), :meth:`_predict` and :meth:`kinematics`.

    Args:
        mass: (N, N) symmetric positive definite mass, dense or scipy sparse.
        force_and_tangent: ``x (N,) -> (f (N,), K (N, N))``, K dense or sparse.
        dt: time step (s), > 0.
        x0: (N,) initial displacement (default 0).
        v0: (N,) initial velocity (default 0).
        t0: initial time (s).
        external: ``t -> (N,)`` applied load; ``None`` means none.
        alpha: Rayleigh mass coefficient α (1/s), ≥ 0.
        beta: Rayleigh stiffness coefficient β (s), ≥ 0.
        damping_stiffness: (N, N) ``K₀`` for the damping; default: the tangent of
            ``force_and_tangent`` at ``x = 0`` (evaluated only if β > 0).
        potential: ``x -> float`` potential energy (J) for the energy monitor;
            ``None`` monitors the kinetic energy alone.
        rtol: relative Newton tolerance on ‖R‖.
        atol: absolute Newton tolerance on ‖R‖ (force units).
        max_iterations: Newton iterations per step before giving up.
        energy_factor: blow-up factor of the energy monitor (default
            :data:`~lbshape.dynamics.sanity.ENERGY_FACTOR`); ``None`` disables it.
        energy_budget: absolute energy (J) always considered acceptable.
        symmetric: the Newton matrix is symmetric (dense solves use ``LDLᵀ``);
            set ``False`` for non-symmetric tangents (follower forces).
        line_search: halve a Newton update (down to 1/64) until it lowers ‖R‖ (for
            forces whose residual is steep in a narrow band, as regularised friction
            is below its slip speed); ``False``: full updates.
        low_rank_tangent: returns ``(W, S)`` (n, k) and (k, k), or None,
            after each force evaluation: the Newton matrix is then ``J + W S Wᵀ`` (a
            rank-k correction of the sparse one, e.g. a free body's rigid-invariant
            example pull, whose rigid directions carry no stiffness, or its stiffness
            damping of the deformation only), solved by the Woodbury identity with J's
            factorisation.
        check_state: ``(x₁, step index, t₁) -> None``, called with each converged state
            before it is accepted; raises :class:`~lbshape.errors.SolverError` to refuse it.
        force: ``x (N,) -> f (N,)``, the force of ``force_and_tangent`` alone, or None.
            Given, the residual test reads the force alone and the tangent (with the
            low-rank part) is evaluated only where an update needs it and kept across
            updates and steps while each update contracts ``‖R‖`` by at least
            ``tangent_contraction`` (a modified Newton with the same residual test; a
            slower update re-evaluates the tangent at the next one).
        tangent_contraction: the contraction a kept tangent must achieve (0 < c < 1).
        tangent_each_step: with ``force``: the tangent is evaluated afresh at each step's
            first update and kept within the step only (a non-smooth force: friction,
            contact, a free body's fitted pull); a reused-factor ``linear_solver`` keeps
            its factor, which preconditions the fresh tangents.
        refactor_with_tangent: a tangent evaluated afresh across steps (not
            ``tangent_each_step``) is factorised afresh; ``False``: the reused factor
            stays and preconditions it (a free body's, turned with its frame).
    """

    #: the scheme's coefficients (one of :data:`SCHEMES`)
    scheme: Scheme

    def __init__(
        self,
        mass: Matrix,
        force_and_tangent: ForceAndTangent,
        *,
        dt: float,
        x0: np.ndarray | None = None,
        v0: np.ndarray | None = None,
        t0: float = 0.0,
        external: Callable[[float], np.ndarray] | None = None,
        alpha: float = 0.0,
        beta: float = 0.0,
        damping_stiffness: Matrix | None = None,
        potential: Callable[[np.ndarray], float] | None = None,
        rtol: float = 1e-8,
        atol: float = 0.0,
        max_iterations: int = 20,
        energy_factor: float | None = ENERGY_FACTOR,
        energy_budget: float = 0.0,
        symmetric: bool = True,
        line_search: bool = False,
        low_rank_tangent: Callable[[], tuple[np.ndarray, np.ndarray] | None] | None = None,
        linear_solver: Callable | None = None,
        check_state: Callable[[np.ndarray, int, float], None] | None = None,
        force: Callable[[np.ndarray], np.ndarray] | None = None,
        tangent_contraction: float = TANGENT_CONTRACTION,
        tangent_each_step: bool = False,
        refactor_with_tangent: bool = True,
    ):
        self._sparse = sp.issparse(mass)
        self.mass = _square_matrix(mass, "mass")
        _check_settings(dt=dt, alpha=alpha, beta=beta, energy_budget=energy_budget, rtol=rtol,
                        atol=atol, max_iterations=max_iterations, energy_factor=energy_factor)
        self.n = self.mass.shape[0]
        self.dt = float(dt)
        self._force_and_tangent = force_and_tangent
        self._external = external
        self._potential = potential
        self.rtol, self.atol = float(rtol), float(atol)
        self.max_iterations = int(max_iterations)
        self.energy_factor = energy_factor
        self.energy_budget = float(energy_budget)
        self._assume_a = "sym" if symmetric else "gen"
        self.line_search = bool(line_search)
        self._low_rank_tangent = low_rank_tangent
        self._linear_solver = linear_solver if self._sparse else None
        self.check_state = check_state
        self._force = force
        self.tangent_contraction = float(tangent_contraction)
        self.tangent_each_step = bool(tangent_each_step)
        self.refactor_with_tangent = bool(refactor_with_tangent)
        self._kept = None  # (K, low-rank part) kept for updates (``force`` given)
        self._fresh_tangent = True  # the next update evaluates the tangent
        self.tangent_evaluations = 0

        self._x = self._vector(x0, "x0")
        self._v = self._vector(v0, "v0")
        self._t = float(t0)
        self._steps = 0
        self._setup_damping(alpha, beta, damping_stiffness)
        self._setup_initial_state()

    def _setup_damping(self, alpha: float, beta: float, damping_stiffness: Matrix | None) -> None:
        """``D = α M + β K₀`` and the constant part ``c_a M + c_v D`` of the Newton matrix."""
        damping = alpha * self.mass
        if beta > 0:
            if damping_stiffness is None:
                _, damping_stiffness = self._evaluate(np.zeros(self.n), 0, self._t,
                                                      what="rest tangent")
            damping = damping + beta * self._as_type(damping_stiffness)
        self.damping = damping
        self._alpha, self._beta = float(alpha), float(beta)
        ca, cv = self.scheme.ca / self.dt**2, self.scheme.cv / self.dt
        self._newton_base = ca * self.mass + cv * self.damping
        if self._sparse:
            self._newton_base = sp.csc_matrix(self._newton_base)
        self._mass_norm = _inf_norm(self.mass)
        self._damping_norm = _inf_norm(self.damping)

    def _setup_initial_state(self) -> None:
        """Force, load and acceleration at t0 (``M a₀ = f_ext − D v₀ − f(x₀)``), initial energy."""
        f0, _ = self._evaluate(self._x, 0, self._t, what="initial force")
        self._f = f0
        self._fext = self._load(self._t, 0)
        rhs = self._fext - self.damping @ self._v - f0
        self._a = self._solve_mass(rhs)
        self._energy = self.total_energy()
        if self._potential is None:
            self._initial_energy = self._energy + 0.5 * abs(float(f0 @ self._x))
        else:
            self._initial_energy = abs(self._energy)
        self._work = 0.0

    # ----------------------------------------------------------------- state
    @property
    def x(self) -> np.ndarray:
        """(N,) displacement at :attr:`time` (read-only view)."""
        return _readonly(self._x)

    @property
    def v(self) -> np.ndarray:
        """(N,) velocity at :attr:`time` (read-only view)."""
        return _readonly(self._v)

    @property
    def a(self) -> np.ndarray:
        """(N,) acceleration at :attr:`time` (read-only view)."""
        return _readonly(self._a)

    @property
    def time(self) -> float:
        """Current time (s)."""
        return self._t

    @property
    def steps_taken(self) -> int:
        """Number of successful steps so far."""
        return self._steps

    @property
    def external_work(self) -> float:
        """Accumulated absolute work (J) of the external load (trapezoidal rule) and of
        the changes credited by :meth:`credit_work`."""
        return self._work

    def credit_work(self, joules: float) -> None:
        """Count ``|joules|`` into the energy budget as work done on the system between
        steps: a supplied potential that the caller changes at a fixed state (a moved
        example target) puts that much energy in or takes it out, outside the external
        load's work."""
        if not math.isfinite(joules):
            raise SolverError(f"non-finite work {joules!r} J credited after step {self._steps}")
        self._work += abs(float(joules))

    def kinetic_energy(self, v: np.ndarray | None = None) -> float:
        """``½ vᵀ M v`` (J) of ``v`` (default: the current velocity)."""
        v = self._v if v is None else v
        return 0.5 * float(v @ (self.mass @ v))

    def total_energy(self, x: np.ndarray | None = None, v: np.ndarray | None = None) -> float:
        """Kinetic plus supplied potential energy (J) of a state (default: current)."""
        x = self._x if x is None else x
        kinetic = self.kinetic_energy(v)
        return kinetic if self._potential is None else kinetic + float(self._potential(x))

    # ------------------------------------------------------------------ steps
    def step(self, guess: np.ndarray | None = None) -> StepInfo:
        """Advance one time step; return its :class:`StepInfo`.

        Args:
            guess: (N,) the Newton iteration's first increment ``x₁ − x`` (default: the
                scheme's predictor), e.g. a :meth:`trial_increment` of nearby forces.

        Raises:
            SolverError: non-finite values, Newton failure or energy blow-up; the
                state stays at the end of the previous step.
        """
        index, t1 = self._steps + 1, self._t + self.dt
        fext = self._load(t1, index)
        dx = self._predict() if guess is None else self._vector(guess, "guess")
        state, dx, iteration, residuals = self._converge(dx, fext, index, t1)
        x1, f, _, v1, a1, _, _ = state
        energy = self.total_energy(x1, v1)
        work = self._work + abs(0.5 * float((self._fext + fext) @ dx))
        self._check_energy(energy, work, index, t1)
        if self.check_state is not None:
            self.check_state(x1, index, t1)
        self._x, self._v, self._a, self._f, self._fext = x1, v1, a1, f, fext
        self._t, self._steps, self._work = t1, index, work
        self._energy = energy
        return StepInfo(index, t1, iteration, residuals[-1], tuple(residuals), energy)

    def trial_increment(self, guess: np.ndarray | None = None) -> np.ndarray:
        """(N,) the converged increment ``x₁ − x`` of the next step, without taking it (the
        state stays; a start for :meth:`step` after the forces change a little).

        Raises:
            SolverError: as :meth:`step`'s Newton iteration.
        """
        index, t1 = self._steps + 1, self._t + self.dt
        dx = self._predict() if guess is None else self._vector(guess, "guess")
        return self._converge(dx, self._load(t1, index), index, t1)[1]

    def _converge(self, dx: np.ndarray, fext: np.ndarray, index: int, t1: float):
        """Newton from the increment dx to the residual test: ``(state, dx, iterations,
        relative residuals)``, state as :meth:`_residual` returns it. A modified Newton
        (``force`` given) that does not converge retakes the step by Newton's method
        proper (force and tangent at every iterate, full updates), to the same test."""
        try:
            return self._newton(dx, fext, index, t1)
        except NewtonFailure:
            if self._force is None:
                raise
        force, self._force = self._force, None  # force and tangent at every iterate
        try:
            return self._newton(dx, fext, index, t1)
        finally:
            self._force, self._kept, self._fresh_tangent = force, None, True

    def _newton(self, dx: np.ndarray, fext: np.ndarray, index: int, t1: float):
        """One Newton iteration of :meth:`_converge` (raises :class:`NewtonFailure`)."""
        self._fresh_tangent = self._fresh_tangent or self.tangent_each_step
        base_scale = max(
            _norm(fext), _norm(self._f), _norm(self.mass @ self._a)
        )
        residuals: list[float] = []
        scale = 0.0
        state = self._residual(dx, fext, index, t1, first=True)
        for iteration in range(self.max_iterations + 1):
            x1, f, K, v1, a1, R, norm = state
            if not np.isfinite(norm):
                raise SolverError(f"non-finite residual at step {index} (t = {t1:.6g} s)")
            if iteration == 0:
                scale = max(base_scale, norm, float(_norm(f)))
                if hasattr(self._linear_solver, "newton_tolerance"):  # an inexact solve's goal
                    self._linear_solver.newton_tolerance = max(self.rtol * scale, self.atol)
            relative = norm / scale if scale > 0 else 0.0
            residuals.append(relative)
            if norm <= max(self.rtol * scale, self.atol) or norm <= self._noise(dx, f, fext):
                break
            if iteration == self.max_iterations:
                raise NewtonFailure(
                    f"Newton did not converge at step {index} (t = {t1:.6g} s): relative "
                    f"residual {relative:.3e} after {iteration} iterations (rtol {self.rtol:g})"
                )
            stale = (K is None and self._kept is not None and not self._fresh_tangent
                     and not (iteration == 0 and self.tangent_each_step))  # not just taken
            delta = self._update(x1, K, R, index, t1)
            state = self._residual(dx - delta, fext, index, t1)
            if stale and not state[-1] < norm:  # the kept tangent's update is refused
                self._fresh_tangent = True
                delta = self._update(x1, K, R, index, t1)
                state = self._residual(dx - delta, fext, index, t1)
            # a modified Newton (``force``) halves an update that raises ‖R‖, as the search
            if not (self.line_search or self._force is not None and not state[-1] < norm):
                dx = dx - delta
                self._contracted(state[-1], norm)
                continue
            # backtracking: the last trial is the accepted one
            fraction, trial = 1.0, dx - delta
            while not (state[-1] < norm or fraction <= 1.0 / 64):
                fraction *= 0.5
                trial = dx - fraction * delta
                state = self._residual(trial, fext, index, t1)
            dx = trial
            self._contracted(state[-1], norm)
        return state, dx, iteration, residuals

    def _contracted(self, new: float, old: float) -> None:
        """After an accepted update that took ‖R‖ from ``old`` to ``new``: a kept tangent
        that contracted less than :attr:`tangent_contraction` is evaluated afresh next;
        an inexact linear solver learns the contraction (its solves need not be finer)."""
        self._fresh_tangent = new > self.tangent_contraction * old
        if hasattr(self._linear_solver, "newton_contraction"):
            self._linear_solver.newton_contraction = new / old if old > 0 else 0.0

    def run(self, steps: int) -> list[StepInfo]:
        """Take ``steps`` steps; return their infos (raises like :meth:`step`)."""
        return [self.step() for _ in range(int(steps))]

    def _residual(self, dx: np.ndarray, fext: np.ndarray, index: int, t1: float, *,
                  first: bool = False):
        """``(x₁, f, K, v₁, a₁, R, ‖R‖)`` of the increment ``dx`` (the step's residual
        ``R = M a₁ + D v₁ + f(x₁) − f_ext``); the step's ``first`` residual with
        ``tangent_each_step`` evaluates the tangent with the force and keeps it."""
        x1 = self._x + dx
        if first and self._force is not None and self.tangent_each_step:
            f, tangent = self._evaluate(x1, index, t1)
            self._keep(tangent)
            K = None
        elif self._force is not None:  # the tangent where an update needs it (_update)
            f, K = np.asarray(self._force(x1), dtype=float).reshape(-1), None
            if f.shape != (self.n,) or not np.isfinite(f).all():
                raise SolverError(f"non-finite force at step {index} (t = {t1:.6g} s)")
        else:
            f, K = self._evaluate(x1, index, t1)
        v1, a1 = self.kinematics(dx)
        R = self.mass @ a1 + self.damping @ v1 + f - fext
        return x1, f, K, v1, a1, R, float(_norm(R))

    # ------------------------------------------------------- scheme specifics
    def _predict(self) -> np.ndarray:
        raise NotImplementedError

    def kinematics(self, dx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(v₁, a₁)`` at the end of a step of displacement increment ``dx`` from the
        current state (the scheme's kinematics, :class:`Scheme`)."""
        raise NotImplementedError

    # --------------------------------------------------------------- helpers
    def _vector(self, value, name: str) -> np.ndarray:
        if value is None:
            return np.zeros(self.n)
        out = np.array(value, dtype=float).reshape(-1)
        if out.shape != (self.n,) or not np.isfinite(out).all():
            raise LbshapeError(f"{name} must be a finite vector of length {self.n}")
        return out

    def _as_type(self, matrix: Matrix) -> Matrix:
        if self._sparse:
            return matrix if sp.issparse(matrix) else sp.csr_matrix(np.asarray(matrix))
        return matrix.toarray() if sp.issparse(matrix) else np.asarray(matrix, dtype=float)

    def _load(self, t: float, index: int) -> np.ndarray:
        if self._external is None:
            return np.zeros(self.n)
        load = np.asarray(self._external(t), dtype=float).reshape(-1)
        if load.shape != (self.n,):
            raise LbshapeError(f"external(t) must return a vector of length {self.n}")
        if not np.isfinite(load).all():
            raise SolverError(f"non-finite external load at step {index} (t = {t:.6g} s)")
        return load

    def _evaluate(self, x: np.ndarray, index: int, t: float, *, what: str = "force"):
        f, K = self._force_and_tangent(x)
        f = np.asarray(f, dtype=float).reshape(-1)
        if f.shape != (self.n,) or K.shape != (self.n, self.n):
            raise LbshapeError(
                f"force_and_tangent must return f ({self.n},) and K ({self.n}, {self.n}), "
                f"got {f.shape} and {K.shape}"
            )
        K = self._as_type(K)
        finite = np.isfinite(K.data).all() if self._sparse else np.isfinite(K).all()
        if not (np.isfinite(f).all() and finite):
            raise SolverError(f"non-finite {what} or tangent at step {index} (t = {t:.6g} s)")
        return f, K

    def forget_factor(self) -> None:
        """The next solve factorises its Newton matrix afresh (a reused-factor linear
        solver; others keep none)."""
        if hasattr(self._linear_solver, "reset"):
            self._linear_solver.reset()

    def forget_tangent(self) -> None:
        """The next update evaluates the tangent (``force`` given; the forces changed)."""
        self._kept, self._fresh_tangent = None, True

    def turn_kept_tangent(self, turn: Callable) -> None:
        """Carry the kept tangent along a rigid turn of the state: ``turn(K, low-rank
        part or None) -> (K, low-rank part)`` turned, or None (none kept: nothing to do)."""
        if self._kept is not None:  # None from turn: evaluated afresh at the next update
            self._kept = turn(*self._kept)
            self._fresh_tangent = self._fresh_tangent or self._kept is None

    def kept_tangent(self) -> dict[str, np.ndarray]:
        """The kept tangent (sparse) and its low-rank part as arrays (empty: none)."""
        if self._kept is None or not sp.issparse(self._kept[0]):
            return {}
        K = sp.csr_matrix(self._kept[0])
        out = {"data": K.data, "indices": K.indices, "indptr": K.indptr,
               "fresh": np.array(self._fresh_tangent)}
        if self._kept[1] is not None:
            out["W"], out["S"] = self._kept[1]
        return out

    def restore_tangent(self, arrays: dict[str, np.ndarray]) -> None:
        """Keep the tangent of :meth:`kept_tangent`'s arrays (empty: forget it); a reused
        factor is then taken afresh of it, as when it was evaluated."""
        self.forget_tangent()
        if not arrays:
            return
        K = sp.csr_matrix((arrays["data"].copy(), arrays["indices"].copy(),
                           arrays["indptr"].copy()), shape=(self.n, self.n))
        low_rank = (arrays["W"].copy(), arrays["S"].copy()) if "W" in arrays else None
        self._kept, self._fresh_tangent = (K, low_rank), bool(arrays["fresh"])
        self.forget_factor()

    def _update(self, x1: np.ndarray, K: Matrix | None, R: np.ndarray, index: int,
                t: float) -> np.ndarray:
        """The Newton update δ of R at x₁: with K (the iterate's tangent), or with the kept
        tangent (``force`` given), evaluated at x₁ first when :attr:`_fresh_tangent`."""
        if K is not None:
            return self._solve_newton(K, R, index, t)
        if self._kept is None or self._fresh_tangent:
            if not self.tangent_each_step and self.refactor_with_tangent:
                self.forget_factor()  # a reused factor: of this tangent's matrix
            self._keep(self._evaluate(x1, index, t)[1])
        return self._solve_newton(self._kept[0], R, index, t, self._kept[1])

    def _keep(self, tangent: Matrix) -> None:
        """Keep a tangent just evaluated, with its low-rank part, for the updates."""
        self.tangent_evaluations += 1
        low_rank = self._low_rank_tangent() if self._low_rank_tangent is not None else None
        self._kept, self._fresh_tangent = (tangent, low_rank), False

    def _solve_newton(self, K: Matrix, R: np.ndarray, index: int, t: float,
                      low_rank=False) -> np.ndarray:
        correction = low_rank if low_rank is not False else (
            self._low_rank_tangent() if self._low_rank_tangent is not None else None)
        try:
            if self._linear_solver is not None:
                delta = self._linear_solver(self._newton_base, K, R, correction)
            else:
                delta = woodbury_solve(self._direct_solver(self._newton_base + K), R,
                                       correction)
        except (sla.LinAlgError, np.linalg.LinAlgError, RuntimeError) as exc:
            raise SolverError(
                f"singular Newton matrix at step {index} (t = {t:.6g} s): {exc}"
            ) from None
        if not np.isfinite(delta).all():
            raise SolverError(f"non-finite Newton update at step {index} (t = {t:.6g} s)")
        return delta

    def _direct_solver(self, J: Matrix):
        """``J⁻¹`` applied to (n,) or (n, k) arrays: one SuperLU factorisation (sparse) or a
        dense solve."""
        if self._sparse:
            return spla.splu(sp.csc_matrix(J)).solve

        def solve(rhs):
            return sla.solve(J, rhs, assume_a=self._assume_a, check_finite=False)

        return solve

    def _solve_mass(self, rhs: np.ndarray) -> np.ndarray:
        try:
            if self._sparse:
                out = spla.splu(sp.csc_matrix(self.mass)).solve(rhs)
            else:
                out = sla.solve(self.mass, rhs, assume_a="pos", check_finite=False)
        except (sla.LinAlgError, RuntimeError) as exc:
            raise LbshapeError(f"mass matrix is not positive definite: {exc}") from None
        if not np.isfinite(out).all():
            raise SolverError(f"non-finite initial acceleration (t = {self._t:.6g} s)")
        return out

    def _noise(self, dx: np.ndarray, f: np.ndarray, fext: np.ndarray) -> float:
        """Round-off level (force units, 2-norm) of evaluating the residual."""
        h, norm = self.dt, _norm
        ca, cv = self.scheme.ca, self.scheme.cv
        inertia = self._mass_norm * (ca / h**2 * norm(dx) + ca / h * norm(self._v) + norm(self._a))
        damping = self._damping_norm * (cv / h * norm(dx) + norm(self._v))
        return 64.0 * np.finfo(float).eps * float(inertia + damping + norm(f) + norm(fext))

    def _check_energy(self, energy: float, work: float, index: int, t: float) -> None:
        if not np.isfinite(energy):
            raise SolverError(f"non-finite energy at step {index} (t = {t:.6g} s)")
        if self.energy_factor is None:
            return
        budget = self._initial_energy + work + self.energy_budget
        if budget > 0 and energy > self.energy_factor * budget:
            raise SolverError(
                f"energy blew up at step {index} (t = {t:.6g} s): {energy:.3e} J exceeds "
                f"{self.energy_factor:g} x budget {budget:.3e} J"
            )


class NewmarkStepper(ImplicitStepper):
    """Average-acceleration Newmark (β = ¼, γ = ½); see :class:`ImplicitStepper`."""

    scheme = SCHEMES["newmark"]

    def _predict(self) -> np.ndarray:
        # constant-acceleration predictor: h v + ½ k_a h² a
        return self.dt * self._v + 0.5 * self.scheme.ka * self.dt**2 * self._a

    def kinematics(self, dx):
        # second order: a₁ = c_a/h² (Δx − h v) − a, v₁ = c_v/h Δx − v (k_a = j_v = 1)
        h, c = self.dt, self.scheme
        a1 = (c.ca / h**2) * (dx - h * self._v) - self._a
        v1 = (c.cv / h) * dx - self._v
        return v1, a1


class BackwardEulerStepper(ImplicitStepper):
    """Backward (implicit) Euler; see :class:`ImplicitStepper`."""

    scheme = SCHEMES["backward-euler"]

    def _predict(self) -> np.ndarray:
        # constant-velocity predictor: h v (k_a = 0)
        return self.dt * self._v

    def kinematics(self, dx):
        # first order: the difference quotients
        v1 = dx / self.dt
        a1 = (v1 - self._v) / self.dt
        return v1, a1


_STEPPERS: dict[str, type[ImplicitStepper]] = {
    stepper.scheme.name: stepper for stepper in (NewmarkStepper, BackwardEulerStepper)
}
assert set(_STEPPERS) == set(SCHEMES)


def make_stepper(
    integrator: str, mass: Matrix, force_and_tangent: ForceAndTangent, **options
) -> ImplicitStepper:
    """The stepper named ``integrator`` (one of :data:`INTEGRATORS`).

    ``options`` are the keyword arguments of :class:`ImplicitStepper`.
    """
    return _STEPPERS[get_scheme(integrator).name](mass, force_and_tangent, **options)


def _check_settings(*, dt, alpha, beta, energy_budget, rtol, atol, max_iterations,
                    energy_factor) -> None:
    """Raise :class:`LbshapeError` for a step, damping or tolerance setting out of range."""
    if not (np.isfinite(dt) and dt > 0):
        raise LbshapeError(f"time step dt must be > 0 s, got {dt}")
    for name, value in (("alpha", alpha), ("beta", beta), ("energy_budget", energy_budget)):
        if not (np.isfinite(value) and value >= 0):
            raise LbshapeError(f"{name} must be a finite number >= 0, got {value}")
    if not rtol > 0 or atol < 0:
        raise LbshapeError(f"Newton tolerances must be rtol > 0, atol >= 0, got {rtol}, {atol}")
    if int(max_iterations) < 1:
        raise LbshapeError(f"max_iterations must be >= 1, got {max_iterations}")
    if energy_factor is not None and not energy_factor > 1:
        raise LbshapeError(f"energy_factor must be > 1 or None, got {energy_factor}")


def _square_matrix(matrix: Matrix, name: str) -> Matrix:
    """A non-empty square matrix as CSR (sparse input) or a float ndarray (dense input)."""
    if not sp.issparse(matrix):
        matrix = np.asarray(matrix, dtype=float)
    if matrix.ndim != 2 or matrix.shape[0] != matrix.shape[1] or matrix.shape[0] == 0:
        raise LbshapeError(f"{name} must be a non-empty square matrix, got shape {matrix.shape}")
    return matrix.tocsr() if sp.issparse(matrix) else matrix


def _inf_norm(matrix: Matrix) -> float:
    """Maximum absolute row sum."""
    return float(abs(matrix).sum(axis=1).max())


def _readonly(array: np.ndarray) -> np.ndarray:
    view = array.view()
    view.flags.writeable = False
    return view
