"""Mesh files of any supported kind to a checked :class:`~lbshape.geometry.mesh.TetMesh`.

Three kinds of file, told apart by the extension:

* gmsh ``.msh`` — loaded by gmsh with its physical groups
  (:func:`lbshape.geometry.mesh.load_mesh`);
* volume meshes that meshio reads (:data:`VOLUME_FORMATS`: ``.vtu``, ``.vtk``,
  ``.mesh``, ``.xdmf``, ``.med``, ``.inp``, …) — their linear tetrahedra are kept,
  other cells (triangles, lines, vertices) ignored; a file without tetrahedra is an
  error (use a surface format for a surface);
* CAD solids (:data:`~lbshape.geometry.cad_files.CAD_FORMATS`: ``.step``, ``.iges``,
  ``.brep``) — read by gmsh's OpenCASCADE kernel and tetrahedralised at the size
  (:func:`lbshape.geometry.cad_files.read_cad_file`);
* closed triangle surfaces (:data:`SURFACE_FORMATS`: ``.stl``, ``.obj``, ``.ply``,
  ``.off``) — read by meshio, repaired
  (:func:`lbshape.geometry.surface_repair.repair_surface`: duplicate vertices,
  zero-area and duplicate triangles, orientation; holes with ``fill_holes``; one of
  several pieces with ``piece``), checked here (:func:`check_surface`: closed, edge-
  and vertex-manifold, one piece, no zero-area triangle) and tetrahedralised by gmsh
  (:func:`tetrahedralise_surface`). With a target size h the surface is remeshed at
  h first (gmsh's classify/reparametrise route); without one the surface
  triangles are kept as the boundary and the interior grows from them. A
  self-intersecting surface makes gmsh's boundary recovery fail, which is
  reported as such.

Every result passes :func:`lbshape.geometry.mesh.check_mesh`. Coordinates are
the file's numbers times the ``units`` (:data:`LENGTH_UNITS`, metres by default) or
``scale`` given; a STEP file converts from the unit it records.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.sparse.linalg import spsolve
from scipy.spatial import cKDTree

from lbshape.errors import LbshapeError
from lbshape.geometry.cad_files import CAD_FORMATS, LENGTH_UNITS, is_cad_file, read_cad_file
from lbshape.geometry.mesh import (
    TetMesh,
    check_mesh,
    gmsh_model,
    load_mesh,
    mesh_from_gmsh_model,
    write_gmsh_model,
)
from lbshape.geometry.surface_repair import (
    DEGENERATE_AREA_RTOL,
    checked_triangles,
    merge_vertices,
    repair_surface,
)

__all__ = [
    "CAD_FORMATS",
    "LENGTH_UNITS",
    "SURFACE_FORMATS",
    "VOLUME_FORMATS",
    "check_surface",
    "is_cad_file",
    "is_surface_file",
    "length_scale",
    "takes_size",
    "posed_surface_pair",
    "read_mesh_file",
    "read_surface",
    "tetrahedralise_surface",
    "write_msh",
]

log = logging.getLogger(__name__)

#: closed triangle surfaces, tetrahedralised by gmsh
SURFACE_FORMATS: tuple[str, ...] = (".stl", ".obj", ".ply", ".off")
#: tetrahedral volume meshes read with meshio (besides gmsh's own ``.msh``)
VOLUME_FORMATS: tuple[str, ...] = (".vtu", ".vtk", ".mesh", ".meshb", ".xdmf", ".med",
                                   ".inp", ".ele", ".node", ".xml")
#: gmsh's angle for splitting a remeshed surface into smooth patches (degrees)
FEATURE_ANGLE_DEG = 40.0


def is_surface_file(path: str | Path) -> bool:
    """True for a triangle surface format (:data:`SURFACE_FORMATS`)."""
    return Path(path).suffix.lower() in SURFACE_FORMATS


def takes_size(path: str | Path) -> bool:
    """True for files meshed at a size: surfaces and CAD solids (not volume meshes)."""
    return is_surface_file(path) or is_cad_file(path)


def length_scale(units: str = "m", scale: float | None = None, *, source: str = "mesh") -> float:
    """Metres per file number: ``scale`` if given, else the factor of ``units``.

    Raises:
        LbshapeError: an unknown unit (listing :data:`LENGTH_UNITS`) or a scale that
            is not a finite positive number.
    """
    if scale is not None:
        if isinstance(scale, bool) or not isinstance(scale, int | float) or not (
                math.isfinite(scale) and scale > 0):
            raise LbshapeError(f"{source}: scale must be a finite positive number, got "
                               f"{scale!r}")
        return float(scale)
    if units not in LENGTH_UNITS:
        raise LbshapeError(f"{source}: unknown units {units!r} (choose one of "
                           f"{', '.join(LENGTH_UNITS)}, or give a numeric scale)")
    return LENGTH_UNITS[units]


def read_mesh_file(path: str | Path, *, size: float | None = None,
                   require_connected: bool = True, units: str = "m",
                   scale: float | None = None, piece: int | str | None = None,
                   fill_holes: bool = False) -> TetMesh:
    """Load any supported mesh file as a checked tetrahedral mesh.

    Args:
        path: a ``.msh``, a meshio volume file, a CAD solid or a closed surface
            (module docstring).
        size: target edge length h in metres (after scaling) for a surface (remeshed
            at h) or a CAD solid; must be None for volume files, which are used as
            they are.
        require_connected: reject meshes made of several pieces.
        units: the unit of the file's numbers (:data:`LENGTH_UNITS`; "m" default).
        scale: metres per file number, instead of ``units``.
        piece: surface or CAD file of several pieces: the one to keep (its index as
            the error lists them, or ``"largest"``).
        fill_holes: close the holes of an open surface file.

    Raises:
        LbshapeError: missing file, unknown format or unit, a size for a volume file,
            no tetrahedra, no solid, a bad surface, or a mesh failing ``check_mesh``.
    """
    path = Path(path)
    if not path.is_file():
        raise LbshapeError(f"mesh file not found: {path}")
    suffix = path.suffix.lower()
    factor = length_scale(units, scale, source=str(path))
    if size is not None and not (math.isfinite(size) and size > 0):
        raise LbshapeError(f"{path}: mesh size must be a positive number of metres, got {size}")
    if suffix in CAD_FORMATS:
        return read_cad_file(path, size=size, units=units, scale=scale, piece=piece)
    if suffix in SURFACE_FORMATS:
        points, triangles = read_surface(path)
        points, triangles, _ = repair_surface(points * factor, triangles, source=str(path),
                                              piece=piece, fill_holes=fill_holes)
        return tetrahedralise_surface(points, triangles, size=size, source=str(path))
    if size is not None:
        raise LbshapeError(f"{path}: a mesh size applies to surface files "
                           f"({', '.join(SURFACE_FORMATS)}) and CAD files "
                           f"({', '.join(CAD_FORMATS)}), not to a volume mesh")
    if suffix == ".msh":
        mesh = load_mesh(path, require_connected=require_connected)
    elif suffix in VOLUME_FORMATS:
        mesh = _read_volume(path, require_connected=require_connected)
    else:
        raise LbshapeError(
            f"{path}: unsupported mesh format '{path.suffix}' (volume: .msh, "
            f"{', '.join(VOLUME_FORMATS)}; surface: {', '.join(SURFACE_FORMATS)}; CAD: "
            f"{', '.join(CAD_FORMATS)})"
        )
    return mesh if factor == 1.0 else mesh.with_points(mesh.points * factor)


def _meshio_read(path: Path):
    import meshio

    try:
        return meshio.read(str(path))
    except Exception as exc:  # meshio raises many types (ReadError, ValueError, KeyError…)
        detail = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise LbshapeError(f"{path}: cannot read mesh file ({detail})") from None


def _read_volume(path: Path, *, require_connected: bool) -> TetMesh:
    data = _meshio_read(path)
    blocks = [np.asarray(block.data) for block in data.cells if block.type == "tetra"]
    if not blocks:
        kinds = ", ".join(sorted({block.type for block in data.cells})) or "none"
        raise LbshapeError(f"{path}: no linear tetrahedra found (cells: {kinds}); "
                           "lbshape needs a tet mesh or a closed surface file")
    points = np.asarray(data.points, dtype=np.float64)
    if points.ndim == 2 and points.shape[1] == 2:
        raise LbshapeError(f"{path}: 2D points; lbshape needs a 3D tet mesh")
    mesh = TetMesh(points, np.concatenate(blocks).astype(np.int64))
    return check_mesh(mesh, require_connected=require_connected, source=str(path))


def read_surface(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a triangle surface file with meshio.

    Returns:
        points (n, 3) in metres and triangles (f, 3) int64, quads split in two.

    Raises:
        LbshapeError: unreadable file, or no triangles in it.
    """
    path = Path(path)
    data = _meshio_read(path)
    faces = []
    for block in data.cells:
        cells = np.asarray(block.data, dtype=np.int64)
        if block.type == "triangle":
            faces.append(cells)
        elif block.type == "quad":
            faces += [cells[:, [0, 1, 2]], cells[:, [0, 2, 3]]]
    if not faces:
        raise LbshapeError(f"{path}: no triangles found in the surface file")
    points = np.asarray(data.points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise LbshapeError(f"{path}: surface vertices must be 3D, got shape {points.shape}")
    return points, np.concatenate(faces)


def check_surface(points: np.ndarray, triangles: np.ndarray, *,
                  source: str = "surface") -> tuple[np.ndarray, np.ndarray]:
    """Check that a triangle surface bounds one solid; return it cleaned.

    Coincident vertices (within :data:`lbshape.geometry.surface_repair.MERGE_RTOL` of
    the bounding-box diagonal) are merged, as STL files repeat them per triangle;
    unused vertices dropped.

    Args:
        points: (n, 3) vertex positions in metres.
        triangles: (f, 3) vertex indices.
        source: a name for messages.

    Returns:
        points (n', 3) and triangles (f, 3) int64 after merging.

    Raises:
        LbshapeError: one line naming the first problem found: non-finite
            coordinates, index out of range, zero-area triangles, duplicate
            triangles, an open surface (edges on one triangle), non-manifold edges
            (on three or more triangles), non-manifold vertices (two fans meeting
            at a point), or several disconnected pieces.
    """
    points, tris = checked_triangles(points, triangles, source)

    points, tris = _merge_vertices(points, tris)
    _check_triangles(points, tris, source)
    edges, edge_id = _check_edges(tris, source)
    _check_vertex_fans(points, tris, edges, edge_id, source)

    pieces = _count_pieces(tris, points.shape[0])
    if pieces > 1:
        raise LbshapeError(f"{source}: surface has {pieces} disconnected pieces; "
                           "one closed body is required")
    return points, tris


def _check_triangles(points: np.ndarray, tris: np.ndarray, source: str) -> None:
    """No zero-area triangle (relative to the bounding-box diagonal) and no duplicate."""
    diag = float(np.linalg.norm(np.ptp(points, axis=0)))
    p = points[tris]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    bad = area <= DEGENERATE_AREA_RTOL * max(diag, np.finfo(float).tiny) ** 2
    if bad.any():
        raise LbshapeError(f"{source}: {int(bad.sum())} zero-area triangles "
                           f"(first: triangle {int(np.flatnonzero(bad)[0])})")
    _, first, counts = np.unique(np.sort(tris, axis=1), axis=0, return_index=True,
                                 return_counts=True)
    if (counts > 1).any():
        raise LbshapeError(f"{source}: {int((counts > 1).sum())} duplicate triangles "
                           f"(first: triangle {int(first[counts > 1][0])})")


def _check_edges(tris: np.ndarray, source: str) -> tuple[np.ndarray, np.ndarray]:
    """Every edge on exactly two triangles; returns the edges (e, 2) (sorted vertex
    pairs) and each triangle side's edge (3f,) (sides ab, then bc, then ca)."""
    half = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    edges, edge_id, counts = np.unique(np.sort(half, axis=1), axis=0, return_inverse=True,
                                       return_counts=True)
    if (counts == 1).any():
        a, b = edges[counts == 1][0]
        raise LbshapeError(
            f"{source}: surface is open: {int((counts == 1).sum())} boundary edges "
            f"(e.g. between vertices {a} and {b}); a closed surface is required")
    if (counts > 2).any():
        a, b = edges[counts > 2][0]
        raise LbshapeError(
            f"{source}: surface is non-manifold: {int((counts > 2).sum())} edges on more "
            f"than two triangles (e.g. between vertices {a} and {b})")
    return edges, edge_id.ravel()


def _check_vertex_fans(points: np.ndarray, tris: np.ndarray, edges: np.ndarray,
                       edge_id: np.ndarray, source: str) -> None:
    """The triangles around each vertex form one fan. Nodes of the graph are (vertex,
    incident edge) pairs; triangle (a, b, c) links (a, ab)-(a, ca) etc."""
    f = tris.shape[0]
    e_ab, e_bc, e_ca = edge_id[:f], edge_id[f:2 * f], edge_id[2 * f:]
    n_edges = edges.shape[0]

    def node(vertex, edge):  # which end of the edge the vertex is: 0 (smaller) or 1
        return 2 * edge + (edges[edge, 1] == vertex)

    rows = np.concatenate([node(tris[:, 0], e_ab), node(tris[:, 1], e_bc),
                           node(tris[:, 2], e_ca)])
    cols = np.concatenate([node(tris[:, 0], e_ca), node(tris[:, 1], e_ab),
                           node(tris[:, 2], e_bc)])
    graph = sp.coo_matrix((np.ones(rows.size), (rows, cols)), shape=(2 * n_edges, 2 * n_edges))
    _, labels = connected_components(graph, directed=False)
    owner = edges.ravel()  # vertex of node 2e + k is edges[e, k]
    fans = np.unique(np.stack([owner, labels]), axis=1)[0]
    per_vertex = np.bincount(fans, minlength=points.shape[0])
    if (per_vertex > 1).any():
        v = int(np.flatnonzero(per_vertex > 1)[0])
        raise LbshapeError(
            f"{source}: surface is non-manifold: {int((per_vertex > 1).sum())} vertices "
            f"where separate sheets touch (e.g. vertex {v} at {points[v].round(6).tolist()})")


def _merge_vertices(points: np.ndarray, tris: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    merged, tris, _ = merge_vertices(points, tris)
    return merged, tris


def _count_pieces(tris: np.ndarray, n: int) -> int:
    rows = np.repeat(tris[:, 0], 2)
    cols = tris[:, 1:].ravel()
    graph = sp.coo_matrix((np.ones(rows.size), (rows, cols)), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    return int(np.unique(labels[np.unique(tris)]).size)


def tetrahedralise_surface(points: np.ndarray, triangles: np.ndarray, *,
                           size: float | None = None, keep_surface: bool = False,
                           source: str = "surface") -> TetMesh:
    """Fill a closed triangle surface with linear tetrahedra (gmsh).

    Args:
        points: (n, 3) surface vertices in metres.
        triangles: (f, 3) vertex indices (orientation free).
        size: target edge length h (m): the surface is remeshed at h and the volume
            filled at h; None keeps the surface triangles and grows the interior
            sizes from them.
        keep_surface: keep the surface triangles even with a ``size`` (which then
            only caps the interior tetrahedra).
        source: a name for messages.

    Returns:
        The checked tetrahedral mesh (its surface vertices are the input's when
        ``size`` is None).

    Raises:
        LbshapeError: a bad surface (:func:`check_surface`) or gmsh failing to
            mesh it (a self-intersecting surface, most often).
    """
    points, tris = check_surface(points, triangles, source=source)
    with gmsh_model("lbshape-surface") as gmsh:
        remesh = size is not None and not keep_surface
        if size is not None:
            gmsh.option.setNumber("Mesh.MeshSizeMax", size)
        if remesh:
            gmsh.option.setNumber("Mesh.MeshSizeMin", 0.5 * size)
            gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0.0)
            gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0.0)
        surface = gmsh.model.addDiscreteEntity(2)
        gmsh.model.mesh.addNodes(2, surface, np.arange(1, points.shape[0] + 1).tolist(),
                                 points.ravel().tolist())
        gmsh.model.mesh.addElementsByType(surface, 2, [], (tris + 1).ravel().tolist())
        try:
            if remesh:
                gmsh.model.mesh.classifySurfaces(math.radians(FEATURE_ANGLE_DEG), True, True,
                                                 math.pi)
                gmsh.model.mesh.createGeometry()
            faces = [tag for _, tag in gmsh.model.getEntities(2)]
            loop = gmsh.model.geo.addSurfaceLoop(faces)
            gmsh.model.geo.addVolume([loop])
            gmsh.model.geo.synchronize()
            gmsh.model.mesh.generate(3)
        except Exception as exc:  # gmsh raises a bare Exception with its own message
            raise LbshapeError(_gmsh_failure(source, exc)) from None
        if not len(gmsh.model.mesh.getElementsByType(4)[0]):
            raise LbshapeError(_gmsh_failure(source, "no tetrahedra generated"))
        mesh = mesh_from_gmsh_model(gmsh.model, source=source)
    mesh = check_mesh(TetMesh(mesh.points, mesh.tets), source=source)
    log.info("%s: tetrahedralised to %d vertices, %d tets", source, mesh.n_vertices,
             mesh.n_tets)
    return mesh


def _gmsh_failure(source: str, exc) -> str:
    detail = " ".join(str(exc).split()) or "unknown error"
    return (f"{source}: gmsh could not tetrahedralise the surface; it is most likely "
            f"self-intersecting ({detail})")


def posed_surface_pair(rest_path: str | Path, posed_path: str | Path, *,
                       size: float | None = None, scale: float = 1.0
                       ) -> tuple[TetMesh, TetMesh] | None:
    """Tet meshes of a rest surface and its posed copy with one connectivity.

    A modelling tool that poses a surface keeps its triangles (and an STL file its
    facet order), which is a vertex correspondence. The rest surface is
    tetrahedralised keeping its triangles (``size`` caps the interior tetrahedra
    only); the posed mesh is the same tetrahedra with the surface vertices at their
    posed positions and the interior ones moved by the harmonic extension of the
    surface displacement (P1 Laplace problem on the rest mesh).

    Args:
        rest_path, posed_path: surface files (:data:`SURFACE_FORMATS`).
        size: largest interior edge length h in metres, or None.
        scale: metres per number of the two files (:func:`length_scale`).

    Returns:
        (rest, posed) with equal ``tets``, or None when the two surfaces do not have
        the same triangles (no correspondence: mesh them separately).

    Raises:
        LbshapeError: a bad surface (either file) or gmsh failing on the rest.
    """
    rest_points, rest_tris = read_surface(rest_path)
    posed_points, posed_tris = read_surface(posed_path)
    if rest_points.shape != posed_points.shape or not np.array_equal(rest_tris, posed_tris):
        return None
    rest_points, posed_points = rest_points * scale, posed_points * scale
    check_surface(posed_points, posed_tris, source=str(posed_path))
    check_surface(rest_points, rest_tris, source=str(rest_path))
    merged, tris, original = merge_vertices(rest_points, rest_tris)
    rest = tetrahedralise_surface(merged, tris, size=size, keep_surface=True,
                                  source=str(rest_path))
    distance, where = cKDTree(rest.points).query(merged)
    scale = float(np.linalg.norm(np.ptp(merged, axis=0)))
    if distance.max() > 1e-9 * scale:
        raise LbshapeError(f"{rest_path}: gmsh moved surface vertices; cannot carry the pose "
                           f"of {Path(posed_path).name} over")
    displacement = harmonic_extension(rest, where, posed_points[original] - merged)
    return rest, rest.with_points(rest.points + displacement)


def harmonic_extension(mesh: TetMesh, vertices: np.ndarray, values: np.ndarray) -> np.ndarray:
    """(n, 3) field equal to ``values`` (k, 3) on ``vertices`` (k,), harmonic elsewhere.

    Solves the P1 Laplace problem ``K u = 0`` on the free vertices of ``mesh`` with
    ``K = ∫ ∇φ·∇ψ`` assembled in numpy (units of ``values``).
    """
    p = mesh.points[mesh.tets]
    edges = p[:, 1:] - p[:, :1]  # (t, 3, 3): rows p_i - p_0
    inverse = np.linalg.inv(edges)  # columns: gradients of barycentric coordinates 1..3
    grads = np.concatenate([-inverse.sum(axis=2, keepdims=True), inverse], axis=2)
    volume = np.abs(np.linalg.det(edges)) / 6.0
    local = volume[:, None, None] * np.einsum("tki,tkj->tij", grads, grads)
    rows = np.repeat(mesh.tets, 4, axis=1).ravel()
    cols = np.tile(mesh.tets, (1, 4)).ravel()
    n = mesh.n_vertices
    K = sp.coo_matrix((local.ravel(), (rows, cols)), shape=(n, n)).tocsr()
    u = np.zeros((n, 3))
    u[vertices] = values
    free = np.setdiff1d(np.arange(n), vertices)
    if free.size:
        rhs = -(K[free][:, vertices] @ np.asarray(values, dtype=float))
        u[free] = np.column_stack([spsolve(K[free][:, free].tocsc(), rhs[:, c])
                                   for c in range(3)])
    return u


def write_msh(mesh: TetMesh, path: str | Path) -> Path:
    """Write a tet mesh as gmsh ``.msh`` (format 4.1, ASCII), atomically.

    Its vertex groups and cell groups are not written (a mesh read from a
    surface or meshio file has none); one discrete volume holds the tetrahedra.

    Raises:
        LbshapeError: a path not ending in ``.msh`` or that cannot be written.
    """
    path = Path(path)
    if path.suffix.lower() != ".msh":
        raise LbshapeError(f"{path}: output must be a .msh file")
    with gmsh_model("lbshape-write") as gmsh:
        volume = gmsh.model.addDiscreteEntity(3)
        gmsh.model.mesh.addNodes(3, volume, np.arange(1, mesh.n_vertices + 1).tolist(),
                                 mesh.points.ravel().tolist())
        gmsh.model.mesh.addElementsByType(volume, 4, [], (mesh.tets + 1).ravel().tolist())
        gmsh.option.setNumber("Mesh.SaveAll", 1)
        write_gmsh_model(gmsh, path)
    return path
