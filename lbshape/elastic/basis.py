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

**Response vectors** (keyword ``responses``; solved with the modal derivatives'
factorisation, :func:`lbshape.elastic.modal_derivatives.modal_derivatives`): the linear
static responses of the object to what drives it — each load pattern (``K x = f``)
and each example's pull (``K x = S d_k``, d_k the example pose's
displacement, S the mass its pull acts with). Linear modes and their derivatives
hold the object's low-frequency shapes; a load or an example that pulls one limb
excites a shape that is a mix of many higher modes (a leg curled about its hip while
the head stays put), which r of those vectors miss. A response enters only if
the plain basis (modes and derivatives, r vectors) leaves more than
``RESPONSE_MIN_OUTSIDE`` (5 %) of it outside its span: one it already holds would
only take a derivative's place and cost accuracy. The entering responses are kept
exactly, after the linear modes (made M-orthogonal to them, then their own M-PCA),
and the derivatives' PCA fills the remaining columns. What the threshold and the
responses change on the demo bar and the teddy is measured in
``docs/decisions.md`` ("Response vectors in the basis"; ``scripts/diagnose_accuracy.py``).

After the PCA, U is re-orthonormalised once in the M inner product (the Gram route
squares the condition number) and ``UᵀMU = I`` is checked to ``ORTHONORMALITY_TOL``.

**Sign.** Each principal component's sign follows the rule of the linear modes and LB
eigenvectors (:func:`lbshape.fem.eigenproblem.fix_signs`). The signs ``eigh`` returns
are arbitrary and change with the BLAS thread count even for an identical Gram
matrix; the cubature draws its training poses in U's coordinates, so a flipped column
would give it other poses and other elements.
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import scipy.sparse as sp

from lbshape.elastic.modal_derivatives import ModalDerivatives
from lbshape.elastic.modes import LinearModes
from lbshape.errors import LbshapeError, SolverError
from lbshape.fem.eigenproblem import fix_signs

log = logging.getLogger(__name__)

