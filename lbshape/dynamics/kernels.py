"""Compiled dense kernels both reduced engines share, and named views of one buffer.

The fixed-object step (:mod:`lbshape.dynamics.reduced`) and the free-body step
(:mod:`lbshape.dynamics.free_body`) run on small dense arrays (r, r × r, 3, 6) and
allocate nothing per step. What both use is here, compiled when numba is present
(:mod:`lbshape._jit`):

* :func:`axpy` (``out += s x``) and :func:`predict` (the scheme's predictor
  ``Δx = h v + ½ k_a h² a``, k_a from :class:`~lbshape.dynamics.schemes.Scheme`);
* :func:`cholesky_in_place` / :func:`cholesky_solve_in_place` (symmetric positive
  definite systems: the fixed object's Newton matrix, the free body's 6 × 6 rigid
  kick) and :func:`max_symmetric_eigenvalue` (cyclic Jacobi);
* :func:`take` and :func:`check_size`, with which a kernel cuts one float buffer into
  named views.

**Named views of one buffer.** A kernel that takes many arrays is easy to call with
two of them swapped, and every array it takes costs a little to pass from Python. So
the free body keeps its step's arrays in a few structures (``NamedTuple`` classes
whose first field ``data`` is one float buffer and whose other fields are views of
it). Python passes the buffer, ``x.data``; the kernel rebuilds the named views from it
with the structure's view function (``body_state(data, r)``: :func:`take` after
:func:`take`, then :func:`check_size`), and a kernel it calls takes the views. Python
gets the same views from the same function run as plain Python
(:func:`lbshape._jit.py_func`), so the layout is written once. Never call a compiled
view function from Python: numba does not return a ``NamedTuple`` class to Python
reliably (it can crash the interpreter); compiled code only passes the views on.
"""

from __future__ import annotations

import math

import numpy as np

from lbshape._jit import njit

__all__ = ["axpy", "check_size", "cholesky_in_place", "cholesky_solve_in_place",
           "max_symmetric_eigenvalue", "norm", "predict", "take"]


def norm(vector: np.ndarray) -> float:
    """Euclidean norm of a 1-D array (cheaper than ``np.linalg.norm`` for small ones)."""
    return math.sqrt(float(vector @ vector))


def axpy(scale: float, x: np.ndarray, out: np.ndarray) -> None:
    """out += scale · x without a temporary."""
    _axpy_kernel(float(scale), x, out)


@njit
def _axpy_kernel(scale, x, out):
    for i in range(out.shape[0]):
        out[i] += scale * x[i]


@njit
def predict(v, a, h, dx, c):
    """The scheme's predictor Δx = h v + ½ k_a h² a into ``dx`` (k_a = ``c[2]``: Newmark
    1, backward Euler 0; ``c`` the step rates of
    :meth:`~lbshape.dynamics.schemes.Scheme.step_rates`)."""
    half = 0.5 * h * h * c[2]
    for i in range(dx.shape[0]):
        dx[i] = h * v[i] + half * a[i]


@njit
def cholesky_in_place(J):
    """Lower Cholesky factor of the symmetric matrix J (n, n), read from and written to its
    lower triangle; False if J is not positive definite."""
    n = J.shape[0]
    for j in range(n):
        d = J[j, j]
        for k in range(j):
            d -= J[j, k] * J[j, k]
        if not d > 0.0:
            return False
        d = np.sqrt(d)
        J[j, j] = d
        for i in range(j + 1, n):
            value = J[i, j]
            for k in range(j):
                value -= J[i, k] * J[j, k]
            J[i, j] = value / d
    return True


@njit
def cholesky_solve_in_place(L, b):
    """b ← (L Lᵀ)⁻¹ b with the factor of :func:`cholesky_in_place` (lower triangle of L)."""
    n = b.shape[0]
    for i in range(n):
        value = b[i]
        for k in range(i):
            value -= L[i, k] * b[k]
        b[i] = value / L[i, i]
    for i in range(n - 1, -1, -1):
        value = b[i]
        for k in range(i + 1, n):
            value -= L[k, i] * b[k]
        b[i] = value / L[i, i]


@njit
def max_symmetric_eigenvalue(A):
    """Largest eigenvalue of the symmetric matrix A (n, n) by cyclic Jacobi (A destroyed)."""
    n = A.shape[0]
    for _ in range(50):
        off = 0.0
        total = 0.0
        for i in range(n):
            for j in range(n):
                total += A[i, j] * A[i, j]
                if i != j:
                    off += A[i, j] * A[i, j]
        if off <= 1e-30 * total:
            break
        for p in range(n - 1):
            for q in range(p + 1, n):
                apq = A[p, q]
                if apq == 0.0:
                    continue
                tau = (A[q, q] - A[p, p]) / (2.0 * apq)
                t = (1.0 if tau >= 0.0 else -1.0) / (abs(tau) + np.sqrt(1.0 + tau * tau))
                c = 1.0 / np.sqrt(1.0 + t * t)
                s = t * c
                for k in range(n):  # columns p, q
                    akp, akq = A[k, p], A[k, q]
                    A[k, p] = c * akp - s * akq
                    A[k, q] = s * akp + c * akq
                for k in range(n):  # rows p, q
                    apk, aqk = A[p, k], A[q, k]
                    A[p, k] = c * apk - s * aqk
                    A[q, k] = s * apk + c * aqk
    largest = A[0, 0]
    for i in range(1, n):
        largest = max(largest, A[i, i])
    return largest


# ------------------------------------------------------ named views of one buffer
@njit
def take(data, at, size):
    """``(data[at:at + size], at + size)``: the next view of a buffer and where the one
    after it starts."""
    return data[at:at + size], at + size


@njit
def check_size(data, used):
    """Raise ``ValueError`` unless the views cut from ``data`` cover it exactly."""
    if used != data.shape[0]:
        raise ValueError("a structure's views do not cover its buffer")


@njit
def quadratic_form(S, q):
    """qᵀ S q."""
    total = 0.0
    for i in range(q.shape[0]):
        row = 0.0
        for j in range(q.shape[0]):
            row += S[i, j] * q[j]
        total += q[i] * row
    return total


@njit
def all_finite(x, v, a):
    """Whether every entry of the three (r,) arrays is finite."""
    for i in range(x.shape[0]):
        if not (np.isfinite(x[i]) and np.isfinite(v[i]) and np.isfinite(a[i])):
            return False
    return True


def dot_sum(a: np.ndarray, b: np.ndarray | None, c: np.ndarray) -> float:
    """(a + b) · c (b may be None)."""
    return float(_dot_sum_kernel(a, a if b is None else b, c, b is not None))


@njit
def _dot_sum_kernel(a, b, c, both):
    total = 0.0
    for i in range(c.shape[0]):
        total += (a[i] + b[i] if both else a[i]) * c[i]
    return total
