"""Optional numba JIT for the real-time kernels: ``njit`` compiles when numba is present.

Without numba the decorated functions run as plain Python (same results, far slower:
the real-time step then misses its budget), with a warning at import;
:data:`HAVE_NUMBA` says which.

Compiled kernels are cached on disk by numba, in a folder named after a digest of
lbshape's own sources (:func:`kernel_cache_dir`, under the precompute cache's root,
unless ``NUMBA_CACHE_DIR`` is set). numba checks a cached kernel only against its
own file, not against the kernels it calls in other modules: after a change to a
callee (e.g. a step structure's layout) a caller's stale machine code would run with
the old layout. A new source digest means a fresh folder, so that cannot happen.
"""

from __future__ import annotations

import hashlib
import os
import warnings
from pathlib import Path

from lbshape.io.cache import cache_root

try:  # numba is a Debian package (python3-numba); the venv sees it
    import numba as _numba
except ImportError:  # pragma: no cover - exercised only on machines without numba
    _numba = None
    warnings.warn("numba is not installed (Debian: python3-numba; scripts/setup installs "
                  "it): lbshape's real-time kernels run as plain Python, far slower",
                  RuntimeWarning, stacklevel=2)

#: True when the kernels are compiled
HAVE_NUMBA = _numba is not None


def kernel_cache_dir() -> Path:
    """``<cache root>/numba/<digest of lbshape's .py files>`` (the root as
    :func:`lbshape.io.cache.cache_root` has it: ``$LBSHAPE_CACHE`` or ``~/.cache/lbshape``)."""
    digest = hashlib.sha256()
    package = Path(__file__).resolve().parent
    for path in sorted(package.rglob("*.py")):
        digest.update(path.relative_to(package).as_posix().encode())
        digest.update(path.read_bytes())
    return cache_root() / "numba" / digest.hexdigest()[:16]


if _numba is not None and not os.environ.get("NUMBA_CACHE_DIR"):
    _numba.config.CACHE_DIR = str(kernel_cache_dir())

__all__ = ["HAVE_NUMBA", "njit", "py_func"]


def njit(function):
    """``numba.njit(cache=True, nogil=True)`` or the function itself without numba."""
    if _numba is None:  # pragma: no cover
        return function
    return _numba.njit(cache=True, nogil=True)(function)


def py_func(function):
    """The plain Python function behind a compiled one (without numba: itself)."""
    return getattr(function, "py_func", function)
