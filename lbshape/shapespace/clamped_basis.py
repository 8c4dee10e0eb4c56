"""The clamped LB basis: the object's eigenfunctions faded to zero at its fixed vertices.

The LB eigenfunctions are free (natural boundary) while the elastic basis U is
clamped: an example's LB displacement ``Φ c_k`` keeps part of its amplitude at the
fixed vertices, which no reduced coordinate can represent. Target coordinates in the
clamped basis ``L_F = Φ_F ⊗ I₃`` describe displacements that vanish there, like every
displacement the reduced dynamics can take. Whether the target routes use it is the
precompute's choice (``boundary``, :mod:`lbshape.pipeline.routes`); whether it keeps
the examples' elements healthy is
:func:`lbshape.shapespace.example_shapes.clamp_is_safe`.
"""

from __future__ import annotations

import numpy as np

#: length of the blend from the fixed vertices to the free LB basis, a share of the
#: object's size (largest edge of its bounding box)
CLAMP_BLEND = 0.2


def clamp_profile(points: np.ndarray, fixed_vertices: np.ndarray, *,
                  blend: float = CLAMP_BLEND) -> np.ndarray:
    """χ (n,): 0 at the fixed vertices, 1 beyond ``blend × size`` from them, smoothstep between.

    Distances are Euclidean to the nearest fixed vertex; without fixed vertices χ = 1.
    """
    points = np.asarray(points, dtype=float)
    fixed = np.asarray(fixed_vertices, dtype=np.int64)
    if fixed.size == 0:
        return np.ones(points.shape[0])
    from scipy.spatial import cKDTree

    length = blend * float(np.ptp(points, axis=0).max())
    distance, _ = cKDTree(points[fixed]).query(points)
    s = np.clip(distance / length, 0.0, 1.0)
    chi = s * s * (3.0 - 2.0 * s)
    chi[fixed] = 0.0
    return chi


def clamped_eigenvectors(eigenvectors: np.ndarray, fixed_vertices: np.ndarray,
                         points: np.ndarray, *, blend: float = CLAMP_BLEND) -> np.ndarray:
    """Φ_F = diag(χ) Φ (n, m): the LB basis faded to zero at the fixed vertices.

    The fade χ (:func:`clamp_profile`) spreads the removed part over a blend length
    instead of one element layer, which on coarse meshes would nearly collapse the
    examples' first layer of elements.
    """
    chi = clamp_profile(points, fixed_vertices, blend=blend)
    return np.asarray(eigenvectors, dtype=float) * chi[:, None]
