"""The ``lbshape`` command line: parses arguments and calls library functions.

Each sub-command lives in :mod:`lbshape.cli` as a module with
``register(subparsers)`` (adds its parser and sets ``func``). Errors from bad input
are :class:`~lbshape.errors.LbshapeError`: printed as one ``error: …`` line, never a
traceback. Exit codes, for every command: 0 done, 2 bad input
(:class:`~lbshape.errors.LbshapeError`), 3 a solver failure
(:class:`~lbshape.errors.SolverError`, or a numerical failure below lbshape's checks,
:data:`NUMERICAL_FAILURES`), 130 interrupted.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

import numpy as np
from scipy.sparse.linalg import ArpackNoConvergence

from lbshape.errors import LbshapeError, SolverError

#: numerical failures that escape lbshape's own checks: a solver failure (exit 3, as
#: :class:`~lbshape.errors.SolverError`), never a traceback
NUMERICAL_FAILURES = (np.linalg.LinAlgError, FloatingPointError, OverflowError,
                      ArpackNoConvergence)
#: sub-command modules, in the order ``lbshape --help`` lists them
COMMANDS = ("mesh", "eigen", "modes", "precompute", "simulate", "render", "live", "bench",
            "tune", "demo")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="lbshape",
        description="Real-time example-based elastic materials in Laplace-Beltrami shape space.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"lbshape.cli.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"lbshape.cli.{name}":
                raise
            continue  # command not implemented yet
        module.register(sub)
    return parser


class _ArgumentParserError(LbshapeError):
    pass


class ProgressAwareHandler(logging.Handler):
    """Log records on stderr through ``tqdm.write``: a warning raised while a progress
    bar is drawn (a mesh's re-oriented tetrahedra during the precompute's mesh stage)
    gets a line of its own and the bar is redrawn below it, instead of the message
    being glued into the bar's line."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            from tqdm import tqdm

            tqdm.write(self.format(record), file=sys.stderr)
        except Exception:  # never let logging break a run
            self.handleError(record)


def quiet_other_libraries(record: logging.LogRecord) -> bool:
    """A handler filter: every record of lbshape's own loggers, only warnings and errors
    of the others. The form compiler's C build (FFCx through cffi and setuptools) logs
    ``running build_ext`` and each gcc command line at INFO on the root logger and lowers
    that logger's level to INFO while it builds: those lines never reach the terminal."""
    return record.levelno >= logging.WARNING or record.name.split(".")[0] == "lbshape"


def configure_logging(*, verbose: bool = False) -> None:
    """The command line's logging: ``LEVEL: message`` lines on stderr through
    :class:`ProgressAwareHandler`; lbshape at INFO with ``verbose``, else WARNING;
    other libraries' warnings and errors only (:func:`quiet_other_libraries`); Python
    warnings (``warnings.warn``) go the same way."""
    handler = ProgressAwareHandler()
    handler.setFormatter(logging.Formatter("%(levelname)s: %(message)s"))
    handler.addFilter(quiet_other_libraries)
    # the root logger stays at WARNING (the form compiler's build may lower it while it
    # compiles: the handler's filter keeps its build log out)
    logging.basicConfig(level=logging.WARNING, handlers=[handler], force=True)
    logging.getLogger("lbshape").setLevel(logging.INFO if verbose else logging.WARNING)
    logging.captureWarnings(True)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``lbshape`` console script; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    configure_logging(verbose=args.verbose)
    try:
        result = args.func(args)
    except LbshapeError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return exc.exit_code
    except NUMERICAL_FAILURES as exc:  # a solve that failed below lbshape's own checks
        print(f"error: solver failed: {type(exc).__name__}: "
              f"{' '.join(str(exc).split())}", file=sys.stderr)
        return SolverError.exit_code
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130
    return int(result or 0)


if __name__ == "__main__":
    sys.exit(main())
