"""User-facing errors: one line, no traceback, non-zero exit from the CLI."""


class LbshapeError(Exception):
    """An error caused by the user's input (files, scenes, parameters).

    The message is a single line that says what is wrong and, where useful, where.
    The command line prints it as ``error: <message>`` and exits with code 2.
    """

    exit_code = 2

    def __init__(self, message: str):
        super().__init__(" ".join(str(message).split()))


class SolverError(LbshapeError):
    """A numerical solve that did not converge or diverged (exit code 3)."""

    exit_code = 3


class NewtonFailure(SolverError):
    """A Newton iteration that did not reach its residual test within its iterations
    (exit code 3): a caller may retry the step another way before giving up."""
