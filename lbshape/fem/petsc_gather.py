"""Distributed PETSc data -> scipy/numpy in input order on rank 0, and back.

Each rank owns a contiguous block of rows of a PETSc matrix or vector; the caller
says which *input* index (vertex, or node-major DOF) every locally owned row
stands for. Rank 0 receives everything and returns it in input order; the other
ranks return ``None``. Works unchanged in serial (one rank owns every row).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from mpi4py import MPI


def gather_csr(A, local_rows: np.ndarray, *, comm: MPI.Comm, size: int) -> sp.csr_matrix | None:
    """An assembled PETSc AIJ matrix as a (size, size) scipy CSR in input order, on rank 0.

    Args:
        A: ``petsc4py.PETSc.Mat`` (AIJ), distributed by rows over ``comm``.
        local_rows: (owned rows,) int, the input index of each locally owned row; the
            columns are renumbered with the same map gathered from every rank.
        comm: the communicator of ``A``.
        size: the global size (rows = columns) in input numbering.

    Returns:
        The scipy matrix on rank 0, ``None`` on the other ranks.
    """
    indptr, indices, data = A.getValuesCSR()
    start = A.getOwnershipRange()[0]
    parts = comm.gather((start, indptr, indices, data, np.asarray(local_rows)), root=0)
    if comm.rank != 0:
        return None
    parts.sort(key=lambda part: part[0])
    global_to_input = np.concatenate([part[4] for part in parts])
    rows = np.concatenate([np.repeat(part[4], np.diff(part[1])) for part in parts])
    cols = np.concatenate([global_to_input[part[2]] for part in parts])
    vals = np.concatenate([part[3] for part in parts])
    return sp.csr_matrix((vals, (rows, cols)), shape=(size, size))


def gather_rows(local: np.ndarray, local_rows: np.ndarray, *, comm: MPI.Comm,
                size: int) -> np.ndarray | None:
    """Locally owned rows (l, k) from every rank -> (size, k) in input order on rank 0.

    Rows that no rank owns (e.g. fixed DOFs left out of the problem) are zero.

    Args:
        local: (l, k) float values of the locally owned rows (e.g. eigenvector blocks).
        local_rows: (l,) the input index of each local row.
        comm: the communicator.
        size: the number of rows in input numbering.

    Returns:
        (size, k) float64 on rank 0, ``None`` on the other ranks.
    """
    parts = comm.gather((np.asarray(local_rows), local), root=0)
    if comm.rank != 0:
        return None
    out = np.zeros((size, local.shape[1]), dtype=np.float64)
    for rows, values in parts:
        out[rows] = values
    return out


def scatter_rows(values: np.ndarray | None, rows: np.ndarray, *, comm: MPI.Comm) -> np.ndarray:
    """The rows ``values[rows]`` each rank asks for, from rank 0's (size, k) array.

    The inverse of :func:`gather_rows`: rank 0 holds the whole array in input order
    (the other ranks pass ``None``); each rank receives only the rows it lists
    (e.g. the input index of every local dof, ghosts included).

    Args:
        values: (size, k) or (size,) on rank 0, ``None`` (ignored) on the other ranks.
        rows: (l,) int, the input indices this rank needs.
        comm: the communicator.

    Returns:
        (l, k) or (l,) float64: ``values[rows]`` on every rank.
    """
    rows = np.asarray(rows, dtype=np.int64)
    if comm.size == 1:
        return np.asarray(values, dtype=np.float64)[rows]
    wanted = comm.gather(rows, root=0)
    parts = None
    if comm.rank == 0:
        values = np.asarray(values, dtype=np.float64)
        parts = [values[r] for r in wanted]
    return comm.scatter(parts, root=0)