#: principal components with singular value ≤ RANK_RTOL × the block's largest are
#: numerically dependent
RANK_RTOL = 1e-6
#: a response direction whose part beyond the linear modes is below this share of its
#: M-norm adds nothing to the basis
RESPONSE_RTOL = 1e-3
#: a response enters the basis only if the modes-and-derivatives basis of the same r
#: leaves more than this share of it (M-norm) outside its span
RESPONSE_MIN_OUTSIDE = 0.05
#: an appended direction is kept if its principal component is at least this share of the
#: largest one (:func:`append_directions`)
APPEND_RTOL = 1e-2
#: a static equilibrium is appended when more than this share of it (M-norm) lies
#: outside U: the cross's equilibria lie 1–5 % outside, and appending them halves its
#: error against the full reference (``docs/decisions.md``, "Static equilibria")
EQUILIBRIUM_MIN_OUTSIDE = 1e-3
#: what :func:`append_directions` appends (each has its count ``n_<kind>``)
APPENDED_KINDS = ("static_equilibria", "example_responses", "impact_columns")
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
        n_responses: response directions kept in U (after the linear modes).
        n_static_equilibria: directions of the nonlinear static equilibria appended
            after the r columns of modes, responses and derivatives
            (:func:`append_directions`, :mod:`lbshape.elastic.static_equilibrium`).
        n_example_responses: example response directions appended after those
            (:func:`append_directions`).
        n_impact_columns: a free body's impact columns, the last columns
            (:mod:`lbshape.pipeline.impact_columns`; their force model:
            :class:`lbshape.elastic.column_forces.ColumnForceModel`).
    """

    U: np.ndarray
    singular_values: np.ndarray
    r: int
    omega2: np.ndarray
    n_linear: int
    n_derivatives: int
    n_responses: int = 0
    n_static_equilibria: int = 0
    n_example_responses: int = 0
    n_impact_columns: int = 0


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
    responses: np.ndarray | None = None,
) -> NonlinearBasis:
    """Mass-PCA basis of scaled linear modes and modal derivatives.

    Args:
        modes: k linear modes (vectors (3n, k), ω² (k,)).
        derivatives: p modal derivatives of those modes (vectors (3n, p)).
        mass: (3n, 3n) consistent mass matrix M in kg (node-major, input order).
        r: number of basis vectors, 1 ≤ r ≤ numerical rank of the k + p vectors.
        keep_linear: keep the linear modes exactly (see the module docstring).
        responses: (3n, c) response vectors (static solutions ``K x = f``) kept after the
            linear modes (only with ``keep_linear``); their numerically independent
            part beyond the modes' span takes up to ``r − k`` columns.

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
    offered = 0 if responses is None else int(np.shape(responses)[1])
    if r > k + p + offered:
        more = f" + {offered} responses" if offered else ""
        raise LbshapeError(f"r={r} exceeds the {k + p + offered} vectors available "
                           f"({k} linear modes + {p} modal derivatives{more})")
    lowest = omega2.min()
    linear_scale = lowest / omega2
    pairs = derivatives.pairs
    derivative_scale = lowest**2 / (omega2[pairs[:, 0]] * omega2[pairs[:, 1]])
    X_lin, X_der = Phi * linear_scale, Psi * derivative_scale

    kept = np.zeros((Phi.shape[0], 0))
    if responses is not None and not keep_linear:
        raise LbshapeError("response vectors need keep_linear=True")
    if keep_linear:
        order = np.argsort(-linear_scale, kind="stable")
        U, singular = _modes_first(Phi, linear_scale, order, X_der, kept, mass, r, p)
        if responses is not None and r > k:
            X = _check_responses(responses, Phi.shape[0])
            missed = _outside_share(X, U, mass) > RESPONSE_MIN_OUTSIDE
            kept = _responses_beyond(X[:, missed], Phi, mass)[:, : r - k]
            if kept.shape[1]:
                U, singular = _modes_first(Phi, linear_scale, order, X_der, kept, mass, r, p)
    else:
        components, singular = principal_components(np.hstack([X_lin, X_der]), mass)
        _check_rank(r, _rank(singular), k, p)
        U = components[:, :r]
    U = _reorthonormalise(U, mass)
    error = float(np.abs(U.T @ (mass @ U) - np.eye(r)).max())
    if error > ORTHONORMALITY_TOL:
        raise SolverError(f"basis is not mass-orthonormal: max |U^T M U - I| = {error:.2e} "
                          f"> {ORTHONORMALITY_TOL:.0e}")
    rayleigh = (np.einsum("ij,ij->j", U, modes.stiffness @ U)
                if modes.stiffness is not None else np.full(r, np.nan))
    log.info("nonlinear basis: r=%d from %d modes + %d responses + %d derivatives "
             "(keep_linear=%s), orthonormality error %.1e", r, k, kept.shape[1], p,
             keep_linear, error)
    return NonlinearBasis(U=U, singular_values=singular, r=int(r), omega2=rayleigh,
                          n_linear=k, n_derivatives=p, n_responses=int(kept.shape[1]))


