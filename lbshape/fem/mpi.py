"""MPI helpers: compute on rank 0 and share the result (or its user error) with every
rank; split a loop of ``count`` items across ranks and sum the parts."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from lbshape.errors import LbshapeError


def compute_on_root(comm, compute: Callable[[], Any], *, share: bool = True):
    """``compute()`` on rank 0 only; its result broadcast to every rank if ``share``.

    A :class:`~lbshape.errors.LbshapeError` raised by ``compute`` on rank 0 is
    broadcast and raised on every rank, so no rank waits for the others forever.

    Args:
        comm: the communicator (``mpi4py.MPI.Comm``).
        compute: a function of no arguments, called on rank 0.
        share: broadcast the result; otherwise the other ranks get ``None``.
    """
    value = error = None
    if comm.rank == 0:
        try:
            value = compute()
        except LbshapeError as exc:
            error = exc
    shared, error = comm.bcast((value if share else None, error), root=0)
    if error is not None:
        raise error
    return shared if share else value


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
