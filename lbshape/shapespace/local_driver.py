"""The runtime of the local examples (paper §5): per-region drivers whose pulls add up,
and where the runtime places each region's target.

The forces and the small matrices they use are those of
:mod:`lbshape.shapespace.local_space` ("Forces"): region R's target is its
interpolated example shape ``L_R c*_R`` attached where the region is attached (its
anchor, :mod:`lbshape.shapespace.local_regions`), ``u*_R = E_R (L_R c*_R + Q_R g)``
with g the anchor's rigid fit of ``u − L_R c*_R`` (:func:`local_example_shape` draws
an example placed so, at rest).

**Targets at run time.** Per region, weights by paper eq. 5 on the region's
descriptors and the target ``c*_R`` of those weights
(:mod:`lbshape.shapespace.local_build`, "Targets"). The reduced method's step
(:meth:`LocalExampleDriver.weights_into`,
:meth:`~LocalExampleDriver.target_from_weights_into`) evaluates, per region,
the precomputed eq. 5 weights and one table lookup already mapped to the pull
``T'_R c*_R`` (r,), into preallocated arrays: no Newton, no n-sized array, no
allocation. A region without a table (more than three examples, or a refused
table) solves its target by Newton at run time, with the energies of
:func:`region_energy_models`.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence

import numpy as np

from lbshape.elastic.element_kernels import mass_matrix
from lbshape.elastic.materials import Material
from lbshape.elastic.polynomial_energy import StVKPolynomialEnergy
from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh
from lbshape.shapespace.euclidean_energy import EuclideanExampleEnergy
from lbshape.shapespace.example_driver import ExampleDriver, TargetInfo
from lbshape.shapespace.interpolation import TargetSolver
from lbshape.shapespace.local_build import region_target_table
from lbshape.shapespace.local_regions import anchor_fit
from lbshape.shapespace.local_space import LocalShapeSpace, RegionSpace
from lbshape.shapespace.projections import block_basis
from lbshape.shapespace.target_table import TableSolver

log = logging.getLogger(__name__)

#: target energies of the local examples: exact polynomial (StVK) or all region elements
LOCAL_ROUTES = ("lb-exact", "euclidean")


def region_energy_models(mesh: TetMesh, material: Material, region: RegionSpace, *,
                         route: str) -> list:
    """One target energy model per example of a region (see
    :mod:`lbshape.shapespace.local_build`, "Targets")."""
    if route not in LOCAL_ROUTES:
        raise LbshapeError(f"local examples support the routes {', '.join(LOCAL_ROUTES)}, "
                           f"got {route!r}")
    basis = block_basis(region.eigenvectors)
    energy = StVKPolynomialEnergy if route == "lb-exact" else EuclideanExampleEnergy
    rests, tets = region.example_energy_shapes(mesh)
    return [energy(x, tets, material, basis) for x in rests]


def local_route(route: str, material: Material) -> str:
    """The local target route for a global route name and a material."""
    if route == "euclidean" or material.model != "stvk":
        return "euclidean"
    return "lb-exact"


class LocalExampleDriver:
    """Per-region :class:`ExampleDriver` s whose pulls add up (drop-in for the global one).

    Args:
        drivers: one driver per region; region R's ``to_reduced`` is ``T'_R``.
        spring: (r, r) ``S_q`` (see :mod:`lbshape.shapespace.local_space`).
        names: region names.
        rigid_pull: (r, r) ``Π`` added to the pull (``Π q``), or None.

    Attributes:
        spring: the spring matrix the dynamics use instead of the identity.
        last: per-region :class:`TargetInfo` of the last :meth:`target` call.

    The run-time step calls :meth:`weights_into` then :meth:`target_from_weights_into`:
    per region the precomputed weights and the target written into preallocated
    arrays (one table lookup per region when tabulated), nothing allocated.
    """

    def __init__(self, drivers: Sequence[ExampleDriver], spring: np.ndarray,
                 names: Sequence[str], *, rigid_pull: np.ndarray | None = None):
        if not drivers:
            raise LbshapeError("local examples need at least one region")
        self.drivers = list(drivers)
        self.spring = np.asarray(spring, dtype=float)
        self.names = tuple(names)
        r = self.drivers[0].D.shape[1]
        if self.spring.shape != (r, r):
            raise LbshapeError(f"spring must be ({r}, {r}), got {self.spring.shape}")
        self.rigid_pull = (None if rigid_pull is None
                           else np.ascontiguousarray(rigid_pull, dtype=float))
        self.last: tuple[TargetInfo, ...] = ()
        self._q = np.zeros(r)  # the state of the last weights_into call
        self._part = np.zeros(r)  # one region's pull

    def weights_into(self, q: np.ndarray) -> None:
        """Each region's weights for reduced coordinates q (r,), into its driver's ``w``."""
        self._q[:] = q
        for driver in self.drivers:
            driver.weights_into(q)

    def target_from_weights_into(self, out: np.ndarray) -> None:
        """The pull ``Σ_R T'_R c*_R + Π q`` (r,) for the weights of :meth:`weights_into`,
        written into ``out``."""
        if self.rigid_pull is None:
            out[:] = 0.0
        else:
            np.dot(self.rigid_pull, self._q, out=out)
        part = self._part
        for driver in self.drivers:
            driver.target_from_weights_into(part)
            np.add(out, part, out=out)

    def target(self, q: np.ndarray) -> TargetInfo:
        """Pull ``Σ_R T_R c*_R + Π q`` (r,), concatenated weights, total iterations."""
        started = time.perf_counter()
        infos = tuple(driver.target(q) for driver in self.drivers)
        self.last = infos
        total = np.sum([info.q_target for info in infos], axis=0)
        if self.rigid_pull is not None:
            total = total + self.rigid_pull @ q
        return TargetInfo(total, np.concatenate([info.weights for info in infos]),
                          int(sum(info.iterations for info in infos)),
                          time.perf_counter() - started)

    def region_weights(self, q: np.ndarray) -> dict[str, np.ndarray]:
        """Region name -> (k_R,) eq.-5 weights for reduced coordinates q (r,)."""
        return {name: d.weights(q) for name, d in zip(self.names, self.drivers, strict=True)}


def local_example_driver(mesh: TetMesh, material: Material, space: LocalShapeSpace, *,
                         route: str, tabulate: bool = True, free_rigid: bool = True,
                         tolerance: float = 1e-6, max_iterations: int = 20) -> LocalExampleDriver:
    """The runtime driver of the local examples (set-up is n_R-sized, steps are not).

    Args:
        mesh: the object's rest mesh.
        material: its material.
        space: the local shape space of the precompute.
        route: one of :data:`LOCAL_ROUTES`.
        tabulate: on the ``lb-exact`` route, regions look their target up in their
            table (:attr:`RegionSpace.table`, built here when the precompute has none);
            the ``euclidean`` baseline solves every step.
        free_rigid: anchor each region's target where the region is attached (the
            module docstring); False leaves the targets unanchored.
        tolerance, max_iterations: Newton settings of the target solves.
    """
    if route not in LOCAL_ROUTES:
        raise LbshapeError(f"local examples support the routes {', '.join(LOCAL_ROUTES)}, "
                           f"got {route!r}")
    drivers = []
    rho = material.density
    for region in space.regions:
        k = region.example_coefficients.shape[0]
        offsets = region.example_coefficients.reshape(k, -1)
        pull = region.pull_matrix(free_rigid=free_rigid)
        table = None
        if tabulate and route == "lb-exact":  # the baseline solves every step
            table = region.table
            if table is None and k <= 3:
                log.info("region %s: no target table in the precompute, built at set-up",
                         region.name)
                table = region_target_table(mesh, material, region)
        if table is not None:
            solver = TableSolver(table.mapped(pull), [None] * k, offsets)
        else:
            models = region_energy_models(mesh, material, region, route=route)
            solver = TargetSolver(models, offsets, tolerance=tolerance,
                                  max_iterations=max_iterations)
        drivers.append(ExampleDriver(region.descriptor_matrix(rho, free_rigid=free_rigid),
                                     region.example_descriptors(rho, free_rigid=free_rigid),
                                     solver, to_reduced=pull))
    return LocalExampleDriver(drivers, space.spring, [reg.name for reg in space.regions],
                              rigid_pull=space.rigid_pull if free_rigid else None)



def local_example_shape(mesh: TetMesh, space: LocalShapeSpace,
                        index: int | Sequence[int]) -> np.ndarray | None:
    """(n, 3) the object (m) with every region that example ``index`` guides in that
    example's region shape, attached at the region's anchor as the runtime attaches
    its targets: ``L_R c_k + Q_R g`` with g the rigid fit of ``−L_R c_k`` on the anchor
    (the rest state's, see the module docstring); None if no region uses it. Several
    indices: each region in the first of them that it uses. A vertex shared by
    regions gets their mean.

    Args:
        mesh: the object's rest mesh (n vertices).
        space: the local shape space.
        index: an example index in the scene's example list, or several.
    """
    indices = [index] if np.isscalar(index) else list(index)
    u, count = np.zeros((mesh.n_vertices, 3)), np.zeros(mesh.n_vertices)
    for region in space.regions:
        hits = np.flatnonzero(np.isin(region.examples, indices))
        if hits.size == 0:
            continue
        shape = region.displacement(region.example_coefficients[hits[0]]).reshape(-1)
        part = region.submesh(mesh)
        Q, F, rows = anchor_fit(part.points, mass_matrix(part, 1.0), region.anchor)
        u[region.vertices] += (shape - Q @ (F @ shape[rows])).reshape(-1, 3)
        count[region.vertices] += 1
    if not count.any():
        return None
    return u / np.maximum(count, 1)[:, None]
