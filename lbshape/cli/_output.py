"""Shared output helpers for sub-commands."""

from __future__ import annotations

import json
import sys


def print_json(payload: dict) -> None:
    """Print a JSON object on stdout (one document, sorted keys off: contract order)."""
    json.dump(payload, sys.stdout, indent=2)
    sys.stdout.write("\n")
