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
   (warm-started from the previous step);
4. target displacement ``u* = L c*`` and force ``f_ex = k_ex M (u* − u)``, k_ex in
   1/s². In a mass-orthonormal reduced basis U (``Uᵀ M U = I``) this projects to
   the reduced method's ``k_ex (q* − q)`` with ``q* = Uᵀ M L c*``.

In the stepper the example force is split into a spring ``k_ex M_ff x`` (part of the
position-dependent force, tangent ``k_ex M_ff``, potential ``½ k_ex xᵀ M_ff x``) and
the pull ``k_ex (M u*)_free``, constant during the step, applied as an external load.
**Local examples** (:class:`~lbshape.shapespace.local_examples.FullSpaceLocalForce`):
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

**Failure.** A non-finite state, a Newton failure, an energy blow-up or a failed
target solve raises :class:`FullSpaceDiverged` (a
:class:`~lbshape.errors.SolverError`) naming the step and time; its ``partial``
attribute holds the :class:`~lbshape.dynamics.record.RunRecord` of what was computed,
for the caller to save.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse as sp

from lbshape.dynamics.contact import (
    ContactPlane,
    friction_force,
    plane_frictions,
    surface_vertices,
)
from lbshape.dynamics.integrators import make_stepper
from lbshape.dynamics.linear_solvers import LINEAR_SOLVERS, make_linear_solver
from lbshape.dynamics.loads import TimedLoad, TimeProfile
from lbshape.dynamics.record import RunRecord, RunRecorder
from lbshape.dynamics.rigid_frame import best_rigid_frame
from lbshape.elastic.assembly import CompiledElasticity
from lbshape.elastic.element_kernels import FullSpaceElasticity, mass_matrix
from lbshape.elastic.materials import Material
from lbshape.elastic.modes import rigid_body_modes
from lbshape.errors import LbshapeError, SolverError
from lbshape.geometry.mesh import TetMesh
from lbshape.shapespace.euclidean_energy import EuclideanExampleEnergy
from lbshape.shapespace.example_shapes import energy_elements, example_rest_shapes
from lbshape.shapespace.interpolation import TargetSolver, simplex_weights
from lbshape.shapespace.local_examples import FullSpaceLocalForce
from lbshape.shapespace.projections import block_basis

log = logging.getLogger(__name__)

#: Newton iterations per step allowed (at least) when a plane has friction, whose Newton
#: runs with a line search: the regularised friction is steep within its slip speed, and
#: the car's wall impact took up to 23 iterations (2.6 per step on average)
FRICTION_NEWTON_ITERATIONS = 60


@dataclass(frozen=True)
class FullSpaceExamples:
    """The shape-space arrays of the full-space example force.

    Attributes:
        eigenvalues: (m,) the object's LB eigenvalues λ in 1/m², > 0.
        eigenvectors: (n, m) the object's LB eigenvectors Φ (M₁-orthonormal).
        coefficients: (k, m, 3) the examples' LB displacement coefficients c_k.
        stiffness: k_ex in 1/s², ≥ 0 (0 disables the example force).
    """

    eigenvalues: np.ndarray
    eigenvectors: np.ndarray
    coefficients: np.ndarray
    stiffness: float


