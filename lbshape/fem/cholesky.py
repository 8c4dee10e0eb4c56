"""Sparse Cholesky factorisation and block solves through PETSc (CHOLMOD where PETSc
has SuiteSparse and the matrix is serial, else MUMPS;
:func:`~lbshape.fem.eigenproblem.factor_package`)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from lbshape.errors import SolverError
from lbshape.fem.eigenproblem import factor_package

#: largest accepted ``‖A X − B‖ / ‖B‖`` of :func:`cholesky_solve` (a backward-stable
#: factorisation lands near machine precision)
RESIDUAL_TOL = 1e-8


class CholeskySolver:
    """One Cholesky factorisation of a symmetric positive definite PETSc matrix, serial
    or distributed (the matrix is not owned; call :meth:`destroy`).

    Args:
        A: ``petsc4py.PETSc.Mat`` (AIJ), SPD.
        prefix: PETSc options prefix of the KSP (command-line options override).
        what: what is factorised, for error messages.

    Raises:
        SolverError: the factorisation failed (singular or not positive definite).
    """

    def __init__(self, A, *, prefix: str = "", what: str = "the matrix"):
        from petsc4py import PETSc

        self._what = what
        self._ksp = PETSc.KSP().create(A.getComm())
        self._ksp.setOptionsPrefix(prefix)
        self._ksp.setOperators(A)
        self._ksp.setType("preonly")
        pc = self._ksp.getPC()
        pc.setType("cholesky")
        pc.setFactorSolverType(factor_package(A.getComm()))
        self._ksp.setFromOptions()
        try:
            self._ksp.setUp()
        except PETSc.Error as exc:
            self.destroy()
            raise SolverError(f"Cholesky factorisation of {what} failed: singular or not "
                              f"positive definite (PETSc error "
                              f"{getattr(exc, 'ierr', '?')})") from None

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """X (l, c) for this rank's rows (l, c) of c right-hand sides, in one block solve."""
        from petsc4py import PETSc

        rows, count = rhs.shape
        comm = self._ksp.getComm()
        sizes = [(rows, PETSc.DECIDE), (PETSc.DECIDE, count)]
        B = PETSc.Mat().createDense(sizes, array=np.asfortranarray(rhs), comm=comm)
        X = PETSc.Mat().createDense(sizes, comm=comm)
        try:
            B.assemble()
            X.setUp()
            X.assemble()
            try:
                self._ksp.getPC().getFactorMatrix().matSolve(B, X)
            except PETSc.Error as exc:
                raise SolverError(f"solve with {self._what} failed ({exc})") from None
            return X.getDenseArray().copy()
        finally:
            B.destroy()
            X.destroy()

    def destroy(self) -> None:
        if self._ksp is not None:
            self._ksp.destroy()
            self._ksp = None


def cholesky_solve(matrix: sp.spmatrix, rhs: np.ndarray) -> np.ndarray:
    """X with ``A X = B`` for a serial SciPy SPD matrix A, one factorisation.

    SuperLU (``scipy.sparse.linalg.splu``) fills in badly on 3-D elasticity: at 18.6k
    vertices it took 18 s and grew as n^1.9; CHOLMOD took 2.2 s.

    Args:
        matrix: (l, l) SPD sparse matrix A (any SciPy format).
        rhs: (l,) or (l, c) right-hand sides B.

    Returns:
        X of the shape of ``rhs``.

    Raises:
        SolverError: the factorisation failed, or the solution's relative residual
            exceeds :data:`RESIDUAL_TOL`.
    """
    from petsc4py import PETSc

    A = sp.csr_matrix(matrix, dtype=float)
    B = np.asarray(rhs, dtype=float)
    columns = B.reshape(A.shape[0], -1)
    if columns.shape[1] == 0:
        return np.zeros_like(B)
    mat = PETSc.Mat().createAIJ(size=A.shape, comm=PETSc.COMM_SELF, csr=(
        A.indptr.astype(PETSc.IntType), A.indices.astype(PETSc.IntType), A.data))
    mat.setOption(PETSc.Mat.Option.SYMMETRIC, True)
    try:
        solver = CholeskySolver(mat)
        try:
            solution = solver.solve(columns)
        finally:
            solver.destroy()
    finally:
        mat.destroy()
    residual = np.linalg.norm(A @ solution - columns) if np.isfinite(solution).all() \
        else np.inf
    if not residual <= RESIDUAL_TOL * max(np.linalg.norm(columns), np.finfo(float).tiny):
        raise SolverError(f"sparse Cholesky solve failed: relative residual {residual:.1e}")
    return solution.reshape(B.shape)
