"""A reduced force model with trailing columns whose energy is taken linear.

A free body's impact columns (:mod:`lbshape.pipeline.impact_columns`) hold the local
crush of an impact: millimetres, where the rest of the basis holds the body's large
deformation. Their energy is taken to second order about rest: with the basis
``[U₀ V]`` (U₀ the leading r₀ columns, V the k impact columns), coordinates ``y = (q, z)``
and the rest stiffness K₀,

    E(y) = E₀(q) + zᵀ VᵀK₀U₀ q + ½ zᵀ VᵀK₀V z,

E₀ the nonlinear model on U₀ (the polynomial or the cubature). Its cost over E₀ is one
(r, r) product: the columns add no nonlinear force build and no cubature elements. On the
Figure 4 bar's designed impacts this gave the same restitution errors, to 0.01 points, as
the exact polynomial force on every column (``docs/decisions.md``, "Impact columns").
"""

from __future__ import annotations

import numpy as np


class LinearColumnsForceModel:
    """E₀ on the leading coordinates plus the linear energy of the trailing ones.

    Args:
        base: the force model of the leading ``leading`` coordinates (``energy``,
            ``force_and_tangent_into``; :class:`~lbshape.elastic.polynomial_forces.
            PolynomialForceModel` or :class:`~lbshape.elastic.reduced_forces.
            ReducedForceModel`).
        coupling: (r, r) ``[U₀ V]ᵀ K₀ [U₀ V]`` in 1/s² (U M-orthonormal); its leading
            (r₀, r₀) block is not used (E₀ holds it).
        leading: r₀, the base model's coordinates (< r).
    """

    def __init__(self, base, coupling: np.ndarray, leading: int):
        coupling = np.asarray(coupling, dtype=float)
        r = coupling.shape[0]
        if coupling.shape != (r, r) or not 0 < leading < r:
            raise ValueError(f"coupling of shape {coupling.shape} for {leading} leading "
                             "coordinates")
        self.base, self.leading, self.r = base, int(leading), int(r)
        self.linear = coupling.copy()
        self.linear[:leading, :leading] = 0.0
        self._f0 = np.zeros(leading)
        self._K0 = np.zeros((leading, leading))

    @property
    def material(self):
        """The base model's material (its inversion check, if any, is the base's)."""
        return getattr(self.base, "material", None)

    def n_coordinates(self) -> int:
        return self.r

    def energy(self, y: np.ndarray) -> float:
        """E(y) in J for y (r,)."""
        y = np.asarray(y, dtype=float)
        return float(self.base.energy(np.ascontiguousarray(y[:self.leading]))
                     + 0.5 * y @ (self.linear @ y))

    def force_and_tangent_into(self, y: np.ndarray, f: np.ndarray, K: np.ndarray) -> None:
        """∇E (r,) into ``f`` and ∇²E (r, r) into ``K`` at y (r,)."""
        r0 = self.leading
        self.base.force_and_tangent_into(np.ascontiguousarray(y[:r0]), self._f0, self._K0)
        np.dot(self.linear, y, out=f)
        f[:r0] += self._f0
        K[...] = self.linear
        K[:r0, :r0] += self._K0

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
        """The base model's smallest element Jacobian at the leading coordinates (the
        columns' millimetres do not invert an element the base keeps upright)."""
        return self.base.min_jacobian_into(np.ascontiguousarray(y[:self.leading]))