def append_directions(basis: NonlinearBasis, X: np.ndarray, mass, stiffness, *,
                      kind: str = "example_responses", max_columns: int | None = None,
                      rtol: float = APPEND_RTOL,
                      min_outside: float = RESPONSE_MIN_OUTSIDE) -> NonlinearBasis:
    """The basis with the principal directions of X (3n, c) that it misses appended.

    Each column of X is normalised (M-norm 1) and its part in span U removed
    M-orthogonally; the principal components of what is left are appended when the
    largest holds more than ``min_outside`` (share of a unit column) and each one
    kept holds at least ``rtol`` of the largest, the largest first and at most
    ``max_columns`` of them (so U grows by at most c columns, by none when it already
    holds X). U stays M-orthonormal; r grows.

    Args:
        basis: the basis (U (3n, r), ``UᵀMU = I``).
        X: (3n, c) directions (the example responses,
            :func:`lbshape.pipeline.responses.example_responses`, or the static
            equilibria, :func:`lbshape.elastic.static_equilibrium.static_equilibria`).
        mass: (3n, 3n) M in kg.
        stiffness: (3n, 3n) K in N/m (the new columns' Rayleigh quotients).
        kind: what X is, one of :data:`APPENDED_KINDS`: the count ``n_<kind>`` grows.
        max_columns: at most this many columns are appended (None: no limit).
        rtol: smallest kept principal component, relative to the largest.
        min_outside: nothing is appended when the largest component is below this.

    Returns:
        The :class:`NonlinearBasis` with ``r + a`` columns and ``n_<kind>`` grown by a.
    """
    if kind not in APPENDED_KINDS:
        raise LbshapeError(f"appended directions must be one of {APPENDED_KINDS}, got {kind!r}")
    X = _check_responses(X, basis.U.shape[0])
    U = basis.U
    norms = np.sqrt(np.einsum("ij,ij->j", X, mass @ X))
    X = X[:, norms > 0] / norms[norms > 0]
    for _ in range(2):  # twice is enough
        X = X - U @ (U.T @ (mass @ X))
    components, singular = principal_components(X, mass)
    if singular.size == 0 or singular[0] <= min_outside or max_columns == 0:
        return basis
    keep = int(np.count_nonzero(singular[: components.shape[1]] >= rtol * singular[0]))
    if max_columns is not None:
        keep = min(keep, int(max_columns))
    U = _reorthonormalise(np.hstack([U, components[:, :keep]]), mass)
    rayleigh = np.einsum("ij,ij->j", U, stiffness @ U)
    log.info("nonlinear basis: %d %s directions appended (r = %d)", keep,
             kind.replace("_", " "), U.shape[1])
    count = f"n_{kind}"
    return dataclasses.replace(basis, U=U, r=int(U.shape[1]), omega2=rayleigh,
                               **{count: getattr(basis, count) + keep})


def _modes_first(Phi, linear_scale, order, X_der, kept, mass, r: int, p: int):
    """``(U, singular values)``: the linear modes (lowest first), the kept responses,
    then the principal components of the derivatives M-orthogonal to both."""
    k, c = Phi.shape[1], kept.shape[1]
    head = np.hstack([Phi, kept])
    X_der = X_der - head @ (head.T @ (mass @ X_der))
    X_der = X_der - head @ (head.T @ (mass @ X_der))  # twice is enough
    components, sv = principal_components(X_der, mass)
    singular = np.concatenate([linear_scale[order], sv])
    if r <= k:
        return Phi[:, order[:r]], singular
    _check_rank(r, k + c + _rank(sv), k, p)
    return np.hstack([Phi[:, order], kept, components[:, : r - k - c]]), singular


def _outside_share(X: np.ndarray, U: np.ndarray, mass) -> np.ndarray:
    """(c,) M-norm share of each column of X outside span U (U M-orthonormal)."""
    rest = X - U @ (U.T @ (mass @ X))
    total = np.sqrt(np.einsum("ij,ij->j", X, mass @ X))
    part = np.sqrt(np.einsum("ij,ij->j", rest, mass @ rest))
    return np.divide(part, total, out=np.zeros_like(part), where=total > 0)


def _check_responses(responses: np.ndarray, size: int) -> np.ndarray:
    X = np.asarray(responses, dtype=np.float64)
    if X.ndim != 2 or X.shape[0] != size or not np.isfinite(X).all():
        raise LbshapeError(f"responses must be a finite ({size}, c) array, got {X.shape}")
    return X


def _responses_beyond(X: np.ndarray, Phi: np.ndarray, mass) -> np.ndarray:
    """M-orthonormal principal components (3n, c') of the responses' part M-orthogonal
    to the linear modes, each response normalised first (so that none dominates by its
    units); parts below ``RANK_RTOL`` of their own size are dropped."""
    if X.shape[1] == 0:
        return X
    norms = np.sqrt(np.einsum("ij,ij->j", X, mass @ X))
    X = X[:, norms > 0] / norms[norms > 0]
    X = X - Phi @ (Phi.T @ (mass @ X))
    X = X - Phi @ (Phi.T @ (mass @ X))
    components, singular = principal_components(X, mass)
    keep = int(np.count_nonzero(singular[: components.shape[1]] > RESPONSE_RTOL))
    return components[:, :keep]


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


def principal_components(X: np.ndarray, mass) -> tuple[np.ndarray, np.ndarray]:
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
    # eigh's signs are arbitrary (see "Sign" in the module docstring)
    return fix_signs(X @ (V[:, :rank] / singular[:rank])), singular


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
