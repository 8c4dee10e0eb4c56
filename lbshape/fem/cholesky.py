"""Sparse Cholesky factorisation and block solves through PETSc (CHOLMOD where PETSc
has SuiteSparse and the matrix is serial, else MUMPS;
:func:`~lbshape.fem.eigenproblem.factor_package`), and a sparse LDLᵀ factor kept as plain
arrays (:class:`StoredLDL`: made once, stored with the precompute, solved later in another
process without a factorisation)."""

from __future__ import annotations

import contextlib

import numpy as np

from lbshape._jit import njit
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


class StoredLDL:
    """A sparse ``A = P L D Lᵀ Pᵀ`` factor of a symmetric positive definite matrix as plain
    arrays, so that it can be saved with the precompute and solved in a later process
    (PETSc's factors cannot be saved).

    Made by SuperLU (scipy) in its symmetric mode: a fill-reducing minimum-degree ordering
    of ``Aᵀ + A``, no pivoting (A is SPD), so its ``U`` is ``D Lᵀ`` and only the strictly
    lower part of L and the pivots D are kept. A solve is two compiled sweeps over L.

    Args:
        indptr, indices, data: the strictly lower part of the unit lower factor L (n, n),
            CSC.
        pivots: (n,) D, all > 0.
        order: (n,) int: row i of the permuted system is row ``order[i]`` of A.
    """

    def __init__(self, indptr: np.ndarray, indices: np.ndarray, data: np.ndarray,
                 pivots: np.ndarray, order: np.ndarray):
        self.indptr = np.ascontiguousarray(indptr, dtype=np.int64)
        self.indices = np.ascontiguousarray(indices, dtype=np.int64)
        self.data = np.ascontiguousarray(data, dtype=float)
        self.pivots = np.ascontiguousarray(pivots, dtype=float)
        self.order = np.ascontiguousarray(order, dtype=np.int64)

    @classmethod
    def factor(cls, A, *, what: str = "the matrix") -> StoredLDL:
        """The factor of the SPD scipy matrix A (n, n).

        Raises:
            SolverError: A is singular or not positive definite.
        """
        import scipy.sparse as sp
        import scipy.sparse.linalg as sla

        try:
            lu = sla.splu(sp.csc_matrix(A), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                          options={"SymmetricMode": True})
        except RuntimeError as exc:
            raise SolverError(f"LDLᵀ factorisation of {what} failed ({exc})") from None
        pivots = lu.U.diagonal()
        if not np.array_equal(lu.perm_r, lu.perm_c) or not np.all(pivots > 0):
            raise SolverError(f"LDLᵀ factorisation of {what} failed: not symmetric positive "
                              f"definite")
        lower = sp.tril(lu.L, -1).tocsc()
        return cls(lower.indptr, lower.indices, lower.data, pivots, np.argsort(lu.perm_c))

    def arrays(self, prefix: str) -> dict[str, np.ndarray]:
        """The stored form, names ``<prefix>indptr`` … (:meth:`from_arrays`)."""
        return {prefix + name: getattr(self, name)
                for name in ("indptr", "indices", "data", "pivots", "order")}

    @classmethod
    def from_arrays(cls, arrays: dict, prefix: str) -> StoredLDL | None:
        """Inverse of :meth:`arrays`; None where ``arrays`` holds no factor under ``prefix``."""
        if prefix + "pivots" not in arrays:
            return None
        return cls(*(arrays[prefix + name]
                     for name in ("indptr", "indices", "data", "pivots", "order")))

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """x (n,) with ``A x = rhs`` for rhs (n,)."""
        return _ldl_solve(self.indptr, self.indices, self.data, self.pivots, self.order,
                          np.ascontiguousarray(rhs, dtype=float))


@njit
def _ldl_solve(indptr, indices, data, pivots, order, rhs):
    """x with ``P L D Lᵀ Pᵀ x = rhs`` (:class:`StoredLDL`'s arrays)."""
    n = rhs.shape[0]
    y = np.empty(n)
    for i in range(n):
        y[i] = rhs[order[i]]
    for j in range(n):  # L z = y, column by column
        yj = y[j]
        for p in range(indptr[j], indptr[j + 1]):
            y[indices[p]] -= data[p] * yj
    for j in range(n):
        y[j] /= pivots[j]
    for j in range(n - 1, -1, -1):  # Lᵀ w = z, row j of Lᵀ is column j of L
        s = y[j]
        for p in range(indptr[j], indptr[j + 1]):
            s -= data[p] * y[indices[p]]
        y[j] = s
    x = np.empty(n)
    for i in range(n):
        x[order[i]] = y[i]
    return x
