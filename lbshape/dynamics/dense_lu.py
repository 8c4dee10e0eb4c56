"""The free body's dense Newton matrix, factorised by LAPACK (:class:`DenseLU`).

A free body's deformation solve (:mod:`lbshape.dynamics.free_body`) has the Newton
matrix ``base + K`` (r, r): ``base = c_a/Δt² I + c_v/Δt (D + Γ(ω₁))`` and K the
tangent of the elastic, example, fictitious and contact forces. The Coriolis matrix Γ
is skew, so the matrix is not symmetric and is solved by LU with partial pivoting. The
friction's effective rate (:mod:`lbshape.dynamics.free_body_contact`) factorises the
same matrix at the end of a sweep and solves it for six right-hand sides.

The factorisation, r³ work, is LAPACK's ``dgetrf`` (SciPy's wrapper) in place on one
preallocated Fortran-ordered array; the sum ``base + K`` into it and the solves, r² work
each, are compiled (:func:`sum_into`, :func:`lu_substitute_rows`), so nothing of size
r × r is allocated. At r = 58 (a bar with its 26 impact columns) a factorisation and
solve take about half the time of a compiled textbook LU (``docs/decisions.md``, "The
free body's Newton matrix by LAPACK"). OpenBLAS's ``dgetrf`` gave bit-identical factors
on one and two threads up to r = 90 and differed at round-off at r = 150; its
many-right-hand-side ``dgetrs`` differed already at r = 32, hence the compiled
substitutions.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import lapack

from lbshape._jit import njit


class DenseLU:
    """LU factors of ``base + K`` (r, r) and solves with them (no allocation but
    LAPACK's pivot vector).

    Args:
        r: the size of the matrices.
    """

    def __init__(self, r: int):
        self.r = int(r)
        #: (r, r) Fortran-ordered: ``base + K``, then (dgetrf in place) its factors
        self._factors = np.zeros((self.r, self.r), order="F")
        self._pivots = np.arange(self.r, dtype=np.int32)

    def factor(self, base: np.ndarray, K: np.ndarray) -> bool:
        """Factorise ``base + K`` (both (r, r)); False if it is singular or not finite
        (the factors are then not to be used)."""
        sum_into(base, K, self._factors)
        # in place for a Fortran-ordered float64 array (SciPy returns that array)
        self._factors, self._pivots, info = lapack.dgetrf(self._factors, overwrite_a=1)
        return info == 0 and finite_diagonal(self._factors)

    def solve_into(self, rhs: np.ndarray, out: np.ndarray) -> None:
        """``out = (base + K)⁻¹ rhs`` (r,) with the last factors."""
        out[:] = rhs
        lu_substitute_rows(self._factors, self._pivots, out.reshape(1, self.r))

    def solve_rows_into(self, rows: np.ndarray, out: np.ndarray) -> None:
        """``out[m] = (base + K)⁻¹ rows[m]`` for each row of ``rows`` (M, r) with the last
        factors; ``out`` (M, r) C-ordered."""
        out[:] = rows
        lu_substitute_rows(self._factors, self._pivots, out)


@njit
def sum_into(a, b, out):
    """``out = a + b`` (n, n), column by column (``out`` Fortran-ordered)."""
    n = out.shape[0]
    for j in range(n):
        for i in range(n):
            out[i, j] = a[i, j] + b[i, j]


@njit
def finite_diagonal(A):
    """Whether every diagonal entry of A (n, n) is finite."""
    for i in range(A.shape[0]):
        if not np.isfinite(A[i, i]):
            return False
    return True


@njit
def lu_substitute_rows(factors, pivots, rows):
    """rows[m] ← A⁻¹ rows[m] for each row of ``rows`` (M, n), in place, A = P L U as
    LAPACK's ``dgetrf`` gives it (:class:`DenseLU`): ``factors`` (n, n) L (unit, below
    the diagonal) and U, ``pivots`` (n,) its row interchanges (0-based, as SciPy returns
    them). Compiled rather than ``dgetrs``: the same answer on any BLAS thread count."""
    n = factors.shape[0]
    for m in range(rows.shape[0]):
        x = rows[m]
        for i in range(n):
            p = pivots[i]
            if p != i:
                x[i], x[p] = x[p], x[i]
        for i in range(1, n):
            value = x[i]
            for j in range(i):
                value -= factors[i, j] * x[j]
            x[i] = value
        for i in range(n - 1, -1, -1):
            value = x[i]
            for j in range(i + 1, n):
                value -= factors[i, j] * x[j]
            x[i] = value / factors[i, i]

