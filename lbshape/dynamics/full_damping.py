"""A free body's co-rotated stiffness damping in the full-space reference
(:class:`FullSpaceDamping`, a part of :class:`~lbshape.dynamics.full.FullSpaceSimulator`):
``β Q K₀ Qᵀ`` in the best rigid frame of each step, acting on the deformation only, and
the low-rank parts of the Newton tangent (see :mod:`lbshape.dynamics.full`). The fast
path also turns the tangent it keeps across steps in flight with that frame
(:meth:`FullSpaceDamping._turn_kept_tangent`) and applies ``β Q K₀ Qᵀ`` without forming
it (:class:`TurnedMatrix`)."""

from __future__ import annotations

import numpy as np
import scipy.linalg
import scipy.sparse as sp

from lbshape._jit import njit
from lbshape.dynamics.integrators import TANGENT_CONTRACTION
from lbshape.dynamics.rigid_frame import KabschFit, skew
from lbshape.dynamics.rigid_motions import rigid_modes

#: the contraction ``‖R_new‖ / ‖R‖`` a free body's tangent kept across steps in flight
#: must achieve (else evaluated afresh at the next update): on the Figure 4 bar, 0.1 let
#: 3.5 updates a step through, 1e-3 evaluated it at every third step; 0.01: every fifth
FLIGHT_TANGENT_CONTRACTION = 0.01


def _turned_rows(turn: np.ndarray, fields: np.ndarray) -> np.ndarray:
    """(3n, k) ``Q F``, Q = diag(turn, …): each vertex's 3 rows of ``fields`` (3n, k),
    node-major, turned by ``turn`` (3, 3)."""
    F = np.ascontiguousarray(fields, dtype=np.float64).reshape(-1, 3, fields.shape[1])
    out = np.empty_like(F)
    _turn_rows(np.ascontiguousarray(turn, dtype=np.float64), F, out)
    return out.reshape(fields.shape)


@njit
def _turn_rows(turn, F, out):
    """out[i] = turn @ F[i] for F, out (n, 3, k)."""
    for i in range(F.shape[0]):
        for c in range(F.shape[2]):
            x, y, z = F[i, 0, c], F[i, 1, c], F[i, 2, c]
            for a in range(3):
                out[i, a, c] = turn[a, 0] * x + turn[a, 1] * y + turn[a, 2] * z


class TurnedMatrix:
    """``Q A Qᵀ`` applied without forming it, ``Q (A (Qᵀ a)))``, Q = diag(turn, …): a
    free body's co-rotated damping between two tangent evaluations.

    Args:
        matrix: (3n, 3n) A, node-major.
        turn: (3, 3) the rotation.
    """

    def __init__(self, matrix: sp.spmatrix, turn: np.ndarray):
        self.matrix, self.turn = matrix, np.asarray(turn)

    def __matmul__(self, a: np.ndarray) -> np.ndarray:
        """``Q A Qᵀ a`` for a (3n,) or (3n, k)."""
        columns = np.asarray(a).reshape(a.shape[0], -1)
        out = _turned_rows(self.turn, self.matrix @ _turned_rows(self.turn.T, columns))
        return out.reshape(a.shape)


def angular_velocity(points: np.ndarray, rigid_velocity: np.ndarray) -> np.ndarray:
    """(3,) rad/s: ω of a rigid velocity field ``V + ω × r`` (3n,) m/s at ``points``
    (n, 3) m: with r about the points' mean (Σ r = 0), ``Σ r × v = (Σ |r|² I − r rᵀ) ω``."""
    r = points - points.mean(axis=0)
    v = rigid_velocity.reshape(-1, 3)
    outer = r.T @ r
    cross = r.T @ v  # Σ r_a v_b
    moment = np.array([cross[1, 2] - cross[2, 1], cross[2, 0] - cross[0, 2],
                       cross[0, 1] - cross[1, 0]])
    return np.linalg.solve(np.trace(outer) * np.eye(3) - outer, moment)


