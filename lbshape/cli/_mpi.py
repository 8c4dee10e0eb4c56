"""Sub-commands under ``mpirun``: which rank prints and writes.

``eigen`` and ``modes`` distribute their solves. ``precompute`` (one scene) runs on
every rank: its solver stages are distributed, the rest runs on rank 0 while the
other ranks wait; only rank 0 shows the progress, prints the summary and writes the
cache. ``simulate`` refuses to run on more than one rank (:func:`require_one_rank`).
A user error is printed once, by rank 0 (:func:`errors_on_rank_zero`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

from lbshape.errors import LbshapeError


def world_rank_size() -> tuple[int, int]:
    """(rank, size) of ``MPI.COMM_WORLD``: (0, 1) without mpirun."""
    from mpi4py import MPI

    return MPI.COMM_WORLD.rank, MPI.COMM_WORLD.size


@contextlib.contextmanager
def errors_on_rank_zero() -> Iterator[None]:
    """A user error inside the block is printed by rank 0 only: the other ranks exit
    with its exit code silently (every rank meets the same error)."""
    try:
        yield
    except LbshapeError as exc:
        if world_rank_size()[0] == 0:
            raise
        raise SystemExit(exc.exit_code) from None


def require_one_rank(command: str) -> None:
    """Refuse to run ``command`` under ``mpirun`` with several ranks.

    Rank 0 raises a one-line :class:`LbshapeError`; the other ranks exit with the
    same code silently, so the error is printed once.
    """
    _, size = world_rank_size()
    if size > 1:
        with errors_on_rank_zero():
            raise LbshapeError(f"{command} runs on one process, not on {size} MPI ranks: "
                               "run it without mpirun (only eigen and modes are parallel)")
