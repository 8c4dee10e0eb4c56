"""Sparse Cholesky factorisation and block solves through PETSc (CHOLMOD where PETSc
has SuiteSparse and the matrix is serial, else MUMPS;
:func:`~lbshape.fem.eigenproblem.factor_package`)."""

from __future__ import annotations

import contextlib

import numpy as np

from lbshape.errors import SolverError
from lbshape.fem.eigenproblem import factor_package


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
        if count == 0:
            return np.zeros((rows, 0))
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



@contextlib.contextmanager
def serial_cholesky(A, *, prefix: str = "", what: str = "the matrix"):
    """``with serial_cholesky(A) as solve:`` one Cholesky factorisation (CHOLMOD) of a
    serial symmetric positive definite scipy matrix A (n, n); ``solve(rhs)`` gives X
    (n, c) with ``A X = rhs`` for rhs (n, c), as often as needed; everything is destroyed
    on leaving the block.

    Raises:
        SolverError: A is singular or not positive definite.
    """
    import scipy.sparse as sp
    from petsc4py import PETSc

    A = sp.csr_matrix(A)
    matrix = PETSc.Mat().createAIJ(
        size=A.shape, csr=(A.indptr.astype(PETSc.IntType), A.indices.astype(PETSc.IntType),
                           A.data), comm=PETSc.COMM_SELF)
    solver = None
    try:
        solver = CholeskySolver(matrix, prefix=prefix, what=what)
        yield lambda rhs: solver.solve(np.asarray(rhs, dtype=float).reshape(A.shape[0], -1))
    finally:
        if solver is not None:
            solver.destroy()
        matrix.destroy()
