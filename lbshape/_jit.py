"""Optional numba JIT for the real-time kernels: ``njit`` compiles when numba is present.

Without numba the decorated functions run as plain Python (same results, far slower:
the real-time step then misses its budget), with a warning at import;
:data:`HAVE_NUMBA` says which. Compiled kernels are cached on disk by numba.
"""

from __future__ import annotations

import warnings

try:  # numba is a Debian package (python3-numba); the venv sees it
    import numba as _numba
except ImportError:  # pragma: no cover - exercised only on machines without numba
    _numba = None
    warnings.warn("numba is not installed (Debian: python3-numba; scripts/setup installs "
                  "it): lbshape's real-time kernels run as plain Python, far slower",
                  RuntimeWarning, stacklevel=2)

#: True when the kernels are compiled
HAVE_NUMBA = _numba is not None

__all__ = ["HAVE_NUMBA", "njit", "py_func"]


def njit(function):
    """``numba.njit(cache=True, nogil=True)`` or the function itself without numba."""
    if _numba is None:  # pragma: no cover
        return function
    return _numba.njit(cache=True, nogil=True)(function)


def py_func(function):
    """The plain Python function behind a compiled one (without numba: itself)."""
    return getattr(function, "py_func", function)
