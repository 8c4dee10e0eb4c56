"""Shared pieces of the symmetric generalized eigenproblems ``A x = λ B x`` (SLEPc).

Used by the LB spectrum (:mod:`lbshape.spectral.spectrum`) and the linear elastic modes
(:mod:`lbshape.elastic.modes`): one checked shift-and-invert configuration, reading the
converged pairs out of SLEPc with a loud convergence check, and the
post-processing every eigenpair set gets (B-orthonormalisation, a deterministic
sign, relative residuals and their check, which the modal derivative solves share).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import scipy.sparse as sp

from lbshape.errors import LbshapeError, SolverError

#: a column's sign is fixed at its first entry with |x| ≥ (1 − SIGN_RTOL) max|x|
SIGN_RTOL = 1e-6


def check_tol_and_target(tol: float, target: float | None) -> None:
    """A SLEPc tolerance in (0, 1) and a shift-and-invert target σ < 0 (or None: default).

    Raises:
        LbshapeError: either is out of range.
    """
    if not (0.0 < tol < 1.0):
        raise LbshapeError(f"tol must be in (0, 1), got {tol!r}")
    if target is not None and not (math.isfinite(target) and target < 0.0):
        raise LbshapeError(f"target must be a finite negative number, got {target!r}")


def shift_invert_eps(A, B, *, comm, prefix: str, nev: int, sigma: float, tol: float,
                     factor: str):
    """A Krylov-Schur GHEP solver for the ``nev`` pairs nearest ``sigma``.

    Shift-and-invert with a direct Cholesky factorisation (``factor``: a PETSc
    solver package such as ``"mumps"``), options prefix ``prefix`` applied last so
    command-line options override. The caller owns the returned ``SLEPc.EPS`` and
    must ``destroy()`` it.
    """
    from slepc4py import SLEPc

    eps = SLEPc.EPS().create(comm)
    eps.setOptionsPrefix(prefix)
    eps.setOperators(A, B)
    eps.setProblemType(SLEPc.EPS.ProblemType.GHEP)
    eps.setType(SLEPc.EPS.Type.KRYLOVSCHUR)
    eps.setDimensions(nev=nev)
    eps.setTarget(sigma)
    eps.setWhichEigenpairs(SLEPc.EPS.Which.TARGET_MAGNITUDE)
    eps.setTolerances(tol=tol, max_it=1000)
    st = eps.getST()
    st.setType(SLEPc.ST.Type.SINVERT)
    st.setShift(sigma)
    ksp = st.getKSP()
    ksp.setType("preonly")
    pc = ksp.getPC()
    pc.setType("cholesky")
    pc.setFactorSolverType(factor)
    return eps


def converged_pairs(eps, *, nev: int, what: str, tol: float,
                    sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """The converged pairs of a solved ``eps``: never taken on trust.

    Args:
        eps: a solved ``SLEPc.EPS`` (not destroyed here).
        nev: the number of pairs that must have converged.
        what: the solver's name for the error message (e.g. ``"LB eigensolver"``).
        tol: the tolerance used, for the message.
        sigma: the shift-and-invert target, for the message.

    Returns:
        values (c,) real eigenvalues in SLEPc's order and the owned rows (l, c) of the
        eigenvectors, with c ≥ ``nev`` the converged count.

    Raises:
        SolverError: fewer than ``nev`` pairs converged (with SLEPc's reason).
    """
    n_converged = eps.getConverged()
    if n_converged < nev:
        raise SolverError(
            f"{what} converged {n_converged} of {nev} requested pairs "
            f"({reason_name(eps.getConvergedReason())}, {eps.getIterationNumber()} "
            f"iterations, tol={tol:g}, target={sigma:.3e})"
        )
    values = np.empty(n_converged)
    vr = eps.getOperators()[0].createVecRight()
    try:
        local = np.empty((vr.getLocalSize(), n_converged))
        for i in range(n_converged):
            values[i] = eps.getEigenpair(i, vr).real
            local[:, i] = vr.getArray(readonly=True)
    finally:
        vr.destroy()
    return values, local


def reason_name(reason: int) -> str:
    """The name of a SLEPc ``EPS.ConvergedReason`` value."""
    from slepc4py import SLEPc

    names = {v: k for k, v in vars(SLEPc.EPS.ConvergedReason).items() if k.isupper()}
    return names.get(int(reason), f"reason {int(reason)}")


def b_orthonormalise(vectors: np.ndarray, B: sp.spmatrix, *, what: str) -> np.ndarray:
    """Löwdin: ``X G^(-1/2)`` with ``G = XᵀBX``; X (n, k) -> B-orthonormal (n, k)."""
    gram = vectors.T @ (B @ vectors)
    gram = 0.5 * (gram + gram.T)
    w, q = np.linalg.eigh(gram)
    if w.min() <= 1e-8 * w.max():
        raise SolverError(
            f"{what} are linearly dependent (Gram eigenvalues {w.min():.2e} .. {w.max():.2e})"
        )
    return vectors @ (q @ np.diag(w ** -0.5) @ q.T)


def fix_signs(vectors: np.ndarray) -> np.ndarray:
    """Make each column positive at its first entry with ``|x| ≥ (1−SIGN_RTOL) max|x|``."""
    mag = np.abs(vectors)
    first = np.argmax(mag >= (1.0 - SIGN_RTOL) * mag.max(axis=0), axis=0)
    signs = np.sign(vectors[first, np.arange(vectors.shape[1])])
    signs[signs == 0] = 1.0
    return vectors * signs


def relative_residuals(A, B, values: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """(k,) ``‖Ax − λBx‖ / (|λ|‖Bx‖ + ‖Ax‖)`` per column."""
    AV, BV = A @ vectors, B @ vectors
    num = np.linalg.norm(AV - BV * values, axis=0)
    den = np.abs(values) * np.linalg.norm(BV, axis=0) + np.linalg.norm(AV, axis=0)
    return num / den


def check_residuals(residuals: np.ndarray, limit: float, *, what: str,
                    describe: Callable[[int], str]) -> None:
    """Raise if any relative residual exceeds ``limit``.

    Args:
        residuals: (k,) relative residuals (dimensionless).
        limit: the largest accepted residual.
        what: the items checked, e.g. ``"LB eigenpairs"``.
        describe: ``describe(i)`` names item i in the message (e.g. ``"pair 3, lambda=…"``).

    Raises:
        SolverError: naming how many exceed ``limit`` and the worst one.
    """
    residuals = np.asarray(residuals)
    bad = residuals > limit
    if bad.any():
        worst = int(np.argmax(residuals))
        raise SolverError(
            f"{what} with large residuals: {int(bad.sum())} of {residuals.size} exceed "
            f"{limit:.1e} (worst: {describe(worst)}, residual {residuals[worst]:.2e})"
        )


def factor_package(comm) -> str:
    """The sparse Cholesky package used by default: ``"cholmod"`` (serial; at 30k
    vertices the elastic modes took 27 s with it against 46 s with MUMPS, its solves
    are 2-3 times faster) or ``"mumps"`` (distributed, or without SuiteSparse)."""
    from petsc4py import PETSc

    if comm.size == 1 and PETSc.Sys.hasExternalPackage("suitesparse"):
        return "cholmod"
    return "mumps"
