"""The example force of the full-space reference (:class:`FullSpaceExampleForce`, a part of
:class:`~lbshape.dynamics.full.FullSpaceSimulator`): its shape-space arrays
(:class:`FullSpaceExamples`), the weights and target of each step (a free body's at the
scheme's predicted end of the step, a fixed object's at its start), and for a free body
the rigid-invariant pull towards the target placed by its best rigid fit (the steps are
in :mod:`lbshape.dynamics.full`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from lbshape.dynamics.rigid_frame import KabschFit, best_rigid_frame
from lbshape.dynamics.rigid_motions import rigid_modes
from lbshape.elastic.modes import rigid_body_modes
from lbshape.errors import LbshapeError, SolverError
from lbshape.shapespace.euclidean_energy import EuclideanExampleEnergy
from lbshape.shapespace.example_shapes import energy_elements, example_rest_shapes
from lbshape.shapespace.interpolation import SimplexWeights, TargetSolver
from lbshape.shapespace.projections import block_basis
from lbshape.shapespace.reused_hessian import ReusedHessianTargetSolver


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


class FullSpaceExampleForce:
    """The example force's set-up and per-step target, for
    :class:`~lbshape.dynamics.full.FullSpaceSimulator` (which holds the arrays the methods
    read: ``mesh``, ``mass``, ``free_dofs``, ``stepper`` …)."""

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
        self._simplex = SimplexWeights(self._example_descriptors)  # its supports, once
        rests = example_rest_shapes(self.mesh.points, phi, coefficients)
        kept = energy_elements(self.mesh.points, self.mesh.tets, rests)
        models = [EuclideanExampleEnergy(x, self.mesh.tets[kept], self.material, L,
                                         compiled=self._fast)
                  for x in rests]
        # the fast path: modified Newton, the Hessians reused across iterations and steps
        solver = ReusedHessianTargetSolver if self._fast else TargetSolver
        self._target_solver = solver(models, flat, tolerance=tolerance)

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
        rigid motions of the placed target and G = Ψᵀ M Ψ = L Lᵀ, ``W = √k_ex M Ψ L⁻ᵀ``
        (3n, 6, :func:`~lbshape.dynamics.rigid_motions.rigid_modes`: it does not depend on
        the point the rotations are taken about), so that the pull's tangent is
        ``k_ex M − W Wᵀ`` (no stiffness along rigid motions: the fit follows them)."""
        n = self.n_vertices
        positions = self.mesh.points + x.reshape(n, 3)
        center, R = self._target_fit(positions)
        placed = center + (self._target_body - self._target_center) @ R.T
        if tangent:  # M Ψ L⁻ᵀ of the placed target's rigid motions
            scalar = self._scalar_mass if self._spring_ff is self._mass_ff else None
            _, mass_rigid = rigid_modes(placed, self._spring_ff, scalar)
            self._pull_rigid = np.sqrt(self._k_ex) * mass_rigid
        return (positions - placed).ravel()

    def _target_fit(self, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(c, R) of the :class:`~lbshape.dynamics.rigid_frame.KabschFit` of the step's
        target shape onto ``positions`` (n, 3), kept while the target is."""
        kept = getattr(self, "_fit_kept", None)
        if kept is None or kept[0] is not self._target_body:
            kept = (self._target_body, KabschFit(self._scalar_mass, self._target_body))
            self._fit_kept = kept
        return kept[1](positions)

    def _update_target(self) -> None:
        """Weights and target from the state at the start of the step (a fixed object) or,
        for a free body, at the scheme's predicted end of the step (where the step's other
        forces are evaluated, as the reduced free body does); sets the example force."""
        x = self.stepper.x
        guess = x + self.stepper._predict() if self.fixed_vertices.size == 0 else x
        if self._local is not None:
            pull = self._local.pull(self.full_displacement(guess))
            self.weights = np.concatenate(list(self._local.weights.values()))
            self._b = self._k_ex * pull[self.free_dofs]
            return
        if self.fixed_vertices.size == 0:  # free body: interpolate in the co-moving frame
            if self._target_body is not None and np.size(self.weights) == 1:
                return  # one example: its weight is 1, its placed target stays
            # the fitted pull is part of the potential: the energy the moved target puts
            # in at the fixed state is work done on the body (the energy monitor's budget)
            before = self._example_energy(x)
            self._update_free_target(guess)
            self.stepper.credit_work(self._example_energy(x) - before)
            return
        weights = self._simplex(self._descriptor @ guess)
        c_star = self._target_solver.solve(weights).z
        self.weights = weights
        self.target_coefficients = c_star
        self._b = self._k_ex * (self._mass_target @ c_star)

    def _init_rigid_fit(self) -> None:
        """A free body's rigid-frame fit (built with the stepper of
        :class:`~lbshape.dynamics.full.FullSpaceSimulator`):
        the scalar mass M₁ (n, n) and the rest shape's M-orthonormal rigid modes (3n, 6)."""
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
        rest = self.mesh.points
        x = rest + u.reshape(n, 3)
        _, _, body = best_rigid_frame(self._scalar_mass, rest, x)
        weights = self._simplex(self._descriptor @ body.ravel())
        c_star = self._target_solver.solve(weights).z
        self.weights = weights
        unchanged = (self._target_body is not None and self.target_coefficients is not None
                     and np.array_equal(c_star, self.target_coefficients))
        self.target_coefficients = c_star
        if unchanged:  # one example, or weights that stay: the same placed target
            return
        shape = self._lb_basis @ c_star
        rigid, mass_rigid = self._rigid_modes
        shape = shape - rigid @ (mass_rigid.T @ shape)  # no rigid content, as U in reduced
        self._target_body = rest + shape.reshape(n, 3)
        weights_m = np.asarray(self._scalar_mass.sum(axis=1)).ravel()
        self._target_center = weights_m @ self._target_body / weights_m.sum()
        self._b = np.zeros(self.free_dofs.size)

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
