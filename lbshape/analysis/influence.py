"""How much one trajectory differs from a reference run without examples, on arrays.

* :func:`trajectory_influence` — ``‖u_ex(T) − u_none(T)‖_M / ‖u_none(T)‖_M`` at the last
  sample and ``max_t ‖u_ex − u_none‖_M / max_t ‖u_none‖_M`` (M the consistent mass);
* :func:`visible_change` — the largest vertex distance between two shapes over the rest
  bounding-box diagonal;
* :func:`nearest_shape` — which of the rest shape and the examples a shape's LB
  descriptor is closest to.

The scene-level measure built on them (a run's :class:`~lbshape.pipeline.influence.Influence`)
is :mod:`lbshape.pipeline.influence`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from lbshape.analysis.norms import m_norms, ratio
from lbshape.errors import LbshapeError

#: the label of the rest shape among the candidates of ``closest_example``
REST = "rest"



def trajectory_influence(u_ex: np.ndarray, u_none: np.ndarray, mass, *, atol: float = 0.0
                         ) -> tuple[float | None, float | None]:
    """``(final, maximum)`` influence of two trajectories sampled at the same times.

    Args:
        u_ex: (k, n, 3) displacements with examples (m).
        u_none: (k, n, 3) displacements without examples (m).
        mass: (3n, 3n) consistent mass (kg).
        atol: M-norms (m·kg^½) up to ``atol`` count as none: a difference that small
            is influence 0, a reference that small (and a larger difference) None.
    """
    u_ex, u_none = np.asarray(u_ex, dtype=float), np.asarray(u_none, dtype=float)
    if u_ex.shape != u_none.shape or u_ex.shape[0] == 0:
        raise LbshapeError(f"trajectories must have the same non-empty shape, got {u_ex.shape} "
                           f"and {u_none.shape}")
    difference = m_norms(u_ex - u_none, mass)
    reference = m_norms(u_none, mass)
    return (ratio(float(difference[-1]), float(reference[-1]), atol),
            ratio(float(difference.max()), float(reference.max()), atol))


def visible_change(points: np.ndarray, shape_ex: np.ndarray, shape_none: np.ndarray) -> float:
    """Largest vertex distance between two shapes over the rest bounding-box diagonal.

    Args:
        points: (n, 3) rest positions X (m).
        shape_ex, shape_none: (n, 3) displacements (m) of the same vertices (a free
            body's deformations, :func:`body_deformations`).
    """
    points = np.asarray(points, dtype=float)
    diagonal = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
    distance = np.linalg.norm(np.asarray(shape_ex) - np.asarray(shape_none), axis=1)
    return float(distance.max()) / diagonal


def nearest_shape(d: np.ndarray, examples: np.ndarray,
                  labels: Sequence[int] | None = None) -> tuple[object, dict]:
    """Which of the rest shape (descriptor 0) and the examples a descriptor is closest to.

    Args:
        d: (3m,) a shape's descriptor.
        examples: (k, 3m) the example descriptors e_k.
        labels: (k,) the examples' indices in the scene (default 0…k−1).

    Returns:
        ``(closest, distances)``: ``"rest"`` or the closest example's label, and
        ``{"rest": ‖d‖/s, "<label>": ‖d − e_k‖/s}`` with s = ``max_k ‖e_k‖``.
    """
    examples = np.atleast_2d(np.asarray(examples, dtype=float))
    labels = list(range(len(examples))) if labels is None else [int(k) for k in labels]
    scale = float(np.linalg.norm(examples, axis=1).max()) or 1.0
    distances = {REST: float(np.linalg.norm(d)) / scale}
    for label, e in zip(labels, examples, strict=True):
        distances[str(label)] = float(np.linalg.norm(d - e)) / scale
    closest = min(distances, key=distances.get)
    return (closest if closest == REST else int(closest)), distances

