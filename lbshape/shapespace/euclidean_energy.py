"""Elastic energy of an example shape over all elements, in a displacement basis.

The Euclidean-space baseline of the target search (Zhu et al. 2015): the energy of
deforming example k's rest shape ``X_k`` (n, 3) — the example reconstructed on the
object's mesh — by the displacement ``B y``, summed over **all** tetrahedra of the
mesh, with the basis B (3n, p) (typically the LB block basis ``L = Φ ⊗ I₃``, p = 3m)
and coordinates y (p,):

* ``E(y) = Σ_e V_e Ψ(F_e(B_e y))``,
* ``g(y) = ∂E/∂y = Bᵀ f(B y)``,
* ``H(y) = ∂g/∂y = Bᵀ K(B y) B``,

with f, K the full-space internal force and tangent of the rest shape ``X_k``
(:class:`lbshape.elastic.element_kernels.FullSpaceElasticity`). No 3n × 3n matrix is formed:
the element rows ``B_e`` (12, p) of the basis are gathered once and every call is
a batched product over the elements. This is the reduced cubature kernel
(:class:`lbshape.elastic.reduced_forces.ReducedForceModel`) with all elements and unit
weights, which reproduces the exact projected quantities.

Both the ``euclidean`` method (reduced dynamics, Euclidean target) and the ``full``
method (:mod:`lbshape.dynamics.full`) hand one such model per example to
:class:`lbshape.shapespace.interpolation.TargetSolver`.
"""

from __future__ import annotations

import numpy as np

from lbshape.elastic.block_energy import BlockBasisEnergy, block_basis_factor
from lbshape.elastic.materials import Material
from lbshape.elastic.reduced_forces import ReducedForceModel
from lbshape.errors import LbshapeError


class EuclideanExampleEnergy:
    """Energy of deforming a rest shape by ``basis @ y``, over all elements.

    Args:
        rest_points: (n, 3) rest shape in metres (an example reconstructed on the
            object's mesh, or the object's own rest shape).
        tets: (t, 4) vertex indices of all tetrahedra of the object's mesh.
        material: the hyperelastic material.
        basis: (3n, p) node-major basis (rows ``3 j + c``) mapping coordinates y (p,)
            to displacements in metres.
        compiled: evaluate an LB block basis ``Φ ⊗ I₃`` with the compiled
            :class:`~lbshape.elastic.block_energy.BlockBasisEnergy` (same values to
            round-off); ``False``: the general model always (comparison runs).

    Attributes:
        n_coordinates: p.
        n_elements: t (every element of the mesh).
        model: the underlying all-element, unit-weight
            :class:`~lbshape.elastic.reduced_forces.ReducedForceModel`.

    Raises:
        LbshapeError: inconsistent shapes, a non-finite basis, or a degenerate rest
            element of ``rest_points``.
    """

    def __init__(
        self, rest_points: np.ndarray, tets: np.ndarray, material: Material, basis: np.ndarray,
        *, compiled: bool = True,
    ):
        tets = np.asarray(tets)
        if tets.ndim != 2 or tets.shape[1] != 4 or tets.shape[0] == 0:
            raise LbshapeError(f"tets must have shape (t, 4) with t >= 1, got {tets.shape}")
        t = tets.shape[0]
        self.model = ReducedForceModel(
            rest_points, tets, material, basis, np.arange(t, dtype=np.int64), np.ones(t)
        )
        self.n_coordinates = self.model.n_coordinates
        self.n_elements = t
        # an LB block basis Φ ⊗ I₃: the compiled block evaluation (same values to round-off)
        phi = block_basis_factor(basis) if compiled else None
        self._block = None if phi is None else BlockBasisEnergy(rest_points, tets, material,
                                                                phi)

    def energy(self, y: np.ndarray) -> float:
        """Strain energy ``E(y)`` in J of the displacement ``basis @ y``, y (p,)."""
        if self._block is not None:
            return self._block.energy(y)
        return self.model.energy(y)

    def force(self, y: np.ndarray) -> np.ndarray:
        """Gradient ``g = Bᵀ f(B y)`` (p,) (J per unit of y)."""
        return self.model.force(y)

    def force_and_tangent(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(g (p,), H (p, p))`` with ``g = Bᵀ f(B y)``, ``H = Bᵀ K(B y) B`` (symmetric)."""
        if self._block is not None:
            return self._block.force_and_tangent(y)
        return self.model.force_and_tangent(y)

    def energy_force_and_tangent(self, y: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        """``(E(y), g, H)`` in one pass (the compiled block evaluation when the basis is an
        LB block basis, else :meth:`energy` and :meth:`force_and_tangent`)."""
        if self._block is not None:
            return self._block.energy_force_and_tangent(y)
        return (self.model.energy(y), *self.model.force_and_tangent(y))

    def min_jacobian(self, y: np.ndarray) -> float:
        """The smallest det F over all elements at y (p,); ≤ 0 means inverted."""
        return self.model.min_jacobian(y)
