"""The twist of a bar's end section: the number a reader of the paper's Figure 3 looks for."""

from __future__ import annotations

import numpy as np

from lbshape.errors import LbshapeError


def end_twist_degrees(points: np.ndarray, u: np.ndarray, *, axis: int = 2,
                      end: str = "min", tolerance: float = 1e-3) -> float:
    """Mean rotation (degrees, right-handed about ``+axis``) of a bar's end section.

    Args:
        points: (n, 3) rest positions (m).
        u: (n, 3) displacement (m).
        axis: the bar's axis (0, 1, 2).
        end: ``"min"`` or ``"max"``: which end section (vertices within
            ``tolerance`` of the extreme axial coordinate).
        tolerance: thickness of the end section (m).

    Each vertex of the section beyond 30 % of its largest radius contributes the
    angle between its arm from the section's centroid at rest and deformed.
    """
    points, u = np.asarray(points, dtype=float), np.asarray(u, dtype=float).reshape(-1, 3)
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

