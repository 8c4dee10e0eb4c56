"""A free body's co-rotated stiffness damping in the full-space reference
(:class:`FullSpaceDamping`, a part of :class:`~lbshape.dynamics.full.FullSpaceSimulator`):
``β Q K₀ Qᵀ`` in the best rigid frame of each step, acting on the deformation only, and
the low-rank parts of the Newton tangent (see :mod:`lbshape.dynamics.full`)."""

from __future__ import annotations

import numpy as np
import scipy.linalg
import scipy.sparse as sp

from lbshape.dynamics.rigid_frame import best_rigid_frame
from lbshape.dynamics.rigid_motions import rigid_modes


class FullSpaceDamping:
    """The co-rotated damping of :class:`~lbshape.dynamics.full.FullSpaceSimulator` (which
    holds the arrays the methods read: ``mesh``, ``_mass_ff``, ``stepper`` …)."""

    def _scaled_damping(self) -> sp.csr_matrix:
        """``D = β Q K₀ Qᵀ`` of the current frame (kept while the frame is)."""
        kept = getattr(self, "_damping_kept", None)
        if kept is None or kept[0] is not self._damping_now:
            kept = (self._damping_now, self._corotated_beta * self._damping_now)
            self._damping_kept = kept
        return kept[1]

    def _deformation_damping(self, x: np.ndarray, damping: sp.csr_matrix,
                             velocity: np.ndarray, rate: float, *,
                             tangent: bool = True) -> np.ndarray:
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
            tangent: keep the rank-12 part (False: the force alone; the kept part stays).
        """
        n = self.n_vertices
        rigid, mass_rigid = rigid_modes(self.mesh.points + x.reshape(n, 3), self._mass_ff,
                                         getattr(self, "_scalar_mass", None))
        if tangent:
            damped_rigid = np.asarray(damping @ rigid)
            core = np.block([[rigid.T @ damped_rigid, -np.eye(6)],
                             [-np.eye(6), np.zeros((6, 6))]])
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


    def _corotate(self) -> None:
        """Free body: rotate the stiffness damping ``β K₀`` into the current best rigid
        frame, ``β Q K₀ Qᵀ`` with Q = diag(R, …, R), so that it does not damp rigid
        rotation (the reduced method damps the body-frame deformation only)."""
        n = self.n_vertices
        if not hasattr(self, "_scalar_mass"):
            self._init_rigid_fit()
        rest = self.mesh.points
        _, R, _ = best_rigid_frame(self._scalar_mass, rest, rest + self.stepper.x.reshape(n, 3))
        solver = getattr(self.stepper, "_linear_solver", None)
        if hasattr(solver, "frame"):  # the reused factor follows the rotation
            solver.frame = R
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