class FullSpaceContact:
    """Penalty contact of the surface vertices with planes, on full displacements, with
    the planes' regularised Coulomb friction (:mod:`lbshape.dynamics.contact`).

    Args:
        planes: the :class:`~lbshape.dynamics.contact.ContactPlane` list.
        points: (n, 3) rest positions (m); ``tets`` (t, 4) give the surface.
    """

    def __init__(self, planes: Sequence[ContactPlane], points: np.ndarray, tets: np.ndarray):
        self.vertices = surface_vertices(tets)
        self.rest = np.asarray(points, dtype=float)[self.vertices]
        self.n = points.shape[0]
        self.planes = list(planes)
        normals = np.array([p.normal for p in self.planes], dtype=float).reshape(-1, 3)
        lengths = np.linalg.norm(normals, axis=1)
        if np.any(lengths == 0):
            raise LbshapeError("contact plane normals must be non-zero")
        #: (P, 3) unit normals (as :class:`~lbshape.dynamics.contact.PlaneContact` uses)
        self.normals = normals / lengths[:, None]
        self.friction = plane_frictions(self.planes)
        #: some plane has friction (the force then depends on the velocity)
        self.has_friction = bool(np.any(self.friction > 0))

    def evaluate(self, u: np.ndarray, v: np.ndarray | None = None, rate: float = 0.0):
        """``(f (3n,) = +∂E/∂u − f_friction, K (3n, 3n) CSR or None, energy J)`` for
        u (3n,) m and the vertex velocities v (3n,) m/s (zero when ``None``).

        The friction force ``f_t`` (:func:`~lbshape.dynamics.contact.friction_force`)
        enters ``f`` with the internal-force sign; its tangent per vertex is
        ``rate C − μ k T nᵀ`` (``rate = ∂v/∂u`` of the step in 1/s, C the rate matrix,
        T the slip direction): the consistent tangent, not symmetric.
        """
        x = self.rest + u.reshape(-1, 3)[self.vertices]
        force = np.zeros((self.n, 3))
        rows, cols, vals = [], [], []
        energy = 0.0
        for plane, n, mu in zip(self.planes, self.normals, self.friction, strict=True):
            gap = (x - np.asarray(plane.point)) @ n
            hit = np.flatnonzero(gap < 0.0)
            if hit.size == 0:
                continue
            d = -gap[hit]
            energy += 0.5 * plane.stiffness * float(d @ d)
            np.add.at(force, self.vertices[hit], -plane.stiffness * d[:, None] * n[None, :])
            blocks = np.broadcast_to(plane.stiffness * np.outer(n, n), (hit.size, 3, 3))
            if mu > 0:
                w = (np.zeros((hit.size, 3)) if v is None
                     else v.reshape(-1, 3)[self.vertices[hit]])
                friction, rates, direction = friction_force(w, n, plane.stiffness * d, mu)
                np.add.at(force, self.vertices[hit], -friction)
                blocks = (blocks + rate * rates
                          - mu * plane.stiffness * direction[:, :, None] * n[None, None, :])
            dofs = 3 * self.vertices[hit][:, None] + np.arange(3)[None, :]  # (h, 3)
            rows.append(np.repeat(dofs, 3, axis=1).ravel())
            cols.append(np.tile(dofs, (1, 3)).ravel())
            vals.append(np.ascontiguousarray(blocks).ravel())
        if not rows:
            return force.ravel(), None, 0.0
        K = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(3 * self.n, 3 * self.n))
        return force.ravel(), K, energy


class FullSpaceDiverged(SolverError):
    """The full-space simulation failed; ``partial`` holds what was computed."""

    def __init__(self, message: str, partial: RunRecord):
        super().__init__(message)
        self.partial = partial


