"""Full-space FEM reference simulation with full-space example interpolation (``full``).

The accuracy reference of every speed claim: no reduced basis, no cubature. On the
free dofs x (fixed vertices eliminated; u is zero on them), with the consistent
mass M (3n × 3n, kg) and the elastic internal force ``f_int = +∂E/∂u`` of all
elements (:class:`~lbshape.elastic.element_kernels.FullSpaceElasticity`):

``M ü + D u̇ + f_int(u) = f_ext(t) + f_ex``,  ``D = α M + β K₀``,
``f_ext(t) = Σ_i profile_i(t) pattern_i``,

K₀ the elastic tangent at rest, integrated by :mod:`lbshape.dynamics.integrators` (sparse
Newton systems, the same stepper as the reduced runtime).

**Example force.** Once per step, from the displacement u (n, 3) at the start of
the step (explicit in the target, implicit in u — as the reduced method does):

1. LB displacement coefficients ``c = Φᵀ M₁ u`` (m, 3), Φ (n, m) the object's
   eigenvectors, M₁ the scalar (volume) P1 mass; descriptor ``d = λ ⊙ c``
   flattened row-major to (3m,) (``d[3 i + comp]``);
2. weights ``w = simplex_weights(example descriptors (k, 3m), d)``;
3. target coefficients ``c* = argmin_c Σ_k w_k E_k(c − c_k)``, with ``E_k`` the
   energy of example k's rest shape ``X_k = X + Φ c_k`` deformed by ``L (c − c_k)``
   over all elements but those an example's reconstruction squeezes
   (:func:`lbshape.shapespace.example_shapes.energy_elements`, as in every route;
   :class:`~lbshape.shapespace.euclidean_energy.EuclideanExampleEnergy`),
   ``L = Φ ⊗ I₃`` (3n, 3m), solved by :class:`~lbshape.shapespace.interpolation.TargetSolver`
   (warm-started from the previous step; the fast path: the modified Newton of
   :class:`~lbshape.shapespace.reused_hessian.ReusedHessianTargetSolver`, same target);
4. target displacement ``u* = L c*`` and force ``f_ex = k_ex M (u* − u)``, k_ex in
   1/s². In a mass-orthonormal reduced basis U (``Uᵀ M U = I``) this projects to
   the reduced method's ``k_ex (q* − q)`` with ``q* = Uᵀ M L c*``.

In the stepper the example force is split into a spring ``k_ex M_ff x`` (part of the
position-dependent force, tangent ``k_ex M_ff``, potential ``½ k_ex xᵀ M_ff x``) and
the pull ``k_ex (M u*)_free``, constant during the step, applied as an external load.
**Local examples** (:class:`~lbshape.shapespace.local_full_force.FullSpaceLocalForce`):
per region R the same steps on the region's own eigenfunctions and elements; the
spring uses ``S = Σ_R M^(R)`` (mass of the covered elements) instead of M and the
pull is ``k_ex Σ_R M^(R) E_R L_R c*_R``.

The two nearly cancel close to the target, so keeping the pull among the loads
lets the Newton convergence test measure the residual against the size of the
example force rather than against their (vanishing) difference. With ``k_ex = 0``
or no examples none of this machinery is built or called.

**Free bodies and contact.** Without fixed vertices the same equations are
integrated in the inertial frame directly (u is the world displacement ``x − X``;
the StVK and Neo-Hookean forces are invariant under rigid rotation, so there is no
frame split and no fictitious force). Contact planes act on the surface vertices
with the penalty force ``k d n`` of :mod:`lbshape.dynamics.contact` (``d`` the
penetration), part of the position-dependent force with its tangent
``k n nᵀ`` per penetrating vertex, and with the planes' regularised Coulomb friction
on the vertex velocity, taken at the scheme's end-of-step velocity ``v₁(x)`` (linear
in x) inside the Newton iteration with its consistent tangent (fully implicit; the
sparse LU solves the non-symmetric system). The slip direction turns within ε of the
slip speed, where a full Newton update overshoots: with friction Newton halves an update
until it lowers the residual (``line_search``) and may take up to
:data:`FRICTION_NEWTON_ITERATIONS` iterations. For a free body the stiffness damping is
co-rotated, ``β Q K₀ Qᵀ`` with Q the best rigid frame's rotation at the start of each
step, so that it does not damp the rigid motion; ``α M`` would still damp it (the
reduced method damps only the deformation): free scenes use ``α = 0``.

For a free body the steps above run in the best-fitting rigid frame of the current
shape (mass-weighted centre and polar-decomposition rotation): see
:meth:`FullSpaceSimulator._update_free_target`.

**A user's drag** (:meth:`FullSpaceSimulator.set_drag`): a spring ``k (x_target − x_i)``
on one vertex, split as the reduced engine splits it (:mod:`lbshape.dynamics.drag`) into a
spring ``k u_i`` (implicit: tangent ``k I₃`` on the vertex's free dofs, energy ``½ k |u_i|²``
part of the potential) and the pull ``k (x_target − X_i)`` among the external loads, so
that Newton's residual is measured against the pull, not against the vanishing difference
of the drag and the elastic force at rest.

**Failure** (:mod:`lbshape.dynamics.sanity`). A non-finite state, a Newton failure, an
energy blow-up, a failed target solve or, for a material that forbids inversion, an
inverted element (det F ≤ 0 on any element of the accepted state) raises a
:class:`~lbshape.errors.SolverError` from :meth:`FullSpaceSimulator.step` naming the step
and time; :meth:`FullSpaceSimulator.run` returns the record of what was computed with
``stable=False`` and the message with its likely cause (a load far beyond what the object
carries, or a step coarse against ``omega_max``). How far the object moves never stops it.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp

from lbshape.dynamics.engine import (
    Drag,
    EngineState,
    NewtonSettings,
    OnStep,
    check_run,
    snapshot,
)
from lbshape.dynamics.example_ramp import check_ramp, ramp_factor
from lbshape.dynamics.free_dofs import CsrRestriction, submatrix, vertex_indices
from lbshape.dynamics.full_contact import FullSpaceContact, step_with_slip_continuation
from lbshape.dynamics.full_damping import FullSpaceDamping
from lbshape.dynamics.full_examples import FullSpaceExampleForce, FullSpaceExamples
from lbshape.dynamics.integrators import make_stepper
from lbshape.dynamics.linear_solvers import CONTRACTION_CAP, LINEAR_SOLVERS, make_linear_solver
from lbshape.dynamics.loads import TimedLoad, TimeProfile
from lbshape.dynamics.record import RunRecord, RunRecorder
from lbshape.dynamics.sanity import (
    forbids_inversion,
    inverted_message,
    step_warnings,
    stop_message,
)
from lbshape.elastic.assembly import CompiledElasticity
from lbshape.elastic.element_kernels import FullSpaceElasticity, mass_matrix
from lbshape.elastic.materials import Material
from lbshape.errors import LbshapeError, SolverError
from lbshape.geometry.mesh import TetMesh, free_dof_mask
from lbshape.shapespace.local_full_force import FullSpaceLocalForce

log = logging.getLogger(__name__)

#: Newton iterations per step allowed (at least) when a plane has friction, whose Newton
#: runs with a line search: the regularised friction is steep within its slip speed, and
#: the car's wall impact took up to 23 iterations (2.6 per step on average)
FRICTION_NEWTON_ITERATIONS = 60
#: the full engine's default Newton settings (converged: the accuracy reference)
FULL_NEWTON = NewtonSettings(1e-8, 20)


class FullSpaceSimulator(FullSpaceExampleForce, FullSpaceDamping):
    """Implicit full-space FEM dynamics with the full-space example force.

    Args:
        mesh: the object's rest mesh (n vertices, t tets).
        material: its hyperelastic material (density ρ sets the mass).
        dt: time step in s, > 0.
        fixed_vertices: (f,) indices of vertices held at zero displacement.
        integrator: ``"newmark"`` or ``"backward-euler"``.
        alpha: Rayleigh mass coefficient α in 1/s.
        beta: Rayleigh stiffness coefficient β in s (K₀: elastic tangent at rest).
        loads: external loads (patterns (3n,) N with time profiles).
        examples: shape-space arrays and k_ex; ``None`` (or k_ex = 0, or no
            example) means no example force.
        local_examples: ``(force, k_ex)``: the local example force (regions) and
            its stiffness in 1/s², instead of ``examples``.
        initial_displacement: (n, 3) m, zero on fixed vertices (default 0).
        initial_velocity: (n, 3) m/s, zero on fixed vertices (default 0).
        target_tolerance: relative gradient tolerance of the target solve.
        newton: the :class:`~lbshape.dynamics.engine.NewtonSettings` of the time step
            (default :data:`FULL_NEWTON`: rtol 1e-8, 20 iterations; with friction or a free
            body's fitted example pull at least :data:`FRICTION_NEWTON_ITERATIONS`).
        contact: penalty contact with planes, or ``None``.
        example_ramp: T in s of ``k_ex(t) = k_ex s(min(1, t/T))`` in the pull and its
            tangent (:mod:`lbshape.dynamics.example_ramp`); 0 (default): k_ex from t = 0.
        linear_solver: ``"reuse"``: compiled assembly
            (:class:`~lbshape.elastic.assembly.CompiledElasticity`), one sparse
            factorisation reused across Newton iterations and steps
            (:class:`~lbshape.dynamics.linear_solvers.ReusedFactorSolver`) and the compiled
            block evaluation of the example target; a modified Newton (the residual test on
            :meth:`_force` alone, the tangent kept while each update lowers ‖R‖ ten-fold:
            the stepper's ``force`` option), across steps with its factor where the force is
            smooth, else evaluated afresh at each step's first update (contact, friction, a
            fitted pull); updates solved to a tenth of the Newton tolerance (an inexact
            Newton); ``"lu-each-iteration"``: the former
            path (numpy assembly, a SuperLU factorisation per Newton iteration), for
            comparison runs. Same answers to round-off and the Newton tolerance.
        omega_max: the highest vibration frequency (rad/s) of the object's modes the
            reduced basis holds, for the coarse-step warning (:attr:`warnings`) and the
            failure advice; or ``None``.
        load_reach: ``() -> LoadReach | None`` for the failure advice (loads in order,
            evaluated only once a run stopped), or ``None``.

    Attributes:
        free_dofs: (nf,) node-major indices of the free dofs (x = u[free_dofs]).
        elastic: the :class:`~lbshape.elastic.element_kernels.FullSpaceElasticity` of the mesh.
        mass: (3n, 3n) consistent mass in kg (CSR).
        stepper: the :mod:`lbshape.dynamics.integrators` stepper on the free dofs.
        warnings: one-line set-up warnings (a coarse step), logged once when built.
        weights: (k,) example weights of the last step (``None`` before / without).
        target_coefficients: (3m,) target LB coefficients c* of the last step.

    Raises:
        LbshapeError: inconsistent shapes, indices out of range, every vertex fixed,
            negative α, β or k_ex, or an initial state that moves a fixed vertex.
    """

    #: no timed parts of a step (the protocol's phase names)
    phases: tuple[str, ...] = ()

    def __init__(
        self,
        mesh: TetMesh,
        material: Material,
        *,
        dt: float,
        fixed_vertices: Sequence[int] | np.ndarray = (),
        integrator: str = "newmark",
        alpha: float = 0.0,
        beta: float = 0.0,
        loads: Sequence[TimedLoad] = (),
        examples: FullSpaceExamples | None = None,
        local_examples: tuple[FullSpaceLocalForce, float] | None = None,
        initial_displacement: np.ndarray | None = None,
        initial_velocity: np.ndarray | None = None,
        target_tolerance: float = 1e-6,
        newton: NewtonSettings = FULL_NEWTON,
        contact: FullSpaceContact | None = None,
        example_ramp: float = 0.0,
        linear_solver: str = "reuse",
        omega_max: float | None = None,
        load_reach=None,
    ):
        if linear_solver not in LINEAR_SOLVERS:
            raise LbshapeError(f"linear_solver must be one of {LINEAR_SOLVERS}, "
                               f"got {linear_solver!r}")
        self._fast = linear_solver == "reuse"
        self._linear_solver = linear_solver
        n = mesh.n_vertices
        self.omega_max, self.load_reach = omega_max, load_reach
        self._inversion = forbids_inversion(material.model)  # det F <= 0 stops the run
        self.warnings = step_warnings(omega_max, float(dt), log)
        self.newton, self.dt = newton, float(dt)
        self.contact = contact
        self._drag: Drag | None = None
        self.mesh, self.material = mesh, material
        self.n_vertices = n
        fixed = vertex_indices(fixed_vertices, n)
        free_mask = free_dof_mask(n, fixed)
        if not free_mask.any():
            raise LbshapeError("every vertex is fixed: nothing to simulate")
        self.fixed_vertices = fixed
        self.free_dofs = np.flatnonzero(free_mask)
        self._free_mask = free_mask

        self.elastic = FullSpaceElasticity(mesh, material)
        self._compiled = (CompiledElasticity(mesh, material, self.free_dofs) if self._fast
                          else None)
        self.mass = mass_matrix(mesh, material.density)
        self._mass_ff = submatrix(self.mass, self.free_dofs)
        K0 = self.elastic.tangent(np.zeros(3 * n))
        self._restrict = CsrRestriction(K0, self.free_dofs)
        K0_ff = self._restrict(K0)

        self._load_patterns, self._load_profiles = self._check_loads(loads)
        self._setup_examples(examples, tolerance=target_tolerance)
        self._local = None
        if local_examples is not None and local_examples[1] > 0:
            if self._k_ex:
                raise LbshapeError("give global or local examples, not both")
            self._local, self._k_ex = local_examples[0], float(local_examples[1])
            self._spring_ff = submatrix(self._local.mass, self.free_dofs)

        x0 = self._initial(initial_displacement, "initial_displacement")
        v0 = self._initial(initial_velocity, "initial_velocity")
        self._v_start = v0  # the friction's velocity while the stepper is set up
        self._make_stepper(integrator, x0, v0, alpha, beta, K0_ff)
        self._configured_k_ex = self._k_ex  # the example force set_examples switches
        self.example_ramp, self._examples_on = check_ramp(example_ramp), True
        if self.example_ramp:
            self._ramp_examples(0.0)
        self._marks = np.zeros(3)  # start, after the target, end of the last step (s)
        self._initial_state = self.state

    def _make_stepper(self, integrator: str, x0, v0, alpha: float, beta: float,
                      K0_ff: sp.csr_matrix) -> None:
        """The :mod:`lbshape.dynamics.integrators` stepper on the free dofs."""
        # free body: the stiffness damping follows the body's rotation (see _corotate)
        free_body = self.fixed_vertices.size == 0
        self._corotated_beta = float(beta) if (free_body and beta > 0) else 0.0
        self._damping_rest = self._damping_now = K0_ff if self._corotated_beta else None
        self._damping_data = None  # β Q K₀ Qᵀ on the compiled pattern (_corotate, lazily)
        self._tangent_across_flight = bool(self._fast and self._corotated_beta)
        self._tangent_frame = None  # the frame the kept tangent is turned to
        if self._corotated_beta:
            beta = 0.0
        fitted_pull = bool(self._k_ex and free_body and self._local is None)  # see _free_gap
        rigid_fit = bool(fitted_pull or self._corotated_beta)  # both fit the rigid frame
        if rigid_fit:
            self._init_rigid_fit()
        friction = self.contact is not None and self.contact.has_friction
        newton = self.newton
        #: the stepper's least Newton iterations (a line search's steps may need more)
        self._newton_floor = FRICTION_NEWTON_ITERATIONS if friction or fitted_pull else 0
        self.stepper = make_stepper(
            integrator,
            self._mass_ff,
            self._force_and_tangent,
            dt=self.dt,
            x0=x0,
            v0=v0,
            external=self._external,
            alpha=alpha,
            beta=beta,
            damping_stiffness=K0_ff,
            potential=self._potential,
            rtol=newton.rtol,
            atol=self._free_pull_round_off() if fitted_pull else 0.0,
            max_iterations=max(newton.max_iterations, self._newton_floor),
            line_search=friction or fitted_pull,
            low_rank_tangent=self._tangent_correction if rigid_fit else None,
            linear_solver=(make_linear_solver(self._linear_solver, symmetric=not friction)
                           if self._fast else None),
            check_state=self._check_inversion if self._inversion else None,
            # a modified Newton across steps where the updates are full ones and smooth (no
            # contact: a kept tangent across a changing contact set settled a sagging bar
            # 2.7 mm lower; no friction, no fitted pull: it slowed the car's Newton), else
            # the tangent afresh at each step's first update, kept within the step
            force=self._force if self._fast else None,
            tangent_each_step=self.contact is not None or friction or fitted_pull,
            # a free body's tangent and factor turned with it in flight (_turn_kept_tangent)
            refactor_with_tangent=not self._tangent_across_flight,
        )
        if self._tangent_across_flight:  # its updates solved to the Newton contraction
            self.stepper._linear_solver.contraction_cap = CONTRACTION_CAP

    def _check_inversion(self, x: np.ndarray, index: int, t: float) -> None:
        """Refuse a state x (free dofs) with an inverted element (det F ≤ 0)."""
        u = self.full_displacement(x)[self.mesh.tets]
        jacobians = self.elastic.kernel.jacobians(u)
        worst = int(np.argmin(jacobians))
        if not jacobians[worst] > 0.0:
            raise SolverError(inverted_message(index, t, float(jacobians[worst]),
                                               f"element {worst}"))

    # ----------------------------------------------------------------- set-up
    def _check_loads(self, loads: Sequence[TimedLoad]):
        patterns, profiles = [], []
        for index, load in enumerate(loads):
            pattern = np.asarray(load.pattern, dtype=float).reshape(-1)
            if pattern.shape != (3 * self.n_vertices,):
                raise LbshapeError(
                    f"load {index}: pattern must have shape ({3 * self.n_vertices},), "
                    f"got {np.shape(load.pattern)}"
                )
            if not np.isfinite(pattern).all():
                raise LbshapeError(f"load {index}: pattern contains NaN or infinite forces")
            if not isinstance(load.profile, TimeProfile):
                raise LbshapeError(f"load {index}: profile must be a TimeProfile")
            patterns.append(pattern[self.free_dofs])
            profiles.append(load.profile)
        stacked = np.array(patterns) if patterns else np.zeros((0, self.free_dofs.size))
        return stacked, profiles

    def _initial(self, value: np.ndarray | None, name: str) -> np.ndarray | None:
        if value is None:
            return None
        u = np.asarray(value, dtype=float)
        if u.shape != (self.n_vertices, 3) or not np.isfinite(u).all():
            raise LbshapeError(f"{name} must be a finite ({self.n_vertices}, 3) array")
        if np.any(u.reshape(-1)[~self._free_mask] != 0.0):
            raise LbshapeError(f"{name} must be zero on the fixed vertices")
        return u.reshape(-1)[self.free_dofs]

    # ---------------------------------------------------------------- state
    @property
    def newton(self) -> NewtonSettings:
        """The step's Newton settings (assigning new ones changes the stepper's; with
        friction or a free body's fitted pull at least :data:`FRICTION_NEWTON_ITERATIONS`
        iterations)."""
        return self._newton

    @newton.setter
    def newton(self, settings: NewtonSettings) -> None:
        self._newton = settings
        stepper = getattr(self, "stepper", None)
        if stepper is not None:
            stepper.rtol = settings.rtol
            stepper.max_iterations = max(settings.max_iterations, self._newton_floor)

    @property
    def uses_examples(self) -> bool:
        """True when the example force is active (k_ex > 0 and at least one example)."""
        return self._k_ex > 0.0 or (self._examples_on and self._configured_k_ex > 0.0)

    @property
    def time(self) -> float:
        """Current time in s."""
        return self.stepper.time

    def full_displacement(self, x: np.ndarray | None = None) -> np.ndarray:
        """(n, 3) displacement in m of free dofs x (default: the current state)."""
        u = np.zeros(3 * self.n_vertices)
        u[self.free_dofs] = self.stepper.x if x is None else x
        return u.reshape(-1, 3)

    def displacement(self) -> np.ndarray:
        """(n, 3) world displacement ``x − X`` of every vertex (m), zero on fixed ones."""
        return self.full_displacement()

    def displacements(self, record: RunRecord) -> np.ndarray:
        """(f, n, 3) the world displacements (m) of a record of this engine."""
        return record.displacements()

    # ------------------------------------------------------------ switches
    def set_examples(self, on: bool) -> bool:
        """The configured example force (global or local) on or off from the next step on;
        returns whether it acts. The example spring's energy the switch adds or removes at
        the current state counts as work for the energy monitor."""
        k_ex = self._configured_k_ex if on else 0.0
        self._examples_on = bool(on)
        if k_ex != self._k_ex:
            x = self.stepper.x
            before = self._example_energy(x)
            self._k_ex = k_ex
            self._pull_rigid = None  # the fitted pull's tangent part, of the last evaluation
            self.stepper.credit_work(self._example_energy(x) - before)
            self.stepper.forget_tangent()
        return self.uses_examples

    def set_drag(self, drag: Drag | None) -> None:
        """A user's point pull from the next step on (``None``: released): the spring
        ``k (x_target − x_i)`` on vertex i's free dofs, implicit (tangent ``k I₃``; see the
        module docstring). The spring's energy the change adds or removes at the current
        state counts as work for the energy monitor."""
        x = self.stepper.x
        before = self._drag_energy(x)
        if drag is not None:
            vertex = drag.vertex
            if not 0 <= vertex < self.n_vertices:
                raise LbshapeError(f"vertex must be an index from 0 to "
                                   f"{self.n_vertices - 1}, got {vertex}")
            dofs = 3 * vertex + np.arange(3)
            free = self._free_mask[dofs]
            self._drag_dofs = np.searchsorted(self.free_dofs, dofs[free])
            self._drag_pull = drag.stiffness * (drag.target - self.mesh.points[vertex])[free]
            size = self.free_dofs.size
            self._drag_tangent = sp.csr_matrix(
                (np.full(self._drag_dofs.size, drag.stiffness),
                 (self._drag_dofs, self._drag_dofs)), shape=(size, size))
        self._drag = drag
        self.stepper.credit_work(self._drag_energy(x) - before)
        self.stepper.forget_tangent()

    # --------------------------------------------------------------- state
    #: the engine's caches of the step that are replaced (not changed in place) and may
    #: be absent (None)
    _CACHES = ("_b", "weights", "target_coefficients", "_target_body", "_target_center",
               "_pull_rigid", "_tangent_frame")
    _STEPPER_ARRAYS = ("_x", "_v", "_a", "_f", "_fext")
    _STEPPER_SCALARS = ("_t", "_steps", "_work", "_energy", "_initial_energy")

    def _target_solvers(self) -> list:
        """The example target solvers (their warm starts are part of the state)."""
        if self._local is not None:
            return [region[3] for region in self._local._regions]
        solver = getattr(self, "_target_solver", None)
        return [] if solver is None else [solver]

    @property
    def state(self) -> EngineState:
        """A snapshot (copies) of the stepper's state and the step's caches (the example
        targets' warm starts included)."""
        stepper = self.stepper
        arrays = {name: getattr(stepper, name) for name in self._STEPPER_ARRAYS}
        for name in self._CACHES:
            value = getattr(self, name, None)
            if value is not None:
                arrays["cache" + name] = value
        damping = getattr(self, "_damping_rigid", None)
        if damping is not None:
            arrays["cache_damping_rigid0"], arrays["cache_damping_rigid1"] = damping
        for index, solver in enumerate(self._target_solvers()):
            if solver._last is not None:  # the target solver's warm start
                arrays[f"warm{index}"] = solver._last
            for key, value in getattr(solver, "kept_arrays", dict)().items():
                arrays[f"warm{index}:{key}"] = value  # a modified Newton's Hessians
        for key, value in stepper.kept_tangent().items():
            arrays["tangent:" + key] = value  # the modified Newton's kept tangent
        scalars = {name: getattr(stepper, name) for name in self._STEPPER_SCALARS}
        return snapshot(self.time, arrays, scalars)

    def reset(self, state: EngineState | None = None) -> None:
        """Back to ``state`` (from :attr:`state`) or, with ``None``, to the initial state at
        t = 0; examples and drag stay as switched."""
        saved = dict((self._initial_state if state is None else state).arrays)
        restore = {}
        for name in (*self._STEPPER_ARRAYS, *self._STEPPER_SCALARS):
            if name not in saved:
                raise LbshapeError(f"the state does not fit this engine ({name!r})")
            value = saved[name]
            restore[name] = value.item() if value.ndim == 0 else value.copy()
        for name, value in restore.items():
            setattr(self.stepper, name, value)
        self.stepper.restore_tangent({k[len("tangent:"):]: v for k, v in saved.items()
                                      if k.startswith("tangent:")})
        for name in self._CACHES:
            value = saved.get("cache" + name)
            setattr(self, name, None if value is None else value.copy())
        damping = [saved.get(f"cache_damping_rigid{i}") for i in range(2)]
        self._damping_rigid = None if damping[0] is None else tuple(d.copy() for d in damping)
        if self._b is None:
            self._b = np.zeros(self.free_dofs.size)
        for index, solver in enumerate(self._target_solvers()):
            warm = saved.get(f"warm{index}")
            solver._last = None if warm is None else warm.copy()
            if hasattr(solver, "restore_kept"):
                prefix = f"warm{index}:"
                solver.restore_kept({k[len(prefix):]: v for k, v in saved.items()
                                     if k.startswith(prefix)})

    # ---------------------------------------------------------------- forces
    def _force_and_tangent(self, x: np.ndarray):
        if self._compiled is not None:  # K on the compiled pattern; terms added in place
            f, K = self._compiled.force_and_tangent(self.full_displacement(x).reshape(-1))
            add = self._compiled.add_into
        else:
            f, K = self.elastic.force_and_tangent(self.full_displacement(x).reshape(-1))
            f, K = f[self.free_dofs], self._restrict(K)

            def add(K, matrix, constant=False, scale=1.0):
                return K + scale * matrix
        if self.contact is not None:
            velocity, rate = self._contact_velocity(x)
            fc, parts, _ = self.contact.evaluate_parts(  # the fast path: the areas' change
                self.full_displacement(x).reshape(-1), velocity, rate, shares=self._fast)
            if parts:
                f = f + fc[self.free_dofs]
                K = self.contact.add_into(K, parts, self.free_dofs, self._compiled, add)
        if self._k_ex and self._target_body is not None:  # free body, global examples
            gap = self._free_gap(x, tangent=True)
            f = f + self._k_ex * (self._spring_ff @ gap)
            # minus the rigid part W Wᵀ (_tangent_correction)
            K = add(K, self._spring_ff, constant=True, scale=self._k_ex)  # k_ex S
        elif self._k_ex:
            f = f + self._k_ex * (self._spring_ff @ x)
            K = add(K, self._spring_ff, constant=True, scale=self._k_ex)  # k_ex S
        stepper = getattr(self, "stepper", None)  # None while the stepper is set up
        if self._corotated_beta and stepper is not None:
            # β Pᵀ R K₀ Rᵀ P v₁(x), v₁ the scheme's end-of-step velocity, linear in x
            v1, _ = stepper.kinematics(x - stepper.x)
            damping = self._scaled_damping()
            rate = stepper.scheme.cv / stepper.dt
            f = f + self._deformation_damping(x, damping, v1, rate)
            K = self._add_damping_tangent(K, damping, rate)  # low-rank: _tangent_correction
        if self._drag is not None:  # the spring k u_i on the vertex's free dofs, k I₃
            f = f.copy()
            f[self._drag_dofs] += self._drag.stiffness * x[self._drag_dofs]
            K = (K + self._drag_tangent).tocsr()
        return f, K

    def _force(self, x: np.ndarray) -> np.ndarray:
        """The force of :meth:`_force_and_tangent` alone (the fast path's residual test;
        the stepper evaluates the tangent only where a Newton update needs it)."""
        u = self.full_displacement(x).reshape(-1)
        f = self._compiled.force(u)
        if self.contact is not None and self.contact.touches(u):  # none in flight
            velocity, rate = self._contact_velocity(x)
            fc, parts, _ = self.contact.evaluate_parts(u, velocity, rate, tangent=False)
            if parts:
                f = f + fc[self.free_dofs]
        if self._k_ex and self._target_body is not None:  # free body, global examples
            f = f + self._k_ex * (self._spring_ff @ self._free_gap(x))
        elif self._k_ex:
            f = f + self._k_ex * (self._spring_ff @ x)
        stepper = getattr(self, "stepper", None)
        if self._corotated_beta and stepper is not None:
            v1, _ = stepper.kinematics(x - stepper.x)
            f = f + self._deformation_damping(x, self._scaled_damping(), v1,
                                              stepper.scheme.cv / stepper.dt, tangent=False)
        if self._drag is not None:
            f = f.copy()
            f[self._drag_dofs] += self._drag.stiffness * x[self._drag_dofs]
        return f

    def _contact_velocity(self, x: np.ndarray) -> tuple[np.ndarray | None, float]:
        """The vertex velocities (3n,) m/s the contact's friction reads at the end-of-step
        position x (the scheme's ``v₁(x)``; the initial velocity while the stepper is set
        up) and ``∂v₁/∂x`` (1/s); ``(None, 0)`` without friction."""
        if not self.contact.has_friction:
            return None, 0.0
        stepper = getattr(self, "stepper", None)
        v = np.zeros(3 * self.n_vertices)
        if stepper is None:
            if self._v_start is not None:
                v[self.free_dofs] = self._v_start
            return v, 0.0
        v[self.free_dofs], _ = stepper.kinematics(x - stepper.x)
        return v, stepper.scheme.cv / stepper.dt

    def _potential(self, x: np.ndarray) -> float:
        elastic = self.elastic if self._compiled is None else self._compiled
        u = self.full_displacement(x).reshape(-1)
        energy = elastic.energy(u)
        if self.contact is not None and self.contact.touches(u):
            energy += self.contact.evaluate_parts(u, tangent=False)[2]
        return energy + self._example_energy(x) + self._drag_energy(x)

    def _drag_energy(self, x: np.ndarray) -> float:
        """The drag spring's part of the potential ``½ k |u_i|²`` (J) at free dofs x."""
        if self._drag is None:
            return 0.0
        u = x[self._drag_dofs]
        return 0.5 * self._drag.stiffness * float(u @ u)

    def _external(self, t: float) -> np.ndarray:
        """The loads at t, the example pull and a drag's pull (free dofs, N)."""
        scales = np.array([profile(t) for profile in self._load_profiles])
        load = scales @ self._load_patterns
        if self._drag is not None:
            load[self._drag_dofs] += self._drag_pull
        return load + self._b if self._k_ex else load

    def _ramp_examples(self, t: float) -> None:
        """k_ex(t) of the ``[examples] ramp`` while the examples are on, in the spring and
        its tangent (the pull ``b`` follows at the target update); the spring energy the
        change adds at the current state counts as work for the energy monitor."""
        factor = ramp_factor(t, self.example_ramp)
        k_ex = factor * self._configured_k_ex
        if not (self._examples_on and self._configured_k_ex) or k_ex == self._k_ex:
            return
        stepper = self.stepper
        x, before = stepper.x, self._example_energy(stepper.x)
        self._k_ex = k_ex  # per-step tangents or a factor kept across fresh ones: a
        if factor == 1.0 and (stepper.tangent_each_step or not stepper.refactor_with_tangent):
            stepper.forget_factor()  # reused factor of the full spring's matrix
        self._pull_rigid = None  # the fitted pull's tangent part, of the last evaluation
        stepper.credit_work(self._example_energy(x) - before)

    # ------------------------------------------------------------------- step
    def step(self) -> int:
        """Advance one step: the example target (with examples; a free body's at the
        predicted end of the step), a free body's co-rotated damping, then the implicit
        step; returns the Newton iterations. The wall times are left in ``_marks`` for :meth:`run`.
        The fast path's Newton starts a free body's step in contact from the
        constant-velocity increment ``h v``: a stiff penalty turns the acceleration within
        a step, and the car's wall steps took 2.3× fewer Newton iterations from it
        (``docs/decisions.md``).

        Raises:
            SolverError: the step failed, named by its index and time; the state stays at
                the last good step.
        """
        marks = self._marks
        marks[0] = time.perf_counter()
        if self.example_ramp:
            self._ramp_examples(self.time + self.dt)
        if self._k_ex:
            self._update_target_at_step()
        marks[1] = time.perf_counter()
        touching = bool(self._fast and self.fixed_vertices.size == 0 and self.contact
                        is not None and self.contact.touches(self.full_displacement()))
        if self._corotated_beta:
            self._corotate(touching)
        guess = self.stepper.dt * self.stepper.v if touching else None  # None: predictor
        info = step_with_slip_continuation(self.stepper, self.contact, guess)
        marks[2] = time.perf_counter()
        return info.iterations

    def run(self, steps: int, *, stride: int = 1, on_step: OnStep | None = None) -> RunRecord:
        """Advance ``steps`` steps from the current state.

        Args:
            steps: number of steps, ≥ 1.
            stride: keep every ``stride``-th state (and the initial one), ≥ 1.
            on_step: called after each step with (step index from 0, time in s,
                displacement (n, 3) in m).

        Returns:
            The :class:`~lbshape.dynamics.record.RunRecord`; its states are the node-major
            displacements u (3n,) in m. A failed step ends it with ``stable`` False and
            the message (naming the step and time).
        """
        steps, stride = check_run(steps, stride)
        recorder = RunRecorder(stride=stride)
        u = self.full_displacement()
        recorder.start(self.time, u.reshape(-1))
        max_disp = _max_norm(u)
        marks = self._marks
        for index in range(steps):
            try:
                iterations = self.step()
            except SolverError as exc:
                message = stop_message(
                    exc, load_reach=self.load_reach, omega_max=self.omega_max, dt=self.dt,
                    scales=[profile(self.time + self.dt) for profile in self._load_profiles])
                log.error("full-space simulation stopped: %s", message)
                return recorder.record(stable=False, message=message,
                                       max_displacement=max_disp)
            u = self.full_displacement()
            max_disp = max(max_disp, _max_norm(u))
            recorder.step(self.time, u.reshape(-1), interp_seconds=marks[1] - marks[0],
                          total_seconds=marks[2] - marks[0], iterations=iterations)
            if on_step is not None:
                on_step(index, self.time, u)
        return recorder.record(max_displacement=max_disp)


def rigid_velocity(mesh: TetMesh, density: float, velocity, angular_velocity) -> np.ndarray:
    """(n, 3) vertex velocities ``v + ω × (X − X_cm)`` (m/s) of a rigid motion (world)."""
    mass = mass_matrix(mesh, density)
    weights = np.asarray(mass[0::3, 0::3].sum(axis=1)).ravel()
    center = weights @ mesh.points / weights.sum()
    arm = mesh.points - center
    return np.asarray(velocity, dtype=float) + np.cross(np.asarray(angular_velocity), arm)


def _max_norm(u: np.ndarray) -> float:
    return float(np.sqrt(np.max(np.einsum("ij,ij->i", u, u))))
