"""Sparse Cholesky solves through PETSc against SciPy's direct solver."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from lbshape.errors import SolverError
from lbshape.fem.cholesky import CholeskySolver, StoredLDL


def cholesky_solve(A: sp.csr_matrix, B: np.ndarray) -> np.ndarray:
    """X with A X = B through one :class:`CholeskySolver` on a serial PETSc copy of A."""
    from petsc4py import PETSc

    mat = PETSc.Mat().createAIJ(size=A.shape, comm=PETSc.COMM_SELF, csr=(
        A.indptr.astype(PETSc.IntType), A.indices.astype(PETSc.IntType), A.data))
    mat.setOption(PETSc.Mat.Option.SYMMETRIC, True)
    try:
        solver = CholeskySolver(mat, what="the test matrix")
        try:
            return solver.solve(B.reshape(A.shape[0], -1)).reshape(B.shape)
        finally:
            solver.destroy()
    finally:
        mat.destroy()


def spd_matrix(n: int, seed: int = 0) -> sp.csr_matrix:
    """A sparse SPD matrix: a 1-D Laplacian plus a random sparse Gram part."""
    rng = np.random.default_rng(seed)
    lap = sp.diags([-np.ones(n - 1), 2.0 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1])
    R = sp.random(n, n, density=0.02, random_state=rng)
    return (lap + R.T @ R + 1e-3 * sp.identity(n)).tocsr()


@pytest.mark.parametrize("shape", [(200,), (200, 5)])
def test_cholesky_solve_matches_scipy(shape):
    A = spd_matrix(200)
    B = np.random.default_rng(1).standard_normal(shape)
    X = cholesky_solve(A, B)
    assert X.shape == B.shape
    reference = spla.spsolve(A.tocsc(), B)
    assert np.allclose(X, reference.reshape(B.shape), rtol=1e-9, atol=1e-12)
    assert np.linalg.norm(A @ X - B) <= 1e-10 * np.linalg.norm(B)


def test_cholesky_solve_refuses_a_singular_matrix():
    """A Neumann 1-D Laplacian (constant null space): one-line SolverError, no garbage."""
    n = 50
    L = sp.diags([-np.ones(n - 1), 2.0 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1]).tolil()
    L[0, 0] = L[-1, -1] = 1.0
    with pytest.raises(SolverError, match="singular or not positive definite"):
        cholesky_solve(L.tocsr(), np.random.default_rng(0).standard_normal(n))


def test_no_right_hand_sides():
    assert cholesky_solve(spd_matrix(20), np.zeros((20, 0))).shape == (20, 0)


def test_serial_cholesky_vector_solves_match_the_block_solve():
    from lbshape.fem.cholesky import serial_cholesky

    A = spd_matrix(120, seed=2)
    B = np.random.default_rng(3).standard_normal((120, 3))
    with serial_cholesky(A) as solve:
        block = solve(B)
        vectors = np.column_stack([solve.vector(B[:, k]) for k in range(3)])
    assert np.allclose(vectors, block, rtol=1e-12, atol=1e-14)
    assert np.linalg.norm(A @ vectors - B) <= 1e-10 * np.linalg.norm(B)


def test_stored_ldl_solves_like_scipy_and_survives_its_arrays():
    """StoredLDL: the same solution as SciPy's direct solver (to 1e-10), and the same
    after a round trip through its arrays (what the precompute stores)."""
    A = spd_matrix(300, seed=4)
    b = np.random.default_rng(5).standard_normal(300)
    factor = StoredLDL.factor(A)
    reference = spla.spsolve(A.tocsc(), b)
    np.testing.assert_allclose(factor.solve(b), reference, rtol=1e-10, atol=1e-12)
    again = StoredLDL.from_arrays(factor.arrays("f_"), "f_")
    np.testing.assert_array_equal(again.solve(b), factor.solve(b))
    assert StoredLDL.from_arrays({}, "f_") is None
    grid = sp.diags([-np.ones(29), 2.0 * np.ones(30), -np.ones(29)], [-1, 0, 1])
    laplacian = (sp.kron(grid, sp.identity(30)) + sp.kron(sp.identity(30), grid)).tocsr()
    assert StoredLDL.factor(laplacian).data.size < 0.05 * 900 * 900  # a fill-reducing order


@pytest.mark.parametrize("shift", [-1.0, 0.0])
def test_stored_ldl_refuses_an_indefinite_or_singular_matrix(shift):
    A = sp.diags([2.0, 1.0, 3.0, 1.0]).tocsr() + sp.csr_matrix(
        ([shift - 1.0], ([1], [1])), shape=(4, 4))
    with pytest.raises(SolverError, match="the test matrix"):
        StoredLDL.factor(A, what="the test matrix")
