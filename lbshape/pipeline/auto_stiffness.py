"""The precompute's ``example-stiffness`` stage: ``stiffness = "auto"`` on a scene's arrays.

Gathers what :func:`lbshape.shapespace.auto_stiffness.auto_example_stiffness` needs from
the stages before it: each example's displacement on the object (global examples:
``Φ c_k``, a free body's without its rigid fit; local examples: on the region's own mesh,
so that the zero displacement outside a region is no jump) and the loads' generalized
force ``‖Uᵀ f‖`` at full strength on the basis U of the moment (a local example: of the
loads on its region's vertices, the loads its region's pull stands out against). Local
examples' k_ex is then raised until the object's linear static equilibrium has every region
near an example (:func:`lbshape.shapespace.local_equilibrium.equilibrium_stiffness`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh, free_dof_mask
from lbshape.pipeline.responses import static_load
from lbshape.scene.schema import Scene
from lbshape.shapespace.auto_stiffness import AutoStiffness, auto_example_stiffness
from lbshape.shapespace.local_equilibrium import equilibrium_stiffness
from lbshape.shapespace.local_full_force import FullSpaceLocalForce
from lbshape.shapespace.local_space import LocalShapeSpace, RegionSpace

__all__ = ["auto_stiffness_stage", "region_load_force"]


def auto_stiffness_stage(scene: Scene, mesh: TetMesh, mass, U: np.ndarray, omega1_sq: float,
                         *, eigenvectors: np.ndarray | None = None,
                         coefficients: Sequence[np.ndarray] = (),
                         space: LocalShapeSpace | None = None, stiffness=None,
                         fixed_vertices: np.ndarray = ()) -> AutoStiffness:
    """The k_ex of ``stiffness = "auto"`` (module docstring).

    Args:
        scene: the scene (its material and loads).
        mesh: the object's rest mesh.
        mass: (3n, 3n) consistent mass, kg.
        U: (3n, r) the basis so far, ``UᵀMU = I``.
        omega1_sq: ω₁² of the object, rad²/s².
        eigenvectors: (n, m) Φ of the global examples' coefficients.
        coefficients: the global examples' (m, 3) coefficients.
        space: the local shape space (local examples).
        stiffness: (3n, 3n) K at rest without supports, N/m (local examples: their
            static equilibrium).
        fixed_vertices: (f,) the clamped vertices.

    Raises:
        LbshapeError: an example without strain energy, naming the scene.
    """
    chosen = _rule(scene, mesh, mass, U, omega1_sq, eigenvectors, coefficients,
                   () if space is None else space.regions)
    if space is None or not space.regions or scene.is_free:  # a free body: no supports
        return chosen
    force = FullSpaceLocalForce(mesh, scene.material, space)
    k_ex, closeness = equilibrium_stiffness(
        force, stiffness, free_dof_mask(mesh.n_vertices, fixed_vertices), chosen.k_ex,
        static_load(scene, mesh, mass) if scene.loads else None, mesh,
        scene.material.density)
    raised = k_ex > chosen.k_ex
    return dataclasses.replace(
        chosen, k_ex=k_ex, governing="regions" if raised else chosen.governing,
        raised_from=chosen.k_ex if raised else 0.0, closeness=tuple(closeness.items()))


def _rule(scene: Scene, mesh: TetMesh, mass, U: np.ndarray, omega1_sq: float,
          eigenvectors, coefficients, regions: Sequence[RegionSpace]) -> AutoStiffness:
    """:func:`auto_example_stiffness` of the scene's examples and loads."""
    load = static_load(scene, mesh, mass) if scene.loads else None
    if regions:
        fields = [field for region in regions for field in region.example_fields(mesh)]
        load_force = [region_load_force(region, U, load)
                      for region in regions for _ in region.example_coefficients]
    else:
        fields = [(mesh, eigenvectors @ np.asarray(c).reshape(-1, 3)) for c in coefficients]
        load_force = 0.0 if load is None else float(np.linalg.norm(U.T @ load))
    try:
        return auto_example_stiffness(fields, scene.material, omega1_sq=omega1_sq,
                                      load_force=load_force)
    except LbshapeError as exc:
        raise LbshapeError(f"scene {scene.name}: {exc}") from None


def region_load_force(region: RegionSpace, U: np.ndarray, load: np.ndarray | None) -> float:
    """``‖Uᵀ f_R‖`` (N/√kg): the generalized force of the loads on the region's vertices
    (``f_R``: the rows of ``load`` (3n,) N of the region's vertices, zero elsewhere; 0
    without loads)."""
    if load is None:
        return 0.0
    rows = (3 * np.asarray(region.vertices)[:, None] + np.arange(3)).ravel()
    return float(np.linalg.norm(U[rows].T @ load[rows]))
