"""Shared test fixtures and helpers.

Fixtures: ``private_cache`` (autouse, whole session) points ``$LBSHAPE_CACHE`` at one
folder under pytest's temporary base directory, so no test reads or writes the
user's cache and no test depends on which ran before it; ``live_display`` (autouse,
whole session) starts a virtual X server when the live window's tests run;
``load_script`` loads a benchmark script of ``scripts/``.

Helpers, imported by the test modules (``from conftest import rel``):
:func:`rel`, :func:`central_difference_errors`, :func:`observed_rates` and
:func:`golden` (a measured value and the test's limit, from ``tests/golden.toml``) and
:func:`user_mesh_scene` (a user's own mesh as a scene, from
:mod:`lbshape.studies.user_meshes`).

Layout: ``tests/<subpackage>/test_*.py`` mirrors the package, without ``__init__.py``
files (pytest's default ``prepend`` import mode), so every test file's basename is
unique across the folders; this conftest stays at ``tests/``, whose folder pytest puts
on ``sys.path`` when it loads it, so ``from conftest import ...`` works in every folder.
"""

from __future__ import annotations

import functools
import importlib.util
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from lbshape.studies.user_meshes import user_mesh_scene as user_mesh_scene  # re-exported

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"
GOLDEN = Path(__file__).resolve().with_name("golden.toml")
BOUNDS = ("below", "at_most", "above", "at_least")


@pytest.fixture(scope="session", autouse=True)
def private_cache(tmp_path_factory) -> Path:
    """``$LBSHAPE_CACHE`` for the whole session: ``<basetemp>/cache`` (restored after)."""
    folder = tmp_path_factory.getbasetemp() / "cache"
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("LBSHAPE_CACHE", str(folder))
        yield folder


@pytest.fixture(scope="session", autouse=True)
def live_display(request):
    """A virtual X display for the whole session when a test of the live window (one using the
    ``display`` fixture of ``tests/interactive``) is collected
    and no ``DISPLAY`` is set (and Xvfb is installed): VTK settles on a window class at
    the first render of the process, so the live window's display must exist before any
    off-screen picture of an earlier test. Yields the display's name or None."""
    import os
    import shutil

    wanted = any("display" in getattr(item, "fixturenames", ()) for item in request.session.items)
    if not wanted or os.environ.get("DISPLAY") or shutil.which("Xvfb") is None:
        yield os.environ.get("DISPLAY")
        return
    from lbshape.interactive.display import virtual_display

    with virtual_display() as name:
        yield name


@pytest.fixture(scope="session")
def load_script():
    """``load_script(name)``: the module of ``scripts/<name>.py``, loaded once and
    registered in ``sys.modules`` (dataclasses look their module up there)."""

    def load(name: str):
        if name not in sys.modules:
            spec = importlib.util.spec_from_file_location(name, SCRIPTS / f"{name}.py")
            module = importlib.util.module_from_spec(spec)
            sys.modules[name] = module
            spec.loader.exec_module(module)
        return sys.modules[name]

    return load


def rel(a, b) -> float:
    """Relative error ``‖a − b‖ / ‖b‖``, 2-norm over all entries of arrays of any shape."""
    a, b = np.asarray(a), np.asarray(b)
    return float(np.linalg.norm(np.ravel(a - b)) / np.linalg.norm(np.ravel(b)))


def central_difference_errors(value, derivative, x, direction, steps) -> np.ndarray:
    """Relative errors (len(steps),) of central differences of ``value`` along ``direction``.

    Args:
        value: function of x, returning a scalar or an array.
        derivative: function of x returning the Jacobian of ``value`` (its gradient
            for a scalar), so that ``derivative(x) @ direction`` is the exact
            directional derivative.
        x: the point, shape (k,).
        direction: (k,) the direction of differentiation.
        steps: step lengths h (along ``direction``, units of x).
    """
    exact = derivative(x) @ direction
    errors = []
    for h in steps:
        fd = (value(x + h * direction) - value(x - h * direction)) / (2 * h)
        errors.append(rel(fd, exact))
    return np.array(errors)


def observed_rates(errors, steps) -> np.ndarray:
    """Observed orders ``log(e_i / e_{i+1}) / log(h_i / h_{i+1})`` between successive steps.

    Args:
        errors: (s, ...) positive errors, one row per step.
        steps: (s,) step sizes h (mesh sizes, time steps or difference steps).

    Returns:
        (s − 1, ...) the orders, one row per pair of successive steps.
    """
    errors = np.asarray(errors, dtype=float)
    steps = np.asarray(steps, dtype=float).reshape((-1,) + (1,) * (errors.ndim - 1))
    return np.log(errors[:-1] / errors[1:]) / np.log(steps[:-1] / steps[1:])


@dataclass(frozen=True)
class Golden:
    """A measured value a test compares against, with the test's limit.

    Attributes:
        key: the entry's dotted name in ``tests/golden.toml`` (``"<file>.<name>"``).
        measured: the value measured, or (lowest, highest) over the cases of ``what``,
            in the unit of ``limit``.
        limit: the number the test compares against.
        bound: "below" (<), "at_most" (<=), "above" (>) or "at_least" (>=).
        what: the quantity, its unit and the cases measured.
        test: the test that measures it (pytest node id from the repository root).
    """

    key: str
    measured: float | tuple[float, float]
    limit: float
    bound: str
    what: str
    test: str


@functools.cache
def golden_table() -> dict:
    """``tests/golden.toml`` as nested dicts (read once)."""
    return tomllib.loads(GOLDEN.read_text(encoding="utf-8"))


def golden_keys(table: dict | None = None, prefix: str = "") -> list[str]:
    """Dotted names of every entry of ``tests/golden.toml`` (tables holding a ``limit``)."""
    table = golden_table() if table is None else table
    keys = []
    for name, value in table.items():
        if isinstance(value, dict):
            key = f"{prefix}{name}"
            keys += [key] if "limit" in value else golden_keys(value, f"{key}.")
    return keys


def golden(key: str) -> Golden:
    """The entry ``key`` (``"<file>.<name>"``) of ``tests/golden.toml``.

    Example: ``assert error < golden("drag.static_equilibrium_error").limit``.
    """
    entry = golden_table()
    for part in key.split("."):
        if not isinstance(entry, dict) or part not in entry:
            raise KeyError(f"no golden value {key!r} in {GOLDEN}")
        entry = entry[part]
    measured = entry["measured"]
    return Golden(key=key, measured=tuple(measured) if isinstance(measured, list) else measured,
                  limit=entry["limit"], bound=entry["bound"], what=entry["what"],
                  test=entry["test"])
