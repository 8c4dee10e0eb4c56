"""The cubature's element selection: greedy + NNLS (:mod:`lbshape.elastic.cubature`).

**Greedy selection + NNLS** (:func:`greedy_nnls`): at each step draw a random
batch of candidate elements, compute their columns, add the one whose column is
best aligned with the current residual (largest ``A_eᵀ res / ‖A_e‖``; scores equal to within
:data:`TIE_RTOL` go to the lowest element index, not to round-off), solve the
non-negative least squares problem on the selected columns, drop elements whose
weight became zero, and stop when the relative training error
``‖A w − b‖ / ‖b‖`` reaches ``tol`` or s elements are selected. Each NNLS solve
is optimal on its set, so the error never increases. Only when no candidate of a
batch helps is a wider set scanned (in chunks): every element when at most
:data:`FALLBACK_ELEMENTS` remain (every built-in scene but the 100k-vertex one),
else that many drawn at random (a full scan of a large mesh costs tens of seconds,
``docs/decisions.md``). The greedy steps are the
same on every rank (same seed, same draws); memory is O(P·r·(s + batch)) besides
one chunk.
"""

from __future__ import annotations

import logging

import numpy as np
from scipy.optimize import nnls

from lbshape.errors import LbshapeError, SolverError
from lbshape.fem.mpi import rank_share

log = logging.getLogger(__name__)

#: elements scanned when no candidate of a batch helps: all of them up to this many,
#: else this many drawn at random
FALLBACK_ELEMENTS = 8192
#: greedy scores within this share of the best are a tie, broken by the lowest element
#: index, so round-off (e.g. the BLAS thread count) never decides between elements whose
#: scores differ only by it
TIE_RTOL = 1e-9


def greedy_nnls(columns, b, hold_columns, b_hold, *, n_elements, s, tol, candidates, rng,
                progress, comm):
    """Greedy candidate selection + NNLS (the module docstring).

    Args:
        columns, hold_columns: the training and held-out columns of A
            (:class:`~lbshape.elastic.cubature_forces.ElementColumns`).
        b, b_hold: (P·r,) and (P'·r,) the normalised exact forces they fit.
        n_elements: E, the elements to choose from (indices ``0 .. E−1``).
        s: the largest number of elements; tol: the training error to stop at.
        candidates: elements drawn per step; rng: the generator of the draws.
        progress: show a progress bar; comm: MPI communicator or None.

    Returns:
        ``(elements (s',) int64, weights (s',) float64 >= 0, history (steps, 3))``, the
        history rows ``[number of elements, train error, holdout error]``.
    """
    b_norm, b_hold_norm = np.linalg.norm(b), np.linalg.norm(b_hold)
    selected = np.zeros(0, dtype=np.int64)
    weights = np.zeros(0)
    chosen = np.zeros((b.size, 0), order="F")  # columns of the selected elements
    chosen_hold = np.zeros((b_hold.size, 0), order="F")
    residual = b.copy()
    error = 1.0
    history = []
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=s, desc="cubature", unit="elt")
    try:
        for _ in range(10 * s):  # every step lowers the error; the cap is a safeguard
            if selected.size >= s or error <= tol:
                break
            pool = np.setdiff1d(np.arange(n_elements), selected, assume_unique=True)
            if pool.size == 0:
                break
            batch = rng.choice(pool, size=min(candidates, pool.size), replace=False)
            column = _best_aligned(columns, residual, batch)
            if column is None:  # nothing in the batch helps: look at (many) more elements
                wider = pool if pool.size <= FALLBACK_ELEMENTS else np.sort(
                    rng.choice(pool, size=FALLBACK_ELEMENTS, replace=False))
                column = _best_aligned_in_chunks(columns, residual, wider, comm)
                if column is None:
                    log.info("cubature: no remaining element reduces the error %.3g", error)
                    break
            best, A_best = column
            trial = np.append(selected, best)
            A_trial = np.column_stack([chosen, A_best])
            try:
                w, _ = nnls(A_trial, b)
            except RuntimeError as exc:
                raise SolverError(
                    f"cubature NNLS failed with {trial.size} elements: {exc}"
                ) from None
            keep = w > 0
            hold_trial = np.column_stack([chosen_hold, hold_columns(np.array([best]))])
            selected, weights = trial[keep], w[keep]
            chosen = np.asfortranarray(A_trial[:, keep])
            chosen_hold = np.asfortranarray(hold_trial[:, keep])
            residual = b - chosen @ weights
            error = float(np.linalg.norm(residual) / b_norm)
            holdout = float(np.linalg.norm(chosen_hold @ weights - b_hold) / b_hold_norm)
            history.append((selected.size, error, holdout))
            if bar is not None:
                bar.n = selected.size
                bar.set_postfix(train=f"{error:.2e}", holdout=f"{holdout:.2e}")
    finally:
        if bar is not None:
            bar.close()
    if not history:
        raise LbshapeError("cubature: no element reduces the training error")
    return selected.astype(np.int64), weights.astype(np.float64), np.asarray(history, dtype=float)


def _scores(A: np.ndarray, residual: np.ndarray) -> np.ndarray:
    """``A_eᵀ res / ‖A_e‖`` per column (0 for a zero column)."""
    norms = np.linalg.norm(A, axis=0)
    inv = np.divide(1.0, norms, out=np.zeros_like(norms), where=norms > 0)
    return (residual @ A) * inv


def _near_best(scores: np.ndarray) -> np.ndarray:
    """Mask of the scores within :data:`TIE_RTOL` of the largest (its near-ties)."""
    best = scores.max()
    return scores >= best - TIE_RTOL * abs(best)


def _best_aligned(columns, residual, candidates) -> tuple[int, np.ndarray] | None:
    """(element, column) of the candidate with the largest positive score, or None;
    of near-equal best scores (:data:`TIE_RTOL`) the lowest element index."""
    A = columns(candidates)
    scores = _scores(A, residual)
    near = np.flatnonzero(_near_best(scores))
    i = int(near[np.argmin(candidates[near])])
    return (int(candidates[i]), A[:, i].copy()) if scores.max() > 0 else None


def _best_aligned_in_chunks(columns, residual, pool, comm) -> tuple[int, np.ndarray] | None:
    """:func:`_best_aligned` over every element of ``pool``, chunk by chunk (split across
    the ranks of ``comm``): the same element for any chunking and rank count."""
    blocks = columns.chunks(pool, parts=1 if comm is None else comm.size)
    scores, elements = [np.zeros(0)], [np.zeros(0, dtype=np.int64)]
    for index in rank_share(comm, len(blocks)):
        block = _scores(columns(blocks[index]), residual)
        near = _near_best(block)  # a near-tie of the overall best is one of its block's
        scores.append(block[near])
        elements.append(np.asarray(blocks[index])[near])
    scores, elements = np.concatenate(scores), np.concatenate(elements)
    if comm is not None and comm.size > 1:
        gathered = comm.allgather((scores, elements))
        scores = np.concatenate([part[0] for part in gathered])
        elements = np.concatenate([part[1] for part in gathered])
    if scores.size == 0 or not scores.max() > 0:
        return None
    best_element = int(elements[_near_best(scores)].min())
    return best_element, columns(np.array([best_element]))[:, 0].copy()
