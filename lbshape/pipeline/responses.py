"""What a scene drives its object with: load patterns and example pulls, the forces
whose static responses the basis keeps (:mod:`lbshape.elastic.basis`).

* **Load patterns** (:func:`mesh_load_patterns`): the scene's ``[[loads]]`` as
  full-space force patterns (3n,) in N with their time profiles — the same patterns
  every method is driven by (:func:`lbshape.pipeline.simulate.load_patterns`).
* **Example pulls** (:func:`example_pulls`): each example's pose applied to the
  object's own rest mesh (global examples) or to the object's region it guides
  (local examples), as a displacement d_k (3n,) in m, with the mass S it pulls with
  (M for global examples, ``Σ_R M^(R)`` for local ones). The pose is the example's
  analytic pose evaluated on the object's points (no inversion check: it is a
  direction, not a rest shape); an example without an analytic pose (a posed mesh
  file) adds no direction.
* **Response loads** (:func:`response_loads`): f per load pattern and ``S d_k`` per
  example pull; their responses ``K⁻¹ f``, the linear static shapes the object takes
  under each, are solved with the modal derivatives' factorisation of K
  (:func:`lbshape.elastic.modal_derivatives.modal_derivatives`, ``static_loads``).
  Neither depends on a load's size or profile nor on k_ex (only on whether it is > 0),
  so runtime changes keep the precompute; a load's type, region and direction are part
  of the cache key (:func:`response_key`). Fixed objects only: a free body's loads move
  it rigidly, its deformation is already held by the plain basis, and an example
  response would take a derivative's place (measured on the car in
  ``docs/architecture.md``, "Response vectors in the basis").
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from lbshape.dynamics.loads import (
    TimedLoad,
    gravity_pattern,
    region_force_pattern,
    region_torque_pattern,
)
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh
from lbshape.geometry.poses import POSES
from lbshape.pipeline.meshes import selected_vertices
from lbshape.scene.schema import Scene
from lbshape.shapespace.local_examples import region_cells, submesh


def mesh_load_patterns(scene: Scene, mesh: TetMesh, mass) -> list[TimedLoad]:
    """The scene's loads as full-space patterns (3n,) in N with their time profiles.

    Args:
        scene: the scene (its ``loads``).
        mesh: the object's rest mesh (regions are selected on it).
        mass: (3n, 3n) node-major consistent mass in kg.
    """
    patterns = []
    for index, load in enumerate(scene.loads):
        what = f"loads[{index}] region"
        if load.type == "gravity":
            pattern = gravity_pattern(mass, load.vector)
        elif load.type == "region_force":
            pattern = region_force_pattern(mass, selected_vertices(load.selection, mesh, what=what),
                                           load.vector)
        elif load.type == "region_torque":
            pattern = region_torque_pattern(
                mass, mesh.points, selected_vertices(load.selection, mesh, what=what), load.vector)
        else:  # the scene schema only admits the types above
            raise LbshapeError(f"unsupported load type {load.type!r}")
        patterns.append(TimedLoad(pattern, load.profile))
    return patterns


def example_pulls(scene: Scene, mesh: TetMesh, mass) -> tuple[np.ndarray, sp.csr_matrix]:
    """The examples' pose displacements on the object and the mass they pull with.

    Returns:
        ``(D, S)``: D (3n, c) displacements in m, one per (region, example) or per
        example with an analytic pose; S (3n, 3n) kg (M, or ``Σ_R M^(R)`` over the
        regions). D has no column for a scene without examples.
    """
    n = mesh.n_vertices
    if scene.examples is None or not scene.examples.poses:
        return np.zeros((3 * n, 0)), sp.csr_matrix(mass)
    poses = scene.examples.poses
    columns = []
    if not scene.has_local_examples:
        for pose in poses:
            if pose.pose is not None:
                posed = POSES[pose.pose](mesh.points, **dict(pose.parameters))
                columns.append((posed - mesh.points).ravel())
        return _stack(columns, n), sp.csr_matrix(mass)
    rho = float(scene.material.density)
    spring = sp.csr_matrix((3 * n, 3 * n))
    for region in scene.regions:
        cells = region_cells(mesh, group=region.selection.group, region=region.selection.region,
                             what=f"region '{region.name}'")
        part, vertices = submesh(mesh, cells, what=f"region '{region.name}'")
        rows = (3 * vertices[:, None] + np.arange(3)).ravel()
        place = sp.csr_matrix((np.ones(rows.size), (rows, np.arange(rows.size))),
                              shape=(3 * n, rows.size))
        spring = spring + place @ mass_matrix(part, rho) @ place.T
        for k in region.examples:
            if poses[k].pose is None:
                continue
            posed = POSES[poses[k].pose](part.points, **dict(poses[k].parameters))
            field = np.zeros((n, 3))
            field[vertices] = posed - part.points
            columns.append(field.ravel())
    return _stack(columns, n), spring.tocsr()


def response_loads(scene: Scene, mesh: TetMesh, mass,
                   fixed_vertices: np.ndarray) -> np.ndarray:
    """(3n, c) forces in N whose static responses the basis keeps: the scene's load
    patterns, then the example pulls ``S d_k`` when the examples pull (k_ex > 0).

    Args:
        scene: the scene (loads, examples, regions, k_ex).
        mesh: the object's rest mesh.
        mass: (3n, 3n) consistent mass, kg.
        fixed_vertices: (f,) clamped vertices; none means a free body (no loads, see
            the module docstring).
    """
    if np.size(fixed_vertices) == 0:
        return np.zeros((3 * mesh.n_vertices, 0))
    columns = []
    if scene.loads:
        columns.append(np.column_stack([load.pattern
                                        for load in mesh_load_patterns(scene, mesh, mass)]))
    k_ex = scene.examples.stiffness if scene.examples is not None else 0.0
    if k_ex > 0:
        D, spring = example_pulls(scene, mesh, mass)
        if D.shape[1]:
            columns.append(spring @ D)
    return np.hstack(columns) if columns else np.zeros((3 * mesh.n_vertices, 0))


def response_key(scene: Scene) -> dict:
    """What the responses depend on beyond the precompute's own fields: each load's
    type, selection and direction (unit vector), and whether the examples pull."""
    loads = []
    for load in scene.loads:
        vector = np.asarray(load.vector, dtype=float)
        norm = float(np.linalg.norm(vector))
        direction = (vector / norm if norm > 0 else vector).round(12).tolist()
        loads.append({"type": load.type, "group": load.selection.group if load.selection
                      else None, "region": load.selection.region if load.selection else None,
                      "direction": direction})
    pulls = scene.examples is not None and scene.examples.stiffness > 0
    return {"loads": loads, "example_pulls": bool(pulls), "free": scene.is_free}


def _stack(columns: list[np.ndarray], n: int) -> np.ndarray:
    return np.column_stack(columns) if columns else np.zeros((3 * n, 0))
