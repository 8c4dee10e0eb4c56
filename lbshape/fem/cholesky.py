"""Sparse Cholesky solves of a serial SciPy matrix through PETSc (CHOLMOD where PETSc
has SuiteSparse, else MUMPS; :func:`~lbshape.fem.eigenproblem.factor_package`)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from lbshape.errors import SolverError
from lbshape.fem.eigenproblem import factor_package

#: largest accepted ``‖A X − B‖ / ‖B‖`` (a backward-stable factorisation of an SPD matrix
#: lands near machine precision; an indefinite one that CHOLMOD does not refuse, far off)
RESIDUAL_TOL = 1e-8


def cholesky_solve(matrix: sp.spmatrix, rhs: np.ndarray) -> np.ndarray:
    """X with ``A X = B`` for a symmetric positive definite A, one factorisation.

    SuperLU (``scipy.sparse.linalg.splu``) fills in badly on 3-D elasticity: at 18.6k
    vertices it took 18 s and grew as n^1.9; a supernodal Cholesky does not.

    Args:
        matrix: (l, l) SPD sparse matrix A (any SciPy format).
        rhs: (l,) or (l, c) right-hand sides B.

    Returns:
        X of the shape of ``rhs``.

    Raises:
        SolverError: the factorisation failed, or the solution's relative residual
            exceeds :data:`RESIDUAL_TOL` (A not positive definite).
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
    ksp = PETSc.KSP().create(PETSc.COMM_SELF)
    dense_b = PETSc.Mat().createDense(columns.shape, array=np.asfortranarray(columns),
                                      comm=PETSc.COMM_SELF)
    dense_x = PETSc.Mat().createDense(columns.shape, comm=PETSc.COMM_SELF)
    try:
        ksp.setOperators(mat)
        ksp.setType("preonly")
        pc = ksp.getPC()
        pc.setType("cholesky")
        pc.setFactorSolverType(factor_package(PETSc.COMM_SELF))
        dense_b.assemble()
        dense_x.setUp()
        dense_x.assemble()
        try:
            ksp.setUp()
            pc.getFactorMatrix().matSolve(dense_b, dense_x)
        except PETSc.Error as exc:
            raise SolverError(f"sparse Cholesky factorisation failed: the matrix is "
                              f"singular or not positive definite (PETSc error "
                              f"{getattr(exc, 'ierr', '?')})") from None
        solution = dense_x.getDenseArray().copy()
    finally:
        for item in (ksp, mat, dense_b, dense_x):
            item.destroy()
    residual = np.linalg.norm(A @ solution - columns) if np.isfinite(solution).all() \
        else np.inf
    if not residual <= RESIDUAL_TOL * max(np.linalg.norm(columns), np.finfo(float).tiny):
        raise SolverError(f"sparse Cholesky solve failed: relative residual {residual:.1e} "
                          f"(the matrix is not positive definite?)")
    return solution.reshape(B.shape)
