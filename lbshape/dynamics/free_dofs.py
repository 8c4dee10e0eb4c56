"""The full-space engine's restriction to its free dofs: fixed vertices' indices checked,
sub-matrices of the free rows and columns, and a restriction of CSR matrices of one fixed
sparsity pattern that gathers their data without sparse re-indexing."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from lbshape.errors import LbshapeError


class CsrRestriction:
    """Restrict CSR matrices with a fixed pattern (that of ``template``) to ``dofs``.

    The rows and columns of ``dofs`` are selected by gathering the data array, so a
    call costs one fancy index of the non-zeros and no sparse re-indexing.
    """

    def __init__(self, template: sp.csr_matrix, dofs: np.ndarray):
        self._indices = template.indices
        self._indptr = template.indptr
        nnz = template.indices.size
        marker = sp.csr_matrix(
            (np.arange(1, nnz + 1, dtype=float), template.indices, template.indptr),
            shape=template.shape,
        )
        sub = marker[dofs][:, dofs].tocsr()
        sub.sort_indices()
        self._gather = sub.data.astype(np.int64) - 1
        self._sub_indices, self._sub_indptr = sub.indices, sub.indptr
        self._shape = (dofs.size, dofs.size)

    def __call__(self, matrix: sp.csr_matrix) -> sp.csr_matrix:
        if not (np.array_equal(matrix.indptr, self._indptr)
                and np.array_equal(matrix.indices, self._indices)):
            raise LbshapeError("tangent does not have the expected sparsity pattern")
        return sp.csr_matrix(
            (matrix.data[self._gather], self._sub_indices.copy(), self._sub_indptr.copy()),
            shape=self._shape,
        )


def submatrix(matrix: sp.spmatrix, dofs: np.ndarray) -> sp.csr_matrix:
    """``matrix[dofs][:, dofs]`` as CSR (any sparse matrix, square)."""
    return sp.csr_matrix(matrix.tocsr()[dofs][:, dofs])


def vertex_indices(values, n: int) -> np.ndarray:
    """Sorted unique vertex indices (k,) int64 of ``values`` checked against ``n`` vertices."""
    idx = np.asarray(values)
    if idx.size == 0:
        return np.zeros(0, dtype=np.int64)
    if idx.ndim != 1 or not np.issubdtype(idx.dtype, np.integer):
        raise LbshapeError(f"fixed vertices must be a 1-D array of integers, got {idx.dtype}")
    if idx.min() < 0 or idx.max() >= n:
        raise LbshapeError(f"fixed vertex index out of range [0, {n})")
    return np.unique(idx.astype(np.int64))
