"""The ``lbshape`` command line: one module per sub-command, each with ``register(subparsers)``."""

from lbshape.cli.main import main

__all__ = ["main"]
