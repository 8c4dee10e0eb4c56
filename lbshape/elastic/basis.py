"""The nonlinear reduced basis U (3n, r): mass-PCA of linear modes and modal derivatives.

Following Barbič & James (2005), the vectors are first scaled so that low
frequencies dominate: linear mode ψ_i by ``ω₁²/ω_i²`` and modal derivative Ψ_ij by
``ω₁⁴/(ω_i² ω_j²)`` (ω₁ the lowest elastic frequency). Principal components are
taken in the mass inner product through the small Gram matrix ``G = XᵀMX`` (its
eigenvectors V and eigenvalues s² give ``U = X V s⁻¹``), never a dense 3n × 3n
matrix.

Two variants (keyword ``keep_linear``):

* ``True`` (default): the k linear modes are kept exactly as the first columns
  (they are M-orthonormal already) and the PCA acts on the scaled derivatives after
  their components along the linear modes are removed M-orthogonally. The basis
  then reproduces the linearisation at rest exactly for those modes, and span(U)
  contains every linear mode used when r ≥ k. For r < k, U is the r lowest modes
  (which is also what PCA of the scaled linear modes alone gives).
* ``False``: one PCA of all scaled vectors together (the literal Barbič & James
  recipe); span(U) need not contain the linear modes exactly. A derivative is
  quadratic in the mode amplitude, so its size relative to the modes depends on
  their (mass) normalisation, i.e. on ρ and the object's size: the joint PCA may
  rank derivatives above low modes. Keeping the modes avoids that dependence.

``singular_values`` are the M-norms of the principal components, descending within
each PCA block: for ``keep_linear`` the linear scales ``ω₁²/ω_i²`` followed by the
derivative block's singular values.

**How many linear modes for a target r** (:func:`default_linear_modes`): the
smallest k with ``k + k(k+1)/2 ≥ 2r`` (capped at r), so the PCA chooses r directions
from about twice as many candidates. The paper's bars use r = 30, which gives
k = 10 (10 modes + 55 derivatives = 65 vectors); r = 10 gives k = 5 (20 vectors).

After the PCA, U is re-orthonormalised once in the M inner product (the Gram route
squares the condition number) and ``UᵀMU = I`` is checked to ``ORTHONORMALITY_TOL``.
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import scipy.sparse as sp

from lbshape.elastic.modal_derivatives import ModalDerivatives
from lbshape.elastic.modes import LinearModes
from lbshape.errors import LbshapeError, SolverError

log = logging.getLogger(__name__)

#: principal components with singular value ≤ RANK_RTOL × the block's largest are
#: numerically dependent
RANK_RTOL = 1e-6
#: accepted ``max |UᵀMU − I|``
ORTHONORMALITY_TOL = 1e-8


@dataclasses.dataclass(frozen=True)
class NonlinearBasis:
    """The reduced elastic basis.

    Attributes:
        U: (3n, r) node-major, input vertex order, ``UᵀMU = I`` (M in kg).
        singular_values: (k + p,) M-norms of the principal components of the scaled
            vectors (see the module docstring), dimensionless relative sizes.
        r: number of basis vectors.
        omega2: (r,) Rayleigh quotients ``uᵢᵀ K uᵢ`` in rad²/s² (``uᵢᵀMuᵢ = 1``): the
            squared frequency of each basis direction (exactly ω_i² for kept linear
            modes), for inverse-frequency scaling.
        n_linear: linear modes offered to the PCA (k).
        n_derivatives: modal derivatives offered to the PCA (p).
    """

    U: np.ndarray
    singular_values: np.ndarray
    r: int
    omega2: np.ndarray
    n_linear: int
    n_derivatives: int


def default_linear_modes(r: int) -> int:
    """Linear modes k for a basis of r vectors: smallest k with k + k(k+1)/2 ≥ 2r, ≤ r."""
    if isinstance(r, bool) or not isinstance(r, int | np.integer) or r < 1:
        raise LbshapeError(f"r must be an integer >= 1, got {r!r}")
    k = 1
    while k + k * (k + 1) // 2 < 2 * r:
        k += 1
    return min(k, int(r))


def nonlinear_basis(
    modes: LinearModes,
    derivatives: ModalDerivatives,
    mass: sp.spmatrix,
    r: int,
    *,
    keep_linear: bool = True,
) -> NonlinearBasis:
    """Mass-PCA basis of scaled linear modes and modal derivatives.

    Args:
        modes: k linear modes (vectors (3n, k), ω² (k,)).
        derivatives: p modal derivatives of those modes (vectors (3n, p)).
        mass: (3n, 3n) consistent mass matrix M in kg (node-major, input order).
        r: number of basis vectors, 1 ≤ r ≤ numerical rank of the k + p vectors.
        keep_linear: keep the linear modes exactly (see the module docstring).

    Returns:
        :class:`NonlinearBasis` with U (3n, r), ``UᵀMU = I``.

    Raises:
        LbshapeError: bad r (more than the available vectors or their rank) or
            inconsistent shapes.
        SolverError: ``UᵀMU`` differs from I by more than ``ORTHONORMALITY_TOL``.
    """
    Phi, Psi, omega2 = _check_inputs(modes, derivatives, mass)
    k, p = Phi.shape[1], Psi.shape[1]
    if isinstance(r, bool) or not isinstance(r, int | np.integer) or r < 1:
        raise LbshapeError(f"r must be an integer >= 1, got {r!r}")
    if r > k + p:
        raise LbshapeError(f"r={r} exceeds the {k + p} vectors available "
                           f"({k} linear modes + {p} modal derivatives)")
    lowest = omega2.min()
    linear_scale = lowest / omega2
    pairs = derivatives.pairs
    derivative_scale = lowest**2 / (omega2[pairs[:, 0]] * omega2[pairs[:, 1]])
    X_lin, X_der = Phi * linear_scale, Psi * derivative_scale

    if keep_linear:
        order = np.argsort(-linear_scale, kind="stable")
        X_der = X_der - Phi @ (Phi.T @ (mass @ X_der))
        X_der = X_der - Phi @ (Phi.T @ (mass @ X_der))  # twice is enough
        components, sv = _principal(X_der, mass)
        singular = np.concatenate([linear_scale[order], sv])
        if r <= k:
            U = Phi[:, order[:r]]
        else:
            _check_rank(r, k + _rank(sv), k, p)
            U = np.hstack([Phi[:, order], components[:, : r - k]])
    else:
        components, singular = _principal(np.hstack([X_lin, X_der]), mass)
        _check_rank(r, _rank(singular), k, p)
        U = components[:, :r]
    U = _reorthonormalise(U, mass)
    error = float(np.abs(U.T @ (mass @ U) - np.eye(r)).max())
    if error > ORTHONORMALITY_TOL:
        raise SolverError(f"basis is not mass-orthonormal: max |U^T M U - I| = {error:.2e} "
                          f"> {ORTHONORMALITY_TOL:.0e}")
    rayleigh = (np.einsum("ij,ij->j", U, modes.stiffness @ U)
                if modes.stiffness is not None else np.full(r, np.nan))
    log.info("nonlinear basis: r=%d from %d modes + %d derivatives (keep_linear=%s), "
             "orthonormality error %.1e", r, k, p, keep_linear, error)
    return NonlinearBasis(U=U, singular_values=singular, r=int(r), omega2=rayleigh,
                          n_linear=k, n_derivatives=p)


def _check_inputs(modes: LinearModes, derivatives: ModalDerivatives, mass):
    if modes.vectors is None:
        raise LbshapeError("the linear modes hold no vectors (not rank 0 of a parallel run)")
    Phi = np.asarray(modes.vectors, dtype=np.float64)
    Psi = np.asarray(derivatives.vectors, dtype=np.float64)
    omega2 = np.asarray(modes.omega2, dtype=np.float64)
    size = Phi.shape[0]
    if Psi.shape[0] != size or mass.shape != (size, size):
        raise LbshapeError(f"inconsistent sizes: modes {Phi.shape}, derivatives {Psi.shape}, "
                           f"mass {mass.shape}")
    if omega2.shape != (Phi.shape[1],) or not (omega2 > 0).all():
        raise LbshapeError("modes.omega2 must hold one positive value per mode")
    pairs = np.asarray(derivatives.pairs)
    if pairs.shape != (Psi.shape[1], 2) or (Psi.shape[1] and pairs.max() >= Phi.shape[1]):
        raise LbshapeError(f"derivative pairs {pairs.shape} do not match "
                           f"{Psi.shape[1]} derivatives of {Phi.shape[1]} modes")
    return Phi, Psi, omega2


def _principal(X: np.ndarray, mass) -> tuple[np.ndarray, np.ndarray]:
    """M-orthonormal principal components (3n, c) and singular values (m,) of X (3n, m).

    Only components with singular value > RANK_RTOL × the largest are returned.
    """
    if X.shape[1] == 0:
        return X[:, :0], np.zeros(0)
    gram = X.T @ (mass @ X)
    w, V = np.linalg.eigh(0.5 * (gram + gram.T))
    w, V = w[::-1], V[:, ::-1]
    singular = np.sqrt(np.clip(w, 0.0, None))
    rank = _rank(singular)
    return X @ (V[:, :rank] / singular[:rank]), singular


def _rank(singular: np.ndarray) -> int:
    if singular.size == 0 or singular[0] == 0.0:
        return 0
    return int(np.count_nonzero(singular > RANK_RTOL * singular[0]))


def _check_rank(r: int, rank: int, k: int, p: int) -> None:
    if r > rank:
        raise LbshapeError(f"r={r} exceeds the numerical rank {rank} of the {k + p} vectors "
                           f"available ({k} linear modes + {p} modal derivatives); "
                           f"use r <= {rank} or more linear modes")


def _reorthonormalise(U: np.ndarray, mass) -> np.ndarray:
    """One Löwdin pass ``U (UᵀMU)^(-1/2)``: removes the round-off left by the Gram route."""
    gram = U.T @ (mass @ U)
    w, Q = np.linalg.eigh(0.5 * (gram + gram.T))
    if w.min() <= 0.5:
        raise SolverError(f"basis vectors are nearly dependent (Gram eigenvalues "
                          f"{w.min():.2e} .. {w.max():.2e})")
    return U @ (Q @ np.diag(w**-0.5) @ Q.T)
