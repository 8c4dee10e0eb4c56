"""Scene data to meshes: build a mesh source, pose an example, select vertices.

The scene (:mod:`lbshape.scene.schema`) only says where meshes come from and which
vertices a region or group names; this module does the work: it runs the gmsh
script of a built-in shape or loads a mesh file, applies an analytic pose
(:mod:`lbshape.geometry.poses`) and evaluates a selection on a mesh.
"""

from __future__ import annotations

import numpy as np

from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh, load_mesh
from lbshape.geometry.poses import apply_pose
from lbshape.geometry.regions import region_vertices
from lbshape.geometry.shapes import build_shape
from lbshape.scene.schema import ExamplePose, MeshSource, Selection


def build_mesh(source: MeshSource) -> TetMesh:
    """The mesh of a source: the built-in shape's gmsh script run, or the file loaded."""
    if source.shape is not None:
        return build_shape(source.shape, size=source.size)
    return load_mesh(source.mesh_file)


def posed_example(pose: ExamplePose, rest: TetMesh) -> TetMesh:
    """The example's rest mesh with its analytic pose applied (``rest`` if it has none)."""
    if pose.pose is None:
        return rest
    return apply_pose(rest, pose.pose, **dict(pose.parameters))


def example_mesh(pose: ExamplePose) -> TetMesh:
    """The example's mesh, built from its source and posed."""
    return posed_example(pose, build_mesh(pose.source))


def selected_vertices(selection: Selection, mesh: TetMesh, *, what: str = "region") -> np.ndarray:
    """(k,) int64 indices of the vertices of ``mesh`` a selection names; error if none.

    Args:
        selection: a region expression in x, y, z (m) or a physical group name.
        mesh: the mesh to select on.
        what: what the selection is for, in error messages.

    Raises:
        LbshapeError: an unknown group, or a selection without any vertex.
    """
    if selection.region is not None:
        return region_vertices(selection.region, mesh.points, what=what)
    if selection.group not in mesh.vertex_groups:
        raise LbshapeError(
            f"{what}: mesh has no physical group '{selection.group}' "
            f"(groups: {', '.join(sorted(mesh.vertex_groups)) or 'none'})"
        )
    idx = np.asarray(mesh.vertex_groups[selection.group], dtype=np.int64)
    if idx.size == 0:
        raise LbshapeError(f"{what}: physical group '{selection.group}' has no vertex")
    return idx
