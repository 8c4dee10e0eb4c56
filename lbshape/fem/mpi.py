"""MPI helpers: compute on rank 0 and share the result (or its user error) with every
rank; split a loop of ``count`` items across ranks and sum the parts.

**Rank-0-only work and PETSc/SLEPc.** The first import of ``petsc4py.PETSc`` in a
process initialises PETSc, and that initialisation is collective over
``MPI.COMM_WORLD``; so is the finalisation of SLEPc at exit when ``slepc4py.SLEPc``
was imported. Work done on rank 0 alone that imports either for the first time
(``import dolfinx`` does) therefore meets the other ranks' next collective call
with a mismatched one: a hang, or a corrupted broadcast. :func:`start_solvers`
imports both on every rank; :func:`compute_on_root` calls it first, so rank-0 work
never starts PETSc on its own.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from lbshape.errors import LbshapeError

#: seconds between two checks of a rank waiting for rank 0 (it sleeps in between)
IDLE_POLL_SECONDS = 0.005


def start_solvers() -> None:
    """Initialise PETSc and SLEPc in this process (collective over ``COMM_WORLD`` the
    first time; a no-op afterwards). Call it on every rank before rank-0-only work."""
    import petsc4py.PETSc  # noqa: F401
    import slepc4py.SLEPc  # noqa: F401


def compute_on_root(comm, compute: Callable[[], Any], *, share: bool = True):
    """``compute()`` on rank 0 only; its result broadcast to every rank if ``share``.

    A :class:`~lbshape.errors.LbshapeError` raised by ``compute`` on rank 0 is
    broadcast and raised on every rank, so no rank waits for the others forever.
    With several ranks, PETSc and SLEPc are started on every rank first
    (:func:`start_solvers`), and the other ranks wait asleep (a non-blocking barrier
    polled every :data:`IDLE_POLL_SECONDS`), leaving their cores to rank 0.

    Args:
        comm: the communicator (``mpi4py.MPI.Comm``).
        compute: a function of no arguments, called on rank 0.
        share: broadcast the result; otherwise the other ranks get ``None``.
    """
    if comm.size > 1:
        start_solvers()
    value = error = None
    if comm.rank == 0:
        try:
            value = compute()
        except LbshapeError as exc:
            error = exc
    if comm.size > 1:
        _idle_barrier(comm)
    shared, error = comm.bcast((value if share else None, error), root=0)
    if error is not None:
        raise error
    return shared if share else value


def _idle_barrier(comm) -> None:
    """A barrier in which a waiting rank sleeps instead of spinning on its core."""
    request = comm.Ibarrier()
    while not request.Test():
        time.sleep(IDLE_POLL_SECONDS)


def run_collectively(comm, read_inputs: Callable[[], Any], solve: Callable[[Any], Any]):
    """``(inputs, solve(inputs))`` with the inputs read on rank 0 only.

    An input error on rank 0 is broadcast so every rank stops; a user error is
    reported (raised) by rank 0 alone, the other ranks exit with its code.
    ``inputs`` is ``None`` on the other ranks.
    """
    try:
        inputs = compute_on_root(comm, read_inputs, share=False)
        return inputs, solve(inputs)
    except LbshapeError as exc:
        if comm.rank == 0:
            raise
        raise SystemExit(exc.exit_code) from None


def rank_share(comm, count: int) -> range:
    """This rank's contiguous block of ``range(count)`` (all of it without ``comm``).

    Blocks differ in length by at most one and are ordered by rank, so concatenating
    every rank's results in rank order gives the serial order.
    """
    if comm is None or comm.size == 1:
        return range(count)
    base, extra = divmod(count, comm.size)
    start = comm.rank * base + min(comm.rank, extra)
    return range(start, start + base + (comm.rank < extra))


def sum_over_ranks(comm, value):
    """The sum of ``value`` (a number or ndarray, same shape on every rank) over all
    ranks, on every rank; ``value`` itself without ``comm`` or on one rank."""
    if comm is None or comm.size == 1:
        return value
    from mpi4py import MPI

    if isinstance(value, np.ndarray):
        total = np.empty_like(value)
        comm.Allreduce(np.ascontiguousarray(value), total, op=MPI.SUM)
        return total
    return comm.allreduce(value, op=MPI.SUM)
