"""The examples' rest shapes on the object's mesh, and the elements their energies use.

Example k's rest shape is reconstructed on the object's mesh from its LB displacement
coefficients, ``X_k = X + Φ c_k`` (n, 3) (:func:`example_rest_shapes`; Φ the object's
eigenvectors or the clamped Φ_F). Every target energy ``E_k`` of the shape space is the
elastic energy of deforming X_k (:mod:`lbshape.shapespace.interpolation`).

**Squeezed elements.** With few eigenfunctions the reconstruction of a large pose can
squeeze elements, and on fine meshes invert them. StVK resists compression less and
less (the force of a uniaxial compression peaks at stretch 1/√3 and falls to zero),
so where another example pulls such an element back towards its own volume the
target energy has several minima and the exact target jumps between them as the
weights move; the target table's check then refuses the table. Measured on the
built-in bar's twist example at several mesh sizes in ``docs/decisions.md``
("Example energy elements").

**Rule** (:func:`energy_elements`): an element enters the example energies only if
every example's rest shape keeps at least :data:`MIN_VOLUME_RATIO` of its volume on
the object. One element set for all examples and every route (the target table, the
``lb-exact``, ``lb`` (and its cubature), ``modal`` and ``euclidean`` routes, local
examples per region, the full-space reference), so that every method minimises the
same target energy; the elastic forces of the object itself keep every element.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from lbshape.geometry.mesh import signed_volumes

#: smallest share of its volume on the object an element may keep in every example's
#: rest shape and still enter the example energies (see the module docstring)
MIN_VOLUME_RATIO = 0.3


def example_rest_shapes(points: np.ndarray, eigenvectors: np.ndarray,
                        coefficients: np.ndarray) -> list[np.ndarray]:
    """k rest shapes ``X + Φ c_k`` (n, 3) in m.

    Args:
        points: (n, 3) the object's rest shape X in m.
        eigenvectors: (n, m) Φ (or Φ_F).
        coefficients: (k, m, 3) the examples' displacement coefficients in m.
    """
    points = np.asarray(points, dtype=float)
    phi = np.asarray(eigenvectors, dtype=float)
    return [points + phi @ c for c in np.asarray(coefficients, dtype=float)]


def volume_ratios(points: np.ndarray, tets: np.ndarray,
                  rests: Sequence[np.ndarray]) -> np.ndarray:
    """(k, t) each element's signed volume in each rest shape over its volume on ``points``."""
    tets = np.asarray(tets)
    reference = np.abs(signed_volumes(np.asarray(points, dtype=float), tets))
    return np.array([signed_volumes(np.asarray(x, dtype=float), tets) / reference
                     for x in rests]).reshape(len(rests), tets.shape[0])


def energy_elements(points: np.ndarray, tets: np.ndarray,
                    rests: Sequence[np.ndarray]) -> np.ndarray:
    """(e,) int64 indices of the elements the example energies sum over: those whose
    volume ratio (:func:`volume_ratios`) is ≥ :data:`MIN_VOLUME_RATIO` in every rest
    shape (all elements when there is no rest shape)."""
    ratios = volume_ratios(points, tets, rests)
    return np.flatnonzero((ratios >= MIN_VOLUME_RATIO).all(axis=0)).astype(np.int64)


def clamp_is_safe(points: np.ndarray, tets: np.ndarray, eigenvectors: np.ndarray,
                  clamped: np.ndarray, coefficients: np.ndarray) -> bool:
    """Whether the clamped examples' rest shapes keep their elements healthy.

    Fading the LB displacement to zero near the fixed vertices
    (:func:`lbshape.shapespace.clamped_basis.clamped_eigenvectors`) adds strain there; on
    a coarse mesh it can flatten or invert an element of an example's rest shape
    ``X + Φ_F c_k``. Safe: every element keeps at least half of the smallest volume
    ratio that the free reconstruction ``X + Φ c_k`` has.

    Args:
        points: (n, 3) rest shape; tets: (t, 4).
        eigenvectors, clamped: (n, m) Φ and Φ_F.
        coefficients: (k, m, 3) example displacement coefficients.
    """
    free = volume_ratios(points, tets, example_rest_shapes(points, eigenvectors,
                                                           coefficients)).min()
    faded = volume_ratios(points, tets, example_rest_shapes(points, clamped,
                                                            coefficients)).min()
    return faded > 0.0 and faded >= 0.5 * free
