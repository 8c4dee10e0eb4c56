"""The conditions of a timing: machine, library versions, thread settings and load.

Every benchmark output states them next to its numbers; this is the one place
they are read.
"""

from __future__ import annotations

import os
import platform
from pathlib import Path

import numpy as np

#: environment variables that set the BLAS / OpenMP thread counts
THREAD_VARIABLES: tuple[str, ...] = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def cpu_name() -> str:
    """The CPU model (``/proc/cpuinfo``), else what :mod:`platform` knows."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def load_average() -> list[float] | None:
    """The 1, 5 and 15 minute load averages (rounded to 0.01), or None where unknown."""
    try:
        return [round(value, 2) for value in os.getloadavg()]
    except OSError:
        return None


def machine_description() -> dict:
    """Machine, thread settings and load: the conditions of a timing.

    Returns:
        ``{"cpu", "cores", "python", "numpy", "threads": {variable: value or "unset"},
        "load_average": [1, 5, 15 min] or None}``.
    """
    return {
        "cpu": cpu_name(), "cores": os.cpu_count(), "python": platform.python_version(),
        "numpy": np.__version__,
        "threads": {name: os.environ.get(name, "unset") for name in THREAD_VARIABLES},
        "load_average": load_average(),
    }


def threads_text(machine: dict) -> str:
    """``"OMP_NUM_THREADS=1, OPENBLAS_NUM_THREADS=unset, …"`` of a :func:`machine_description`."""
    return ", ".join(f"{k}={v}" for k, v in machine["threads"].items())


def load_text(machine: dict) -> str:
    """The load averages of a :func:`machine_description` as ``"0.5, 0.7, 0.9"``
    (``"unknown"`` if not available)."""
    load = machine.get("load_average")
    return ", ".join(str(v) for v in load) if load else "unknown"


def machine_text(machine: dict | None = None) -> str:
    """One line: ``"<cpu>, <cores> cores, Python x, numpy y; threads: …"``.

    Args:
        machine: a :func:`machine_description` (default: read now).
    """
    machine = machine_description() if machine is None else machine
    return (f"{machine['cpu']}, {machine['cores']} cores, Python {machine['python']}, "
            f"numpy {machine['numpy']}; threads: {threads_text(machine)}")
