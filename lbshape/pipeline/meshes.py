"""Scene data to meshes: build a mesh source, pose an example, select vertices.

The scene (:mod:`lbshape.scene.schema`) only says where meshes come from and which
vertices a region or group names; this module does the work: it runs the gmsh
script of a built-in shape or of a user (``.py``) or reads a mesh file (any format of
:func:`lbshape.geometry.mesh_files.read_mesh_file`, surfaces tetrahedralised at the
source's size), gives an example's rest and posed meshes (an analytic pose of
:mod:`lbshape.geometry.poses` applied, or a posed file paired with its rest), poses a
part of an example (a local-example region) and evaluates a selection on a mesh.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh
from lbshape.geometry.mesh_files import (
    is_surface_file,
    length_scale,
    posed_surface_pair,
    read_mesh_file,
    write_msh,
)
from lbshape.geometry.poses import apply_pose, pose_parts
from lbshape.geometry.regions import region_vertices
from lbshape.geometry.shapes import build_script, build_shape, write_script, write_shape
from lbshape.scene.schema import ExamplePose, MeshSource, Selection


def build_mesh(source: MeshSource) -> TetMesh:
    """The mesh of a source: the built-in shape's or the user's gmsh script run, the
    file read (a surface file tetrahedralised at ``source.size``), or the mesh held in
    memory (returned as it is)."""
    if source.mesh is not None:
        return source.mesh
    if source.shape is not None:
        return build_shape(source.shape, size=source.size)
    if source.script is not None:
        return build_script(source.script, size=source.size)
    return read_mesh_file(source.mesh_file, **source.read_options)


def write_mesh(source: MeshSource, path: str | Path) -> TetMesh:
    """Build ``source`` (:func:`build_mesh`) and write it as gmsh ``.msh`` (format 4.1),
    atomically; a gmsh script's physical groups are kept. Returns the mesh.

    Raises:
        LbshapeError: as :func:`build_mesh`, an output that is not ``.msh`` or would
            overwrite the input file, or a path that cannot be written.
    """
    path = Path(path)
    if path.suffix.lower() != ".msh":
        raise LbshapeError(f"{path}: output must be a .msh file")
    inputs = [f for f in (source.script, source.mesh_file) if f is not None]
    if any(path.resolve() == Path(f).resolve() for f in inputs):
        raise LbshapeError(f"{path}: output would overwrite the input file")
    if source.shape is not None:
        return write_shape(source.shape, path, size=source.size)
    if source.script is not None:
        return write_script(source.script, path, size=source.size)
    mesh = build_mesh(source)
    write_msh(mesh, path)
    return mesh


def posed_example(pose: ExamplePose, rest: TetMesh) -> TetMesh:
    """The example's rest mesh with its analytic pose applied, whole or part by part
    (:func:`~lbshape.geometry.poses.pose_parts`; ``rest`` if it has none)."""
    if pose.parts:
        parts = [(selected_vertices(part.selection, rest, what=f"example part {k}"),
                  part.pose, dict(part.parameters)) for k, part in enumerate(pose.parts)]
        held = (() if pose.hold is None
                else selected_vertices(pose.hold, rest, what="the example's hold"))
        return pose_parts(rest, parts, held)
    if pose.pose is None:
        return rest
    return apply_pose(rest, pose.pose, **dict(pose.parameters))


def posed_file_meshes(pose: ExamplePose, object_mesh: TetMesh) -> tuple[TetMesh, TetMesh]:
    """(posed, rest) meshes, with one connectivity, of an example given as a posed file
    or a posed mesh in memory (without analytic pose; a built-in shape without pose is
    at rest).

    The vertex correspondence between a posed mesh and its rest is what makes its
    displacement well defined, so it is required:

    * with ``rest``: the two files must share their connectivity: volume meshes
      with the same tetrahedra, or surfaces with the same triangles (a modelling
      tool's export keeps them, and an STL file its facet order), which are
      tetrahedralised together (:func:`lbshape.geometry.mesh_files.posed_surface_pair`);
    * without ``rest``: the posed file is a posed copy of the object (same
      tetrahedra), whose rest is the object's mesh.

    Raises:
        LbshapeError: no correspondence (the message says which files to give).
    """
    name = pose.source.label
    if pose.rest is None:
        posed = build_mesh(pose.source)
        if not _same_connectivity(posed, object_mesh):
            raise LbshapeError(
                f"posed example {name} has no vertex correspondence with the object "
                f"({posed.n_vertices} vs {object_mesh.n_vertices} vertices, or other tets): "
                "give its un-posed mesh as 'rest' (same mesh before posing)")
        return posed, object_mesh
    rest_file = pose.rest.mesh_file
    if (rest_file is not None and pose.source.mesh_file is not None
            and is_surface_file(pose.source.mesh_file) and is_surface_file(rest_file)):
        scale = length_scale(pose.source.units, pose.source.scale, source=name)
        pair = posed_surface_pair(rest_file, pose.source.mesh_file, size=pose.source.size,
                                  scale=scale)
        if pair is None:
            raise LbshapeError(
                f"posed example {name} and its rest {rest_file.name} have different "
                "triangles; export both from the same surface so that vertices correspond")
        return pair[1], pair[0]
    posed, rest = build_mesh(pose.source), build_mesh(pose.rest)
    if not _same_connectivity(posed, rest):
        raise LbshapeError(
            f"posed example {name} and its rest {pose.rest.label} have different meshes "
            f"({posed.n_vertices} vs {rest.n_vertices} vertices, or other tets); both must "
            "be the same mesh, or surfaces with the same triangles")
    return posed, rest


def example_meshes(pose: ExamplePose, object_mesh: TetMesh, *,
                   build: Callable[[MeshSource], TetMesh] = build_mesh
                   ) -> tuple[TetMesh, TetMesh]:
    """(rest, posed) meshes of an example, with one connectivity: the built mesh and
    its analytic pose applied (:func:`posed_example`), or a posed file and its rest
    (:func:`posed_file_meshes`; the object's mesh for a posed copy of the object).
    Every use of an example, whole or by region, starts here.

    Args:
        pose: the example.
        object_mesh: the object's rest mesh.
        build: builds the mesh of a source that is not a posed file (e.g. a memoised
            :func:`build_mesh` when several examples pose one mesh).

    Raises:
        LbshapeError: a posed file without vertex correspondence to its rest.
    """
    if pose.is_posed_file:
        posed, rest = posed_file_meshes(pose, object_mesh)
        return rest, posed
    rest = build(pose.source)
    return rest, posed_example(pose, rest)


def posed_part(pose: ExamplePose, part: TetMesh, vertices: np.ndarray,
               posed: TetMesh) -> np.ndarray:
    """(n_P, 3) posed positions (m) of a part of an example (a local-example region).

    An analytic pose is applied to the part itself: the pose's bar is the part (its
    extent along the pose axis, its anchor end). A posed file, an example posed part
    by part (or a shape at rest) gives its own positions of the part's vertices.

    Args:
        pose: the example.
        part: (n_P vertices) the part, cut from the example's rest mesh.
        vertices: (n_P,) int the part's vertices in that rest mesh.
        posed: the example's posed mesh (:func:`example_meshes`).
    """
    if pose.pose is not None:
        return posed_example(pose, part).points
    return np.asarray(posed.points)[vertices]


def _same_connectivity(a: TetMesh, b: TetMesh) -> bool:
    return a.n_vertices == b.n_vertices and np.array_equal(a.tets, b.tets)


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
