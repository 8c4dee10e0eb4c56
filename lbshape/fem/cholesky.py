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
        self._vectors = None
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

    def solve_vector(self, rhs: np.ndarray) -> np.ndarray:
        """x (l,) for this rank's rows (l,) of one right-hand side, through vectors kept
        between calls (less overhead than :meth:`solve` for many sequential solves)."""
        from petsc4py import PETSc

        if self._vectors is None:
            self._vectors = self._ksp.getOperators()[0].createVecs()
        x, b = self._vectors
        b.getArray()[:] = rhs
        try:
            self._ksp.getPC().getFactorMatrix().solve(b, x)
        except PETSc.Error as exc:
            raise SolverError(f"solve with {self._what} failed ({exc})") from None
        return x.getArray().copy()

    def destroy(self) -> None:
        if self._vectors is not None:
            for vector in self._vectors:
                vector.destroy()
            self._vectors = None
        if self._ksp is not None:
            self._ksp.destroy()
            self._ksp = None



@contextlib.contextmanager
def serial_cholesky(A, *, prefix: str = "", what: str = "the matrix"):
    """``with serial_cholesky(A) as solve:`` one Cholesky factorisation (CHOLMOD) of a
    serial symmetric positive definite scipy matrix A (n, n); ``solve(rhs)`` gives X
    (n, c) with ``A X = rhs`` for rhs (n, c), as often as needed (``solve.vector(b)``: x (n,)
    for one rhs (n,), with less overhead per call); everything is destroyed on leaving the
    block.

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

        def solve(rhs):
            return solver.solve(np.asarray(rhs, dtype=float).reshape(A.shape[0], -1))

        solve.vector = solver.solve_vector
        yield solve
    finally:
        if solver is not None:
            solver.destroy()
        matrix.destroy()