class FullSpaceSimulator:
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
        newton_rtol: relative Newton tolerance of the time step.
        max_newton_iterations: Newton iterations per step before failing (with friction
            at least :data:`FRICTION_NEWTON_ITERATIONS`).
        contact: penalty contact with planes, or ``None``.
        linear_solver: ``"reuse"``: compiled assembly
            (:class:`~lbshape.elastic.assembly.CompiledElasticity`), one sparse
            factorisation reused across Newton iterations and steps
            (:class:`~lbshape.dynamics.linear_solvers.ReusedFactorSolver`) and the compiled
            block evaluation of the example target; ``"lu-each-iteration"``: the former
            path (numpy assembly, a SuperLU factorisation per Newton iteration), for
            comparison runs. Same answers to round-off and the Newton tolerance.

    Attributes:
        free_dofs: (nf,) node-major indices of the free dofs (x = u[free_dofs]).
        elastic: the :class:`~lbshape.elastic.element_kernels.FullSpaceElasticity` of the mesh.
        mass: (3n, 3n) consistent mass in kg (CSR).
        stepper: the :mod:`lbshape.dynamics.integrators` stepper on the free dofs.
        weights: (k,) example weights of the last step (``None`` before / without).
        target_coefficients: (3m,) target LB coefficients c* of the last step.

    Raises:
        LbshapeError: inconsistent shapes, indices out of range, every vertex fixed,
            negative α, β or k_ex, or an initial state that moves a fixed vertex.
    """

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
        newton_rtol: float = 1e-8,
        max_newton_iterations: int = 20,
        contact: FullSpaceContact | None = None,
        linear_solver: str = "reuse",
    ):
        if linear_solver not in LINEAR_SOLVERS:
            raise LbshapeError(f"linear_solver must be one of {LINEAR_SOLVERS}, "
                               f"got {linear_solver!r}")
        self._fast = linear_solver == "reuse"
        n = mesh.n_vertices
        self.contact = contact
        friction = contact is not None and contact.has_friction
        self.mesh = mesh
        self.material = material
        self.n_vertices = n
        fixed = _vertex_indices(fixed_vertices, n)
        free_mask = np.ones(3 * n, dtype=bool)
        free_mask[(3 * fixed[:, None] + np.arange(3)).ravel()] = False
        if not free_mask.any():
            raise LbshapeError("every vertex is fixed: nothing to simulate")
        self.fixed_vertices = fixed
        self.free_dofs = np.flatnonzero(free_mask)
        self._free_mask = free_mask

        self.elastic = FullSpaceElasticity(mesh, material)
        self._compiled = (CompiledElasticity(mesh, material, self.free_dofs) if self._fast
                          else None)
        self.mass = mass_matrix(mesh, material.density)
        self._mass_ff = _submatrix(self.mass, self.free_dofs)
        K0 = self.elastic.tangent(np.zeros(3 * n))
        self._restrict = _CsrRestriction(K0, self.free_dofs)
        K0_ff = self._restrict(K0)

        self._load_patterns, self._load_profiles = self._check_loads(loads)
        self._setup_examples(examples, tolerance=target_tolerance)
        self._local = None
        if local_examples is not None and local_examples[1] > 0:
            if self._k_ex:
                raise LbshapeError("give global or local examples, not both")
            self._local, self._k_ex = local_examples[0], float(local_examples[1])
            self._spring_ff = _submatrix(self._local.mass, self.free_dofs)
            self._kM_ff = self._k_ex * self._spring_ff

        x0 = self._initial(initial_displacement, "initial_displacement")
        v0 = self._initial(initial_velocity, "initial_velocity")
        self._v_start = v0  # the friction's velocity while the stepper is set up
        # free body: the stiffness damping follows the body's rotation (see _corotate)
        self._corotated_beta = float(beta) if (fixed.size == 0 and beta > 0) else 0.0
        self._damping_rest = K0_ff if self._corotated_beta else None
        self._damping_now = K0_ff if self._corotated_beta else None
        self._damping_data = None  # β Q K₀ Qᵀ on the compiled pattern (_corotate)
        if self._corotated_beta:
            beta = 0.0
        # a free body's global examples: the rigid-invariant fitted pull (_free_gap)
        fitted_pull = bool(self._k_ex and self.fixed_vertices.size == 0 and self._local is None)
        self.stepper = make_stepper(
            integrator,
            self._mass_ff,
            self._force_and_tangent,
            dt=dt,
            x0=x0,
            v0=v0,
            external=self._external if (self._load_profiles or self._k_ex) else None,
            alpha=alpha,
            beta=beta,
            damping_stiffness=K0_ff,
            potential=self._potential,
            rtol=newton_rtol,
            atol=self._free_pull_round_off() if fitted_pull else 0.0,
            max_iterations=(max(max_newton_iterations, FRICTION_NEWTON_ITERATIONS)
                            if friction or fitted_pull else max_newton_iterations),
            line_search=friction or fitted_pull,
            low_rank_tangent=(self._tangent_correction
                              if fitted_pull or self._corotated_beta else None),
            linear_solver=(make_linear_solver(linear_solver, symmetric=not friction)
                           if self._fast else None),
        )

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

    def _setup_examples(self, examples: FullSpaceExamples | None, *, tolerance: float) -> None:
        self._k_ex = 0.0
        self._spring_ff = self._mass_ff
        self._b = np.zeros(self.free_dofs.size)
        self.target_coefficients: np.ndarray | None = None
        self.weights: np.ndarray | None = None
        #: free body, global examples: the target shape Y (n, 3) of the step and its centre
        self._target_body: np.ndarray | None = None
        self._target_center: np.ndarray | None = None
        if examples is None:
            return
        try:
            k_ex = float(examples.stiffness)
        except (TypeError, ValueError):
            k_ex = float("nan")
        if isinstance(examples.stiffness, bool) or not np.isfinite(k_ex) or k_ex < 0:
            raise LbshapeError(
                f"example stiffness k_ex must be a finite number >= 0 (1/s^2), "
                f"got {examples.stiffness!r}"
            )
        lam = np.asarray(examples.eigenvalues, dtype=float)
        phi = np.asarray(examples.eigenvectors, dtype=float)
        coefficients = np.asarray(examples.coefficients, dtype=float)
        n, m = self.n_vertices, lam.size
        if lam.ndim != 1 or m == 0 or not np.isfinite(lam).all() or (lam <= 0).any():
            raise LbshapeError("eigenvalues must be a non-empty (m,) array of finite values > 0")
        if phi.shape != (n, m) or not np.isfinite(phi).all():
            raise LbshapeError(f"eigenvectors must be a finite ({n}, {m}) array, got {phi.shape}")
        if coefficients.ndim != 3 or coefficients.shape[1:] != (m, 3):
            raise LbshapeError(
                f"example coefficients must have shape (k, {m}, 3), got {coefficients.shape}"
            )
        if not np.isfinite(coefficients).all():
            raise LbshapeError("example coefficients contain NaN or infinite values")
        k = coefficients.shape[0]
        if k_ex == 0.0 or k == 0:
            return
        self._k_ex = float(k_ex)
        weights = np.repeat(lam, 3)
        volume_mass = self.mass[0::3, 0::3] / self.material.density  # M₁ (n, n), m³
        # descriptor of the free displacement x: d = D_f x, D = diag(λ ⊗ 1₃)(Φᵀ M₁ ⊗ I₃)
        D = np.kron(lam[:, None] * np.asarray((volume_mass @ phi).T), np.eye(3))
        self._descriptor = np.ascontiguousarray(D[:, self.free_dofs])  # (3m, nf)
        L = block_basis(phi)  # (3n, 3m) node-major, column 3i + comp
        self._lb_basis = L
        ML = np.asarray(self.mass @ L)
        self._mass_target = np.ascontiguousarray(ML[self.free_dofs])  # (nf, 3m): (M L)_free
        flat = coefficients.reshape(k, 3 * m)
        self._example_descriptors = flat * weights
        rests = example_rest_shapes(self.mesh.points, phi, coefficients)
        kept = energy_elements(self.mesh.points, self.mesh.tets, rests)
        models = [EuclideanExampleEnergy(x, self.mesh.tets[kept], self.material, L,
                                         compiled=self._fast) for x in rests]
        self._target_solver = TargetSolver(models, flat, tolerance=tolerance)
        self._kM_ff = self._k_ex * self._mass_ff

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
    def uses_examples(self) -> bool:
        """True when the example force is active (k_ex > 0 and at least one example)."""
        return self._k_ex > 0.0

    @property
    def time(self) -> float:
        """Current time in s."""
        return self.stepper.time

    def full_displacement(self, x: np.ndarray | None = None) -> np.ndarray:
        """(n, 3) displacement in m of free dofs x (default: the current state)."""
        u = np.zeros(3 * self.n_vertices)
        u[self.free_dofs] = self.stepper.x if x is None else x
        return u.reshape(-1, 3)

    # ---------------------------------------------------------------- forces
    def _force_and_tangent(self, x: np.ndarray):
        if self._compiled is not None:  # K on the compiled pattern; terms added in place
            f, K = self._compiled.force_and_tangent(self.full_displacement(x).reshape(-1))
            add = self._compiled.add_into
        else:
            f, K = self.elastic.force_and_tangent(self.full_displacement(x).reshape(-1))
            f, K = f[self.free_dofs], self._restrict(K)

            def add(K, matrix, constant=False):
                return K + matrix
        if self.contact is not None:
            velocity, rate = self._contact_velocity(x)
            fc, Kc, _ = self.contact.evaluate(self.full_displacement(x).reshape(-1), velocity,
                                              rate)
            if Kc is not None:
                f = f + fc[self.free_dofs]
                K = add(K, Kc[self.free_dofs][:, self.free_dofs]).tocsr()
        if self._k_ex and self._target_body is not None:  # free body, global examples
            gap = self._free_gap(x, tangent=True)
            f = f + self._k_ex * (self._spring_ff @ gap)
            # minus the rigid part W Wᵀ (_tangent_correction)
            K = add(K, self._kM_ff, constant=True)
        elif self._k_ex:
            f = f + self._k_ex * (self._spring_ff @ x)
            K = add(K, self._kM_ff, constant=True)
        stepper = getattr(self, "stepper", None)  # None while the stepper is set up
        if self._corotated_beta and stepper is not None:
            # β Pᵀ R K₀ Rᵀ P v₁(x), v₁ the scheme's end-of-step velocity, linear in x
            v1, _ = stepper.kinematics(x - stepper.x)
            damping = self._corotated_beta * self._damping_now
            rate = stepper.scheme.cv / stepper.dt
            f = f + self._deformation_damping(x, damping, v1, rate)
            if self._damping_data is not None and self._compiled.on_pattern(K):
                K.data += rate * self._damping_data
            else:
                K = (K + rate * damping).tocsr()  # + its rigid part (_tangent_correction)
        return f, K

    def _deformation_damping(self, x: np.ndarray, damping: sp.csr_matrix,
                             velocity: np.ndarray, rate: float) -> np.ndarray:
        """(3n,) N: a free body's stiffness damping of its deformation only,
        ``Pᵀ D P v`` with ``P = I − Ψ Ψᵀ M`` and Ψ (3n, 6) the M-orthonormal rigid
        motions of the current shape ``X + x``.

        ``D = β Q K₀ Qᵀ`` alone does not vanish on a rigid rotation of a *deformed* body:
        ``K₀ (ω × u_body) ≠ 0``, and on the S-bent bar of Figure 4 held by its example
        pull that took 28 % of the angular momentum in 0.26 s of free flight. P removes
        the rigid velocity first and Pᵀ removes the net force and torque, so the damping
        conserves both momenta, as the reduced method's body-frame ``β K q̇`` does.

        Its tangent ``rate · Pᵀ D P`` (P held) is ``rate · D`` plus the rank-12 part
        ``[a b] [[C, −I], [−I, 0]] [a b]ᵀ`` (a = MΨ, b = DΨ, C = Ψᵀ D Ψ), kept for
        :meth:`_tangent_correction`: with ``rate · D`` alone Newton took 4.9 iterations per
        step on a spinning bent bar, with it 3.0.

        Args:
            x: (3n,) the Newton iterate's displacement in m.
            damping: (3n, 3n) D in N·s/m.
            velocity: (3n,) the end-of-step velocity v₁(x) in m/s.
            rate: ∂v₁/∂x of the scheme in 1/s.
        """
        n = self.n_vertices
        rigid = rigid_body_modes(self.mesh.points + x.reshape(n, 3), self._mass_ff)
        mass_rigid = np.asarray(self._mass_ff @ rigid)
        damped_rigid = np.asarray(damping @ rigid)
        core = np.block([[rigid.T @ damped_rigid, -np.eye(6)], [-np.eye(6), np.zeros((6, 6))]])
        self._damping_rigid = (np.hstack([mass_rigid, damped_rigid]), rate * core)
        force = damping @ (velocity - rigid @ (mass_rigid.T @ velocity))
        return force - mass_rigid @ (rigid.T @ force)

    def _tangent_correction(self) -> tuple[np.ndarray, np.ndarray] | None:
        """``(W, S)``: the low-rank part ``W S Wᵀ`` of the last tangent evaluation, the
        fitted pull's ``−W_p W_pᵀ`` (:meth:`_free_gap`) and the deformation damping's
        rigid part (:meth:`_deformation_damping`); None before the first."""
        parts = []
        pull = getattr(self, "_pull_rigid", None)
        if pull is not None:
            parts.append((pull, -np.eye(pull.shape[1])))
        damping = getattr(self, "_damping_rigid", None)
        if damping is not None:
            parts.append(damping)
        if not parts:
            return None
        return (np.hstack([W for W, _ in parts]),
                scipy.linalg.block_diag(*[S for _, S in parts]))

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

    def _corotate(self) -> None:
        """Free body: rotate the stiffness damping ``β K₀`` into the current best rigid
        frame, ``β Q K₀ Qᵀ`` with Q = diag(R, …, R), so that it does not damp rigid
        rotation (the reduced method damps the body-frame deformation only)."""
        n = self.n_vertices
        if not hasattr(self, "_scalar_mass"):
            self._init_rigid_fit()
        rest = self.mesh.points
        _, R, _ = best_rigid_frame(self._scalar_mass, rest, rest + self.stepper.x.reshape(n, 3))
        self._damping_data = None  # β Q K₀ Qᵀ on the compiled pattern
        if self._compiled is not None:
            if getattr(self, "_damping_rest_data", None) is None:
                self._damping_rest_data = self._compiled.pattern_values(self._damping_rest)
            rotated = (None if self._damping_rest_data is None
                       else self._compiled.rotated(self._damping_rest_data, R))
            if rotated is not None:
                c = self._compiled
                self._damping_now = sp.csr_matrix((rotated, c.indices, c.indptr),
                                                  shape=self._damping_rest.shape)
                self._damping_data = self._corotated_beta * rotated
                return
        Q = sp.kron(sp.identity(n, format="csr"), sp.csr_matrix(R), format="csr")
        self._damping_now = (Q @ self._damping_rest @ Q.T).tocsr()

    def _potential(self, x: np.ndarray) -> float:
        elastic = self.elastic if self._compiled is None else self._compiled
        energy = elastic.energy(self.full_displacement(x).reshape(-1))
        if self.contact is not None:
            energy += self.contact.evaluate(self.full_displacement(x).reshape(-1))[2]
        return energy + self._example_energy(x)

    def _example_energy(self, x: np.ndarray) -> float:
        """The example spring's energy (J) at free-dof displacements x (its part of the
        potential): ``½ k_ex ‖x − T(x)‖²_M`` towards a free body's placed target, else
        ``½ k_ex xᵀ M x`` (the target's side is the external force ``b``)."""
        if not self._k_ex:
            return 0.0
        if self._target_body is not None:
            gap = self._free_gap(x)
            return 0.5 * self._k_ex * float(gap @ (self._spring_ff @ gap))
        return 0.5 * self._k_ex * float(x @ (self._spring_ff @ x))

    def _free_pull_round_off(self) -> float:
        """Round-off (N, 2-norm) of a free body's fitted example pull.

        ``k_ex M (x − T(x))`` subtracts positions of size |X̄| (the body's radius), and the
        fit's rotation is exact only to ε: the pull is known to ``k_ex ε |X̄| ‖M 1‖``, which
        at a strong k_ex lies above ``rtol`` times a small step's residual scale (Newton
        would iterate on noise)."""
        points = self.mesh.points
        radius = float(np.linalg.norm(points - points.mean(axis=0), axis=1).max())
        row_sums = np.asarray(self._mass_ff.sum(axis=1)).ravel()
        return 64.0 * np.finfo(float).eps * self._k_ex * radius * float(np.linalg.norm(row_sums))

    def _free_gap(self, x: np.ndarray, *, tangent: bool = False) -> np.ndarray:
        """(3n,) ``x_world − T(x)``: a free body's positions minus the target shape placed
        by its mass-weighted best rigid fit onto them (see :meth:`_update_free_target`).

        With ``tangent`` also the rigid part of the pull's tangent: with Ψ (3n, 6) the
        rigid motions of the placed target (translations, rotations about its centre)
        and G = Ψᵀ M Ψ = L Lᵀ, ``W = √k_ex M Ψ L⁻ᵀ`` (3n, 6), so that the pull's tangent
        is ``k_ex M − W Wᵀ`` (no stiffness along rigid motions: the fit follows them)."""
        n = self.n_vertices
        positions = self.mesh.points + x.reshape(n, 3)
        center, R, _ = best_rigid_frame(self._scalar_mass, self._target_body, positions)
        placed = center + (self._target_body - self._target_center) @ R.T
        if tangent:
            arm = placed - center
            psi = np.zeros((3 * n, 6))
            for axis in range(3):
                psi[axis::3, axis] = 1.0
                turn = np.zeros(3)
                turn[axis] = 1.0
                psi[:, 3 + axis] = np.cross(turn, arm).ravel()
            mass_psi = np.asarray(self._spring_ff @ psi)
            lower = np.linalg.cholesky(psi.T @ mass_psi)
            self._pull_rigid = np.sqrt(self._k_ex) * np.linalg.solve(lower, mass_psi.T).T
        return (positions - placed).ravel()

    def _external(self, t: float) -> np.ndarray:
        scales = np.array([profile(t) for profile in self._load_profiles])
        load = scales @ self._load_patterns
        return load + self._b if self._k_ex else load

    def _update_target(self) -> None:
        """Weights and target from the current state; sets the example force."""
        x = self.stepper.x
        if self._local is not None:
            pull = self._local.pull(self.full_displacement(x))
            self.weights = np.concatenate(list(self._local.weights.values()))
            self._b = self._k_ex * pull[self.free_dofs]
            return
        if self.fixed_vertices.size == 0:  # free body: interpolate in the co-moving frame
            # the fitted pull is part of the potential: the energy the moved target puts
            # in at the fixed state is work done on the body (the energy monitor's budget)
            before = self._example_energy(x)
            self._update_free_target(x)
            self.stepper.credit_work(self._example_energy(x) - before)
            return
        weights = simplex_weights(self._example_descriptors, self._descriptor @ x)
        c_star = self._target_solver.solve(weights).z
        self.weights = weights
        self.target_coefficients = c_star
        self._b = self._k_ex * (self._mass_target @ c_star)

    def _init_rigid_fit(self) -> None:
        self._scalar_mass = sp.csr_matrix(self.mass[0::3, 0::3])
        rigid = rigid_body_modes(self.mesh.points, self.mass)  # (3n, 6), M-orthonormal
        self._rigid_modes = (rigid, np.asarray(self.mass @ rigid))

    def _update_free_target(self, u: np.ndarray) -> None:
        """Free body: the shape is compared in the best-fitting rigid frame, and the
        example force acts on the deformation only.

        With the scalar mass M₁, the centre of mass ``c = Σ M₁ x / m`` and the rotation
        R of the polar decomposition of ``Σ M₁ (x − c) X̄ᵀ`` (mass-weighted Kabsch fit of
        the rest shape X̄ = X − X_cm to x; then ``Σ M X̄ × u_b = 0``, the frame of the
        reduced method's rigid-free basis), the body-frame displacement
        ``u_b = Rᵀ (x − c) − X̄`` gives the weights and the target ``c*`` (held for the
        step). The target shape ``Y = X̄ + Π L c*`` loses its rigid content (M-orthogonal
        projection Π on the rest shape's rigid motions, as the projection on U does in
        the reduced method). The example energy is rigid-invariant,
        ``½ k_ex min_{c,R} ‖x − (c + R Y)‖²_M``: its force ``k_ex M (x − T(x))``, with
        ``T(x) = c(x) + R(x) Y`` the target placed by its best rigid fit onto the
        current positions (:meth:`_free_gap`, evaluated at every Newton iterate), has
        no net force and no net torque — an internal force, as ``k_ex (q* − q)`` on the
        rigid-free basis is in the reduced method. (A pull towards a frame fixed during
        the step would hold the body's rigid motion with stiffness k_ex; at the car's
        k_ex that changed its angular momentum in free flight.) The Newton tangent
        keeps ``k_ex M``, exact but for the fit's motion, so Newton converges.
        """
        n = self.n_vertices
        if not hasattr(self, "_scalar_mass"):
            self._init_rigid_fit()
        rest = self.mesh.points
        x = rest + u.reshape(n, 3)
        _, _, body = best_rigid_frame(self._scalar_mass, rest, x)
        weights = simplex_weights(self._example_descriptors, self._descriptor @ body.ravel())
        c_star = self._target_solver.solve(weights).z
        self.weights = weights
        self.target_coefficients = c_star
        shape = self._lb_basis @ c_star
        rigid, mass_rigid = self._rigid_modes
        shape = shape - rigid @ (mass_rigid.T @ shape)  # no rigid content, as U in reduced
        self._target_body = rest + shape.reshape(n, 3)
        weights_m = np.asarray(self._scalar_mass.sum(axis=1)).ravel()
        self._target_center = weights_m @ self._target_body / weights_m.sum()
        self._b = np.zeros(self.free_dofs.size)

    # ------------------------------------------------------------------- run
    def run(
        self,
        steps: int,
        *,
        stride: int = 1,
        on_step: Callable[[int, float, np.ndarray], None] | None = None,
    ) -> RunRecord:
        """Advance ``steps`` steps from the current state.

        Args:
            steps: number of steps, ≥ 1.
            stride: keep every ``stride``-th state (and the initial one), ≥ 1.
            on_step: called after each step with (local step index, time in s,
                displacement (n, 3) in m).

        Returns:
            The :class:`~lbshape.dynamics.record.RunRecord` (``stable`` True); its
            states are the node-major displacements u (3n,) in m.

        Raises:
            FullSpaceDiverged: a step failed; its message names the step and time,
                its ``partial`` holds the record up to the last good step.
        """
        steps, stride = int(steps), int(stride)
        if steps < 1 or stride < 1:
            raise LbshapeError(f"steps and stride must be >= 1, got {steps} and {stride}")
        recorder = RunRecorder(stride=stride)
        u = self.full_displacement()
        recorder.start(self.time, u.reshape(-1))
        max_disp = _max_norm(u)
        for index in range(1, steps + 1):
            started = time.perf_counter()
            try:
                if self._k_ex:
                    self._update_target_at_step()
                interpolated = time.perf_counter()
                if self._corotated_beta:
                    self._corotate()
                info = self.stepper.step()
            except SolverError as exc:
                log.error("full-space simulation stopped: %s", exc)
                partial = recorder.record(stable=False, message=str(exc),
                                          max_displacement=max_disp)
                raise FullSpaceDiverged(str(exc), partial) from exc
            finished = time.perf_counter()
            u = self.full_displacement()
            max_disp = max(max_disp, _max_norm(u))
            recorder.step(self.time, u.reshape(-1), interp_seconds=interpolated - started,
                          total_seconds=finished - started, iterations=info.iterations)
            if on_step is not None:
                on_step(index, self.time, u)
        return recorder.record(max_displacement=max_disp)

    def _update_target_at_step(self) -> None:
        """:meth:`_update_target`, its failure named by the step and time it was for."""
        try:
            self._update_target()
        except SolverError as exc:
            step = self.stepper.steps_taken + 1
            raise SolverError(
                f"target interpolation failed at step {step} "
                f"(t = {self.time + self.stepper.dt:.6g} s): {exc}"
            ) from None


def rigid_velocity(mesh: TetMesh, density: float, velocity, angular_velocity) -> np.ndarray:
    """(n, 3) vertex velocities ``v + ω × (X − X_cm)`` (m/s) of a rigid motion (world)."""
    mass = mass_matrix(mesh, density)
    weights = np.asarray(mass[0::3, 0::3].sum(axis=1)).ravel()
    center = weights @ mesh.points / weights.sum()
    arm = mesh.points - center
    return np.asarray(velocity, dtype=float) + np.cross(np.asarray(angular_velocity), arm)


# -------------------------------------------------------------------- helpers
class _CsrRestriction:
    """Restrict CSR matrices with a fixed pattern (that of ``template``) to ``dofs``.

    The rows and columns of ``dofs`` are selected by gathering the data array, so a
    call costs one fancy index of the non-zeros and no sparse re-indexing.
    """

    def __init__(self, template: sp.csr_matrix, dofs: np.ndarray):
        self._indices = template.indices
        self._indptr = template.indptr
        nnz = template.indices.size
        marker = sp.csr_matrix(
            (np.arange(1, nnz + 1, dtype=float), template.indices, template.indptr),
            shape=template.shape,
        )
        sub = marker[dofs][:, dofs].tocsr()
        sub.sort_indices()
        self._gather = sub.data.astype(np.int64) - 1
        self._sub_indices, self._sub_indptr = sub.indices, sub.indptr
        self._shape = (dofs.size, dofs.size)

    def __call__(self, matrix: sp.csr_matrix) -> sp.csr_matrix:
        if not (np.array_equal(matrix.indptr, self._indptr)
                and np.array_equal(matrix.indices, self._indices)):
            raise LbshapeError("tangent does not have the expected sparsity pattern")
        return sp.csr_matrix(
            (matrix.data[self._gather], self._sub_indices.copy(), self._sub_indptr.copy()),
            shape=self._shape,
        )


def _submatrix(matrix: sp.spmatrix, dofs: np.ndarray) -> sp.csr_matrix:
    return sp.csr_matrix(matrix.tocsr()[dofs][:, dofs])


def _vertex_indices(values, n: int) -> np.ndarray:
    idx = np.asarray(values)
    if idx.size == 0:
        return np.zeros(0, dtype=np.int64)
    if idx.ndim != 1 or not np.issubdtype(idx.dtype, np.integer):
        raise LbshapeError(f"fixed vertices must be a 1-D array of integers, got {idx.dtype}")
    if idx.min() < 0 or idx.max() >= n:
        raise LbshapeError(f"fixed vertex index out of range [0, {n})")
    return np.unique(idx.astype(np.int64))


def _max_norm(u: np.ndarray) -> float:
    return float(np.sqrt(np.max(np.einsum("ij,ij->i", u, u))))
