"""Commands that run under MPI: read inputs on rank 0, solve on every rank."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from lbshape.errors import LbshapeError


def run_collectively(comm, read_inputs: Callable[[], Any], solve: Callable[[Any], Any]):
    """``(inputs, solve(inputs))`` with the inputs read on rank 0 only.

    An input error on rank 0 is broadcast so every rank stops; a user error is
    reported (raised) by rank 0 alone, the other ranks exit with its code.
    ``inputs`` is ``None`` on the other ranks.
    """
    try:
        error = inputs = None
        if comm.rank == 0:
            try:
                inputs = read_inputs()
            except LbshapeError as exc:
                error = exc
        error = comm.bcast(error, root=0)
        if error is not None:
            raise error
        return inputs, solve(inputs)
    except LbshapeError as exc:
        if comm.rank == 0:
            raise
        raise SystemExit(exc.exit_code) from None
