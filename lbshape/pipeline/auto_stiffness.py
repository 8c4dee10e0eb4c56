"""The precompute's ``example-stiffness`` stage: ``stiffness = "auto"`` on a scene's arrays.

Gathers what :func:`lbshape.shapespace.auto_stiffness.auto_example_stiffness` needs from
the stages before it: each example's displacement on the object (global examples:
``Φ c_k``, a free body's without its rigid fit; local examples: on the region's own mesh,
so that the zero displacement outside a region is no jump) and the loads' generalized
force ``‖Uᵀ f‖`` at full strength on the basis U of the moment (a local example: of the
loads on its region's vertices, the loads its region's pull stands out against).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh
from lbshape.pipeline.responses import static_load
from lbshape.scene.schema import Scene
from lbshape.shapespace.auto_stiffness import AutoStiffness, auto_example_stiffness
from lbshape.shapespace.local_space import RegionSpace

__all__ = ["auto_stiffness_stage", "region_load_force"]


def auto_stiffness_stage(scene: Scene, mesh: TetMesh, mass, U: np.ndarray, omega1_sq: float,
                         *, eigenvectors: np.ndarray | None = None,
                         coefficients: Sequence[np.ndarray] = (),
                         regions: Sequence[RegionSpace] = ()) -> AutoStiffness:
    """The k_ex of ``stiffness = "auto"`` (module docstring).

    Args:
        scene: the scene (its material and loads).
        mesh: the object's rest mesh.
        mass: (3n, 3n) consistent mass, kg.
        U: (3n, r) the basis so far, ``UᵀMU = I``.
        omega1_sq: ω₁² of the object, rad²/s².
        eigenvectors: (n, m) Φ of the global examples' coefficients.
        coefficients: the global examples' (m, 3) coefficients.
        regions: the local shape space's regions (local examples).

    Raises:
        LbshapeError: an example without strain energy, naming the scene.
    """
    load = static_load(scene, mesh, mass) if scene.loads else None
    if regions:
        fields = [(region.submesh(mesh), region.displacement(c))
                  for region in regions for c in region.example_coefficients]
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
