"""Mass norms of trajectories and the relative errors built on them.

* :func:`m_norms` — ``sqrt(u(t)ᵀ M u(t))`` per sample, M the consistent elastic mass (kg);
* :func:`trajectory_error` — ``max_t ‖u(t) − u_full(t)‖_M / max_t ‖u_full(t)‖_M`` over
  the same sample times (the benchmarks' error against ``full``);
* :func:`ratio` — a relative measure that is 0 below round-off and None when only its
  reference is below round-off (:data:`ROUNDOFF` of the object's size).
"""

from __future__ import annotations

import numpy as np

from lbshape.errors import LbshapeError

#: M-norm differences below ROUNDOFF × sqrt(mass) × bounding-box diagonal count as none
ROUNDOFF = 1e-12


def ratio(numerator: float, denominator: float, atol: float) -> float | None:
    """``numerator / denominator``: 0 when ``numerator ≤ atol`` (nothing to measure), None
    when only ``denominator ≤ atol`` (undefined)."""
    if numerator <= atol:
        return 0.0
    return numerator / denominator if denominator > atol else None


def m_norms(u: np.ndarray, mass) -> np.ndarray:
    """(k,) mass norms ``sqrt(u(t)ᵀ M u(t))`` of a trajectory.

    Args:
        u: (k, n, 3) or (k, 3n) displacements in m (node-major).
        mass: (3n, 3n) symmetric positive definite mass in kg (sparse or dense).

    Returns:
        (k,) norms in m·kg^½.
    """
    u = np.asarray(u, dtype=float)
    flat = u.reshape(u.shape[0], -1)
    if flat.shape[1] != mass.shape[0]:
        raise LbshapeError(
            f"displacements have {flat.shape[1]} components per sample, the mass matrix "
            f"has {mass.shape[0]} rows"
        )
    squares = np.einsum("ti,ti->t", flat, np.asarray((mass @ flat.T).T))
    return np.sqrt(np.maximum(squares, 0.0))


def trajectory_error(
    u: np.ndarray,
    u_full: np.ndarray,
    mass,
    *,
    times: np.ndarray | None = None,
    times_full: np.ndarray | None = None,
) -> float:
    """Relative trajectory error ``max_t ‖u(t) − u_full(t)‖_M / max_t ‖u_full(t)‖_M``.

    Args:
        u: (k, n, 3) or (k, 3n) displacements in m.
        u_full: the reference, same shape and same sample times.
        mass: (3n, 3n) consistent elastic mass in kg.
        times: (k,) sample times of ``u`` in s (checked against ``times_full``).
        times_full: (k,) sample times of ``u_full`` in s.

    Returns:
        The dimensionless error (0 for identical trajectories).

    Raises:
        LbshapeError: different shapes or sample times, or a reference that never
            moves (the relative error is undefined).
    """
    u, u_full = np.asarray(u, dtype=float), np.asarray(u_full, dtype=float)
    if u.shape != u_full.shape or u.ndim not in (2, 3) or u.shape[0] == 0:
        raise LbshapeError(
            f"trajectories must have the same non-empty (k, n, 3) or (k, 3n) shape, "
            f"got {u.shape} and {u_full.shape}"
        )
    if (times is None) != (times_full is None):
        raise LbshapeError("give the sample times of both trajectories or of neither")
    if times is not None:
        times, times_full = np.asarray(times, dtype=float), np.asarray(times_full, dtype=float)
        if times.shape != (u.shape[0],) or times_full.shape != (u.shape[0],):
            raise LbshapeError(
                f"sample times must have shape ({u.shape[0]},), got {times.shape} and "
                f"{times_full.shape}"
            )
        scale = max(float(np.max(np.abs(times_full))), 1.0)
        worst = float(np.max(np.abs(times - times_full)))
        if worst > 1e-9 * scale:
            raise LbshapeError(
                f"trajectories are sampled at different times (largest difference {worst:.3g} s)"
            )
    reference = float(m_norms(u_full, mass).max())
    if not reference > 0.0:
        raise LbshapeError("the reference trajectory never moves: relative error undefined")
    return float(m_norms(u - u_full, mass).max()) / reference

