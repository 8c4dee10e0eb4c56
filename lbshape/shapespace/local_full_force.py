"""The local example force of the full-space reference (paper §5), n-sized by design:
the forces of :mod:`lbshape.shapespace.local_space` ("Forces") evaluated on the full
displacement, the reference the reduced driver
(:mod:`lbshape.shapespace.local_driver`) is checked against.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from lbshape.elastic.element_kernels import mass_matrix
from lbshape.elastic.materials import Material
from lbshape.geometry.mesh import TetMesh
from lbshape.shapespace.euclidean_energy import EuclideanExampleEnergy
from lbshape.shapespace.interpolation import SimplexWeights, TargetSolver
from lbshape.shapespace.local_regions import anchor_fit
from lbshape.shapespace.local_space import LocalShapeSpace
from lbshape.shapespace.projections import block_basis, descriptor_matrix


class FullSpaceLocalForce:
    """The local example force of the full-space reference (n-sized by design).

    Per step: region coefficients ``c_R = Φ_Rᵀ M_R u_R``, weights (eq. 5), target
    ``c*_R`` by Newton with the energy over all of R's elements, and the pull
    ``Σ_R M^(R) E_R (L_R c*_R + Q_R g_R)`` (3n,) in kg·m (g_R the anchor fit, see the
    module docstring of :mod:`lbshape.shapespace.local_space`); the spring matrix is
    :attr:`mass` = ``Σ_R M^(R)`` (3n, 3n) kg.

    Args:
        mesh: the object's rest mesh.
        material: its material.
        space: the local shape space.
        free_rigid: as in :func:`local_example_driver`.
        tolerance: target Newton tolerance.
    """

    def __init__(self, mesh: TetMesh, material: Material, space: LocalShapeSpace, *,
                 free_rigid: bool = True, tolerance: float = 1e-6):
        self.regions = tuple(space.regions)
        self.names = tuple(reg.name for reg in space.regions)
        self.free_rigid = bool(free_rigid)
        n, rho = mesh.n_vertices, float(material.density)
        self._regions = []
        blocks = []
        for region in space.regions:
            sub = region.submesh(mesh)
            mass_R = mass_matrix(sub, rho)
            rows = (3 * region.vertices[:, None] + np.arange(3)).ravel()
            place = sp.csr_matrix((np.ones(rows.size), (rows, np.arange(rows.size))),
                                  shape=(3 * n, rows.size))
            blocks.append(place @ mass_R @ place.T)
            L = block_basis(region.eigenvectors)
            ML = np.asarray(mass_R @ L)  # (3n_R, 3m) kg
            Q, F, anchor_rows = anchor_fit(sub.points, mass_R, region.anchor)
            mass_Q = np.asarray(mass_R @ Q)  # (3n_R, 6): M_R Q F kept as two factors
            relative = ML.T.copy()  # (3m, 3n_R): Lᵀ M_R (I − Q F S) when anchored
            if self.free_rigid:
                relative[:, anchor_rows] -= (L.T @ mass_Q) @ F
                ML = ML - mass_Q @ (F @ L[anchor_rows])
            descriptor = descriptor_matrix(region.eigenvalues, relative.T, rho)
            k = region.example_coefficients.shape[0]
            rests, tets = region.example_energy_shapes(mesh)
            models = [EuclideanExampleEnergy(x, tets, material, L) for x in rests]
            solver = TargetSolver(models, region.example_coefficients.reshape(k, -1),
                                  tolerance=tolerance)
            # the weights' supports, once (eq. 5 for fixed examples)
            examples = SimplexWeights(region.example_descriptors(rho, free_rigid=self.free_rigid))
            self._regions.append((rows, descriptor, examples, solver, ML,
                                  (mass_Q, F), rows.reshape(-1)[anchor_rows]))
        self.mass = sp.csr_matrix(sum(blocks))
        self.weights: dict[str, np.ndarray] = {}
        self._coupling: sp.csr_matrix | None = None

    def anchor_coupling(self) -> sp.csr_matrix:
        """(3n, 3n) kg: the pull's part linear in the state, ``Σ_R E_R M_R Q_R F_R
        E_anchor``: with the weights held, ``pull(u) = pull(0) + G u`` (the anchor fit
        moves each region's target with its anchor ring; none without ``free_rigid``).
        Built once."""
        if self._coupling is None:
            n3 = self.mass.shape[0]
            blocks = [sp.coo_matrix((n3, n3))]
            for rows, *_, (mass_Q, F), anchor_rows in self._regions:
                if self.free_rigid:
                    i, j = np.meshgrid(rows, anchor_rows, indexing="ij")
                    blocks.append(sp.coo_matrix(((mass_Q @ F).ravel(), (i.ravel(), j.ravel())),
                                                shape=(n3, n3)))
            self._coupling = sp.csr_matrix(sum(blocks))
        return self._coupling

    def pull(self, u: np.ndarray) -> np.ndarray:
        """(3n,) the pull (kg·m) for the displacement u (3n,) or (n, 3)."""
        u = np.asarray(u, dtype=float).reshape(-1)
        out = np.zeros_like(u)
        for name, (rows, descriptor, examples, solver, ML, (mass_Q, F), anchor_rows) in zip(
                self.names, self._regions, strict=True):
            w = examples(descriptor @ u[rows])
            self.weights[name] = w
            pull = ML @ solver.solve(w).z
            if self.free_rigid:  # M_R Q F u[anchor] (rank 6)
                pull += mass_Q @ (F @ u[anchor_rows])
            out[rows] += pull
        return out
