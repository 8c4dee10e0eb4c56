"""A reduced force model for a basis that ends with impact columns.

A free body's impact columns (:mod:`lbshape.pipeline.impact_columns`) hold the local
crush of an impact: large strains in a few elements, where the rest of the basis holds
the body's deformation as a whole. With the basis ``[U₀ V]`` (U₀ the leading r₀ columns,
V the k impact columns), coordinates ``y = (q, z)`` and the rest stiffness K₀,

    E(y) = E₀(q) + E_V(z) + zᵀ VᵀK₀U₀ q,

E₀ the nonlinear model on U₀ (the polynomial or the cubature), E_V the columns' own
energy — exact (the StVK polynomial on V, built like E₀'s) or, where that is not built,
its quadratic part ½ zᵀ VᵀK₀V z — and their coupling to q linear. The columns add no
(r, r)-sized nonlinear model: E₀ costs what it costs on r₀ columns, E_V on k. On the
Figure 4 bar's designed impacts the exact E_V took the edge hits from 2.5 / 6.6 % (all
linear) to 1.1 / 3.1 % in restitution (``docs/decisions.md``, "Impact columns").
"""

from __future__ import annotations

import numpy as np

from lbshape._jit import njit
from lbshape.elastic.polynomial_forces import linear_part_into


class ColumnForceModel:
    """E₀ on the leading coordinates, E_V on the trailing ones, a linear coupling.

    Args:
        base: the force model of the leading ``leading`` coordinates (``energy``,
            ``force_and_tangent_into``; :class:`~lbshape.elastic.polynomial_forces.
            PolynomialForceModel` or :class:`~lbshape.elastic.reduced_forces.
            ReducedForceModel`).
        coupling: (r, r) ``[U₀ V]ᵀ K₀ [U₀ V]`` in 1/s² (U M-orthonormal); its leading
            (r₀, r₀) block is not used (E₀ holds it), nor its trailing block when
            ``columns`` is given.
        leading: r₀, the base model's coordinates (< r).
        columns: the force model of the trailing r − r₀ coordinates (E_V), or None for
            their quadratic energy.
    """

    def __init__(self, base, coupling: np.ndarray, leading: int, columns=None):
        coupling = np.asarray(coupling, dtype=float)
        r = coupling.shape[0]
        if coupling.shape != (r, r) or not 0 < leading < r:
            raise ValueError(f"coupling of shape {coupling.shape} for {leading} leading "
                             "coordinates")
        self.base, self.columns = base, columns
        self.leading, self.r = int(leading), int(r)
        self.linear = coupling.copy()
        self.linear[:leading, :leading] = 0.0
        if columns is not None:
            self.linear[leading:, leading:] = 0.0
        k = r - leading
        self._f0, self._K0 = np.zeros(leading), np.zeros((leading, leading))
        self._fv, self._Kv = np.zeros(k), np.zeros((k, k))

    @property
    def material(self):
        """The base model's material (its inversion check, if any, is the base's)."""
        return getattr(self.base, "material", None)

    def n_coordinates(self) -> int:
        return self.r

    def energy(self, y: np.ndarray) -> float:
        """E(y) in J for y (r,)."""
        y = np.asarray(y, dtype=float)
        r0 = self.leading
        total = self.base.energy(np.ascontiguousarray(y[:r0])) + 0.5 * y @ (self.linear @ y)
        if self.columns is not None:
            total += self.columns.energy(np.ascontiguousarray(y[r0:]))
        return float(total)

    def force_and_tangent_into(self, y: np.ndarray, f: np.ndarray, K: np.ndarray) -> None:
        """∇E (r,) into ``f`` and ∇²E (r, r) into ``K`` at y (r,)."""
        r0 = self.leading
        self.base.force_and_tangent_into(np.ascontiguousarray(y[:r0]), self._f0, self._K0)
        if self.columns is not None:
            self.columns.force_and_tangent_into(np.ascontiguousarray(y[r0:]), self._fv,
                                                self._Kv)
        _combine(self.linear, y, self._f0, self._K0, self._fv, self._Kv,
                 self.columns is not None, f, K)

    def force_and_tangent(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(∇E (r,), ∇²E (r, r)) at y (r,)."""
        f, K = np.zeros(self.r), np.zeros((self.r, self.r))
        self.force_and_tangent_into(np.asarray(y, dtype=float), f, K)
        return f, K

    def force(self, y: np.ndarray) -> np.ndarray:
        return self.force_and_tangent(y)[0]

    def tangent(self, y: np.ndarray) -> np.ndarray:
        return self.force_and_tangent(y)[1]

    def min_jacobian_into(self, y: np.ndarray) -> float:
        """The base model's smallest element Jacobian at the leading coordinates."""
        return self.base.min_jacobian_into(np.ascontiguousarray(y[:self.leading]))


@njit
def _combine(linear, y, f0, K0, fv, Kv, with_columns, f, K):
    """``f = linear y`` and ``K = linear`` (r, r), then the leading model's force f0 and
    tangent K0 added to the leading block and, ``with_columns``, the columns' fv, Kv to
    the trailing one."""
    r, r0 = y.shape[0], f0.shape[0]
    linear_part_into(linear, y, f, K)
    for a in range(r0):
        f[a] += f0[a]
        for b in range(r0):
            K[a, b] += K0[a, b]
    if with_columns:
        for a in range(r - r0):
            f[r0 + a] += fv[a]
            for b in range(r - r0):
                K[r0 + a, r0 + b] += Kv[a, b]