class FullSpaceDamping:
    """The co-rotated damping of :class:`~lbshape.dynamics.full.FullSpaceSimulator` (which
    holds the arrays the methods read: ``mesh``, ``_mass_ff``, ``stepper`` …)."""

    def _scaled_damping(self) -> sp.csr_matrix:
        """``D = β Q K₀ Qᵀ`` of the current frame (kept while the frame is)."""
        if isinstance(self._damping_now, TurnedMatrix):  # scaled already
            return self._damping_now
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
        step on a spinning bent bar, with it 3.0. The fast path adds P's turn with the
        body, ``− Pᵀ D P Ω`` (Ω = diag([ω]×, …), ω the spin of v's rigid part: P v loses
        ``ω × δx`` when the shape moves by δx; the rest of P's derivative is rank 3 and
        of the deformation's size), as ``− D Ω`` (:meth:`_add_damping_tangent`) and the
        two-sided low-rank part ``[a b] core ([a b] + Ω [a b] / rate)ᵀ``. At 1.5 rad/s
        and dt = 1 ms the left-out turn alone held Newton to a 1e-3 contraction per update
        (|ω| / rate); with it the Figure 4 bar's contraction is 1e-5, as without damping.

        Args:
            x: (3n,) the Newton iterate's displacement in m.
            damping: (3n, 3n) D in N·s/m.
            velocity: (3n,) the end-of-step velocity v₁(x) in m/s.
            rate: ∂v₁/∂x of the scheme in 1/s.
            tangent: keep the rank-12 part (False: the force alone; the kept part stays).
        """
        points = self.mesh.points + x.reshape(self.n_vertices, 3)
        rigid, mass_rigid = rigid_modes(points, self._mass_ff, self._scalar_mass)
        rigid_velocity = rigid @ (mass_rigid.T @ velocity)
        if tangent:
            damped_rigid = np.asarray(damping @ rigid)
            core = rate * np.block([[rigid.T @ damped_rigid, -np.eye(6)],
                                    [-np.eye(6), np.zeros((6, 6))]])
            W = np.hstack([mass_rigid, damped_rigid])
            self._damping_rigid = (W, core)
            self._damping_spin = None
            if self._fast:  # − Pᵀ D P Ω = − D Ω + W (core / rate) (Ω W)ᵀ
                omega = angular_velocity(points, rigid_velocity)
                self._damping_spin = omega
                zero = np.zeros_like(core)
                self._damping_rigid = (np.hstack([W, W + _turned_rows(skew(omega), W) / rate]),
                                       np.block([[zero, core], [zero, zero]]))
        force = damping @ (velocity - rigid_velocity)
        return force - mass_rigid @ (rigid.T @ force)

    def _add_damping_tangent(self, K: sp.csr_matrix, damping, rate: float) -> sp.csr_matrix:
        """K plus the sparse part of the deformation damping's tangent: ``rate · D``, and
        on the fast path ``D (rate I − Ω)`` (Ω of the spin at the last
        :meth:`_deformation_damping` with ``tangent``); in place on the compiled pattern's
        3 × 3 blocks, else a sparse sum. ``damping``: D, (3n, 3n) sparse or a
        :class:`TurnedMatrix`."""
        spin = getattr(self, "_damping_spin", None)
        data = self._damping_pattern_data()
        turned = None if spin is None else rate * np.eye(3) - skew(spin)
        if data is not None and self._compiled.on_pattern(K):
            K.data += rate * data if turned is None else (data.reshape(-1, 3) @ turned).ravel()
            return K
        if isinstance(damping, TurnedMatrix):  # formed on the pattern
            damping = sp.csr_matrix((data, self._compiled.indices, self._compiled.indptr),
                                    shape=K.shape)
        if turned is None:
            return (K + rate * damping).tocsr()
        n = K.shape[0] // 3
        return (K + damping @ sp.kron(sp.identity(n), sp.csr_matrix(turned))).tocsr()

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

    def _corotate(self, touching: bool = False) -> None:
        """Free body: rotate the stiffness damping ``β K₀`` into the current best rigid
        frame, ``β Q K₀ Qᵀ`` with Q = diag(R, …, R), so that it does not damp rigid
        rotation (the reduced method damps the body-frame deformation only); the fast
        path turns its kept tangent into the frame too (:meth:`_turn_kept_tangent`;
        ``touching``: a surface vertex is behind a contact plane)."""
        n = self.n_vertices
        rest = self.mesh.points
        if getattr(self, "_rest_fit", None) is None:
            self._rest_fit = KabschFit(self._scalar_mass, rest)
        _, R = self._rest_fit(rest + self.stepper.x.reshape(n, 3))
        solver = getattr(self.stepper, "_linear_solver", None)
        if hasattr(solver, "frame"):  # the reused factor follows the rotation
            solver.frame = R
        if self._tangent_across_flight:
            self._turn_kept_tangent(R, touching)
        self._damping_data = None  # β Q K₀ Qᵀ on the compiled pattern, when asked
        if self._compiled is not None:
            if getattr(self, "_damping_rest_data", None) is None:
                self._damping_rest_data = self._compiled.pattern_values(self._damping_rest)
                self._damping_rest_scaled = self._corotated_beta * self._damping_rest
            if self._damping_rest_data is not None and self._compiled.blocked:
                self._damping_now = TurnedMatrix(self._damping_rest_scaled, R)
                return
        Q = sp.kron(sp.identity(n, format="csr"), sp.csr_matrix(R), format="csr")
        self._damping_now = (Q @ self._damping_rest @ Q.T).tocsr()

    def _damping_pattern_data(self) -> np.ndarray | None:
        """``β Q K₀ Qᵀ`` as a data array on the compiled pattern (rotated when first asked
        in a step), or None off the fast path's blocked pattern."""
        if self._damping_data is None and isinstance(self._damping_now, TurnedMatrix):
            self._damping_data = self._corotated_beta * self._compiled.rotated(
                self._damping_rest_data, self._damping_now.turn)
        return self._damping_data

    def _turn_kept_tangent(self, R: np.ndarray, touching: bool) -> None:
        """The fast path's free body in flight keeps its tangent across steps, turned with
        the body: ``Q K Qᵀ`` and ``Q W`` (Q = diag(R R_lastᵀ, …), R (3, 3) the frame of
        this step, R_last the kept tangent's), as the reused factor is (a rotated body's
        stiffness is the rotated stiffness; mass, spring and damping turn alike). It is
        evaluated afresh where an update contracts ‖R‖ less than
        :data:`FLIGHT_TANGENT_CONTRACTION`, and at each step in contact (a penalty
        that changes within the step). On the Figure 4 bar in flight (steps 1-288): one
        evaluation in about five steps, 1.7 Newton updates a step (its updates solved to
        the Newton iteration's contraction: :data:`~lbshape.dynamics.linear_solvers.
        CONTRACTION_CAP`, set with the stepper)."""
        stepper = self.stepper
        stepper.tangent_each_step = touching
        stepper.tangent_contraction = (TANGENT_CONTRACTION if touching
                                       else FLIGHT_TANGENT_CONTRACTION)
        last, self._tangent_frame = self._tangent_frame, np.array(R)
        if touching or last is None:
            return
        turn = R @ last.T

        def turned(K, low_rank):
            data = self._compiled.rotated(K.data, turn) if self._compiled.on_pattern(K) \
                else None
            if data is None:  # not on the blocked pattern: evaluated afresh
                return None
            K = sp.csr_matrix((data, K.indices, K.indptr), shape=K.shape)
            if low_rank is None:
                return K, None
            W, S = low_rank
            return K, (_turned_rows(turn, W), S)

        stepper.turn_kept_tangent(turned)
