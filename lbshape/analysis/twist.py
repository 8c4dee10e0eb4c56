"""The twist of a bar's end section: the number a reader of the paper's Figure 3 looks for.

Measure the free end (``end="free"`` with the clamped vertices): the clamped end of a
fixed bar does not turn, whichever end of the axis it is.
"""

from __future__ import annotations

import numpy as np

from lbshape.errors import LbshapeError


def free_end(points: np.ndarray, fixed: np.ndarray | None, *, axis: int = 2) -> str:
    """``"min"`` or ``"max"``: the end of the bar along ``axis`` farther from its clamped
    vertices ``fixed`` (indices; ``"min"`` for a free body, none clamped)."""
    points = np.asarray(points, dtype=float)
    fixed = np.asarray(fixed if fixed is not None else (), dtype=np.int64)
    if fixed.size == 0:
        return "min"
    z = points[:, axis]
    clamp = float(z[fixed].mean())
    return "min" if clamp - z.min() > z.max() - clamp else "max"


def end_twist_degrees(points: np.ndarray, u: np.ndarray, *, axis: int = 2,
                      end: str = "min", tolerance: float = 1e-3,
                      fixed: np.ndarray | None = None) -> float:
    """Mean rotation (degrees, right-handed about ``+axis``) of a bar's end section.

    Args:
        points: (n, 3) rest positions (m).
        u: (n, 3) displacement (m).
        axis: the bar's axis (0, 1, 2).
        end: ``"min"`` or ``"max"``: which end section (vertices within
            ``tolerance`` of the extreme axial coordinate); ``"free"``: the end away from
            the clamped vertices ``fixed`` (:func:`free_end`).
        tolerance: thickness of the end section (m).
        fixed: the clamped vertex indices (for ``end="free"``).

    Each vertex of the section beyond 30 % of its largest radius contributes the
    angle between its arm from the section's centroid at rest and deformed.
    """
    points, u = np.asarray(points, dtype=float), np.asarray(u, dtype=float).reshape(-1, 3)
    if end == "free":
        end = free_end(points, fixed, axis=axis)
    elif end not in ("min", "max"):
        raise LbshapeError(f"end must be 'min', 'max' or 'free', got {end!r}")
    z = points[:, axis]
    extreme = z.min() if end == "min" else z.max()
    section = np.flatnonzero(np.abs(z - extreme) <= tolerance)
    if section.size < 2:
        raise LbshapeError("the bar's end section has fewer than two vertices")
    i, j = (axis + 1) % 3, (axis + 2) % 3
    rest = points[section] - points[section].mean(axis=0)
    moved = points[section] + u[section]
    moved = moved - moved.mean(axis=0)
    a, b = rest[:, [i, j]], moved[:, [i, j]]
    angles = np.arctan2(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0], np.einsum("ij,ij->i", a, b))
    radius = np.linalg.norm(a, axis=1)
    keep = radius > 0.3 * radius.max()
    return float(np.degrees(np.mean(angles[keep])))

