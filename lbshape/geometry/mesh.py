"""Tetrahedral meshes: the package's mesh type, loading from gmsh files, and checks.

Policy for bad input (applied by :func:`check_mesh`, consistently everywhere):

* no tetrahedra, NaN/inf coordinates, degenerate (near zero-volume) tetrahedra,
  indices out of range, or several disconnected bodies -> :class:`LbshapeError`;
* inverted tetrahedra (negative orientation) are **re-oriented** by swapping two
  vertices, and a warning with their count is logged;
* vertices used by no tetrahedron are dropped (indices compacted).
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from lbshape.errors import LbshapeError
from lbshape.io.atomic import write_atomic

log = logging.getLogger(__name__)

#: gmsh element type of the 4-node tetrahedron
_GMSH_TET4 = 4
#: relative tolerance for a degenerate tetrahedron: |vol| < tol * (mean edge)^3
DEGENERATE_RTOL = 1e-10


@dataclass(frozen=True)
class TetMesh:
    """A linear tetrahedral mesh.

    Attributes:
        points: (n, 3) float64 vertex coordinates in metres.
        tets: (t, 4) int64 vertex indices, positively oriented.
        cell_groups: name -> (k,) int64 indices of tetrahedra (gmsh physical volumes).
        vertex_groups: name -> (k,) int64 vertex indices (gmsh physical points,
            curves and surfaces).
    """

    points: np.ndarray
    tets: np.ndarray
    cell_groups: Mapping[str, np.ndarray] = field(default_factory=dict)
    vertex_groups: Mapping[str, np.ndarray] = field(default_factory=dict)

    @property
    def n_vertices(self) -> int:
        return int(self.points.shape[0])

    @property
    def n_tets(self) -> int:
        return int(self.tets.shape[0])

    def signed_volumes(self) -> np.ndarray:
        """(t,) signed tetrahedron volumes in m^3."""
        return signed_volumes(self.points, self.tets)

    def volume(self) -> float:
        """Total volume in m^3."""
        return float(np.sum(np.abs(self.signed_volumes())))

    def with_points(self, points: np.ndarray) -> TetMesh:
        """The same connectivity and groups on new vertex positions (n, 3)."""
        points = np.asarray(points, dtype=np.float64)
        if points.shape != self.points.shape:
            raise ValueError(f"points must have shape {self.points.shape}, got {points.shape}")
        return TetMesh(points, self.tets, self.cell_groups, self.vertex_groups)

    def boundary_faces(self) -> np.ndarray:
        """(f, 3) int64 boundary triangles, oriented with outward normals."""
        return boundary_faces(self.tets)


def free_dof_mask(n_vertices: int, fixed_vertices) -> np.ndarray:
    """(3n,) bool, node-major: the displacement DOFs of the vertices not in
    ``fixed_vertices`` ((f,) vertex indices)."""
    free = np.ones(3 * int(n_vertices), dtype=bool)
    free[(3 * np.asarray(fixed_vertices, dtype=np.int64).reshape(-1, 1) + np.arange(3))
         .ravel()] = False
    return free


def signed_volumes(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Signed volumes (t,) of tetrahedra ``tets`` (t, 4) on ``points`` (n, 3)."""
    p = points[tets]
    e1, e2, e3 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]
    return np.einsum("ij,ij->i", np.cross(e1, e2), e3) / 6.0


def boundary_faces(tets: np.ndarray) -> np.ndarray:
    """(f, 3) boundary triangles of positively oriented ``tets``, normals outward."""
    # faces opposite to vertex 0..3, each ordered so that its normal points outward
    local = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])
    faces = tets[:, local].reshape(-1, 3)
    key = np.sort(faces, axis=1).astype(np.int64)
    n = int(key.max(initial=0)) + 1
    if n < 2**21:  # one int64 per face: a 1-D sort, not a sort of rows
        key = (key[:, 0] * n + key[:, 1]) * n + key[:, 2]
        _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    else:
        _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return faces[counts[inverse.ravel()] == 1]


def locate_points(points: np.ndarray, tets: np.ndarray, queries: np.ndarray, *,
                  candidates: int = 16) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The element of a tetrahedral mesh that holds each query point, and its barycentric
    coordinates there: a P1 field's value at the point is their weighted sum over the
    element's vertices (a transfer between two meshes of one shape).

    The element is sought among the ``candidates`` elements with the nearest centroids. A
    point outside all of them (a curved boundary's vertex beyond the other mesh's chord)
    gets the least-outside one, its coordinates clipped to ≥ 0 and rescaled to sum 1.

    Args:
        points: (n, 3) the mesh's vertices (m).
        tets: (e, 4) its elements.
        queries: (q, 3) points (m).
        candidates: elements tried per point.

    Returns:
        (elements (q,), coordinates (q, 4), outside (q,)): the element index, the
        barycentric coordinates, and how far outside it each point lay (the most negative
        coordinate's magnitude, 0 inside).
    """
    from scipy.spatial import cKDTree

    points, tets = np.asarray(points, dtype=float), np.asarray(tets, dtype=np.int64)
    queries = np.asarray(queries, dtype=float).reshape(-1, 3)
    _, near = cKDTree(points[tets].mean(axis=1)).query(queries, k=min(candidates, len(tets)))
    near = near.reshape(len(queries), -1)  # (q, c)
    corners = points[tets[near]]  # (q, c, 4, 3)
    edges = np.swapaxes(corners[:, :, 1:] - corners[:, :, :1], -1, -2)  # columns x_i − x_0
    local = np.linalg.solve(edges, (queries[:, None] - corners[:, :, 0])[..., None])[..., 0]
    coordinates = np.concatenate([1.0 - local.sum(axis=-1, keepdims=True), local], axis=-1)
    best = coordinates.min(axis=-1).argmax(axis=1)  # the least-outside candidate
    rows = np.arange(len(queries))
    chosen = coordinates[rows, best]
    outside = np.maximum(-chosen.min(axis=1), 0.0)
    chosen = np.clip(chosen, 0.0, None)
    return near[rows, best], chosen / chosen.sum(axis=1, keepdims=True), outside


#: the farthest a point may lie outside the mesh for :func:`interpolate_at`, in barycentric
#: units of its nearest element (a curved boundary's vertex beyond the other mesh's chord:
#: the car at half its mesh size, 0.05)
MAX_OUTSIDE = 0.5


def interpolate_at(points: np.ndarray, tets: np.ndarray, values: np.ndarray,
                   queries: np.ndarray) -> np.ndarray:
    """Vertex values of a tetrahedral mesh interpolated (P1) at other points: ``values``
    (..., n, d) → (..., q, d), through :func:`locate_points` (a transfer between two
    meshes of one shape).

    Raises:
        LbshapeError: a query point lies outside the mesh by more than
            :data:`MAX_OUTSIDE` (the two meshes are not of one shape).
    """
    cells, weights, outside = locate_points(points, tets, queries)
    if outside.size and outside.max() > MAX_OUTSIDE:
        raise LbshapeError(f"{int((outside > MAX_OUTSIDE).sum())} points lie outside the mesh "
                           f"(up to {outside.max():.2g} of an element): not a mesh of the "
                           f"same shape")
    corners = np.asarray(tets)[cells]  # (q, 4)
    return np.einsum("qk,...qkd->...qd", weights, np.asarray(values)[..., corners, :])


def check_mesh(mesh: TetMesh, *, require_connected: bool = True, source: str = "mesh") -> TetMesh:
    """Validate a mesh and return a cleaned copy (see the module docstring for the policy).

    Args:
        mesh: the mesh to check.
        require_connected: reject meshes made of several disconnected bodies.
        source: a name for messages (usually the file path).

    Raises:
        LbshapeError: with a one-line message naming ``source``.
    """
    points = np.asarray(mesh.points, dtype=np.float64)
    tets = np.asarray(mesh.tets)
    if points.ndim != 2 or points.shape[1] != 3:
        raise LbshapeError(f"{source}: vertex array must be (n, 3), got {points.shape}")
    if tets.ndim != 2 or tets.shape[1] != 4 or tets.shape[0] == 0:
        raise LbshapeError(f"{source}: no tetrahedra found (lbshape needs a linear tet mesh)")
    tets = tets.astype(np.int64)
    if tets.min() < 0 or tets.max() >= points.shape[0]:
        raise LbshapeError(f"{source}: tetrahedron vertex index out of range")
    bad = ~np.isfinite(points).all(axis=1)
    if bad.any():
        raise LbshapeError(
            f"{source}: {int(bad.sum())} vertices have NaN or infinite coordinates "
            f"(first: vertex {int(np.flatnonzero(bad)[0])})"
        )

    # drop unused vertices, remap indices and vertex groups
    used = np.zeros(points.shape[0], dtype=bool)
    used[tets.ravel()] = True
    vertex_groups = dict(mesh.vertex_groups)
    if not used.all():
        new_index = -np.ones(points.shape[0], dtype=np.int64)
        new_index[used] = np.arange(int(used.sum()))
        points, tets = points[used], new_index[tets]
        vertex_groups = {k: new_index[v][new_index[v] >= 0] for k, v in vertex_groups.items()}

    vol = signed_volumes(points, tets)
    p = points[tets]
    edges = np.linalg.norm(p[:, [1, 2, 3, 2, 3, 3]] - p[:, [0, 0, 0, 1, 1, 2]], axis=2)
    scale = edges.mean(axis=1) ** 3
    degenerate = np.abs(vol) <= DEGENERATE_RTOL * np.maximum(scale, np.finfo(float).tiny)
    if degenerate.any():
        raise LbshapeError(
            f"{source}: {int(degenerate.sum())} degenerate (zero-volume) tetrahedra "
            f"(first: tet {int(np.flatnonzero(degenerate)[0])})"
        )
    inverted = vol < 0
    if inverted.any():
        log.warning("%s: re-oriented %d inverted tetrahedra", source, int(inverted.sum()))
        tets = tets.copy()
        tets[inverted] = tets[inverted][:, [0, 2, 1, 3]]

    if require_connected:
        n_pieces = count_components(points.shape[0], tets)
        if n_pieces > 1:
            raise LbshapeError(
                f"{source}: mesh has {n_pieces} disconnected pieces; one body is required"
            )
    return TetMesh(points, tets, dict(mesh.cell_groups), vertex_groups)


def count_components(n_vertices: int, tets: np.ndarray) -> int:
    """Number of connected pieces of the vertex graph of ``tets``."""
    rows = np.repeat(tets[:, 0], 3)
    cols = tets[:, 1:].ravel()
    graph = sp.coo_matrix((np.ones(rows.size), (rows, cols)), shape=(n_vertices, n_vertices))
    return int(connected_components(graph, directed=False)[0])


def mesh_from_gmsh_model(model, *, source: str = "gmsh model") -> TetMesh:
    """Extract the linear tetrahedra and physical groups of the current gmsh model.

    Args:
        model: the ``gmsh.model`` module (with a 3D mesh generated or loaded).
        source: a name for error messages.
    """
    node_tags, coords, _ = model.mesh.getNodes()
    if len(node_tags) == 0:
        raise LbshapeError(f"{source}: no mesh nodes found")
    node_tags = np.asarray(node_tags, dtype=np.int64)
    index = np.full(node_tags.max() + 1, -1, dtype=np.int64)
    index[node_tags] = np.arange(node_tags.size)
    points = np.asarray(coords, dtype=np.float64).reshape(-1, 3)

    types = model.mesh.getElementTypes(dim=3)
    other = [t for t in types if t != _GMSH_TET4]
    if other:
        names = ", ".join(model.mesh.getElementProperties(t)[0] for t in other)
        raise LbshapeError(f"{source}: unsupported 3D elements ({names}); only 4-node tetrahedra")
    tet_tags, tet_nodes = model.mesh.getElementsByType(_GMSH_TET4)
    if len(tet_tags) == 0:
        raise LbshapeError(f"{source}: no tetrahedra found (lbshape needs a linear tet mesh)")
    tets = index[np.asarray(tet_nodes, dtype=np.int64).reshape(-1, 4)]
    tet_position = {int(t): i for i, t in enumerate(tet_tags)}

    cell_groups: dict[str, np.ndarray] = {}
    vertex_groups: dict[str, np.ndarray] = {}
    for dim, tag in model.getPhysicalGroups():
        name = model.getPhysicalName(dim, tag) or f"{dim}:{tag}"
        if dim == 3:
            cells = []
            for entity in model.getEntitiesForPhysicalGroup(dim, tag):
                _, etags, _ = model.mesh.getElements(dim, entity)
                for group in etags:
                    cells.extend(tet_position[int(e)] for e in group if int(e) in tet_position)
            cell_groups[name] = np.unique(np.asarray(cells, dtype=np.int64))
        nodes, _ = model.mesh.getNodesForPhysicalGroup(dim, tag)
        if len(nodes):
            vertex_groups[name] = np.unique(index[np.asarray(nodes, dtype=np.int64)])
    return TetMesh(points, tets, cell_groups, vertex_groups)


def load_mesh(path: str | Path, *, require_connected: bool = True) -> TetMesh:
    """Load and check a tetrahedral mesh from a gmsh ``.msh`` file.

    Raises:
        LbshapeError: missing, unreadable or malformed file, or a mesh failing
            :func:`check_mesh`.
    """
    path = Path(path)
    if not path.is_file():
        raise LbshapeError(f"mesh file not found: {path}")
    if path.suffix.lower() != ".msh":
        raise LbshapeError(f"{path}: unsupported mesh format '{path.suffix}' (expected .msh)")
    with gmsh_session() as gmsh:
        gmsh.clear()
        try:
            gmsh.open(str(path))
        except Exception as exc:  # gmsh raises a bare Exception with its own message
            raise LbshapeError(f"{path}: not a readable gmsh file ({exc})") from None
        try:
            mesh = mesh_from_gmsh_model(gmsh.model, source=str(path))
        finally:
            gmsh.clear()
    return check_mesh(mesh, require_connected=require_connected, source=str(path))


#: gmsh options every lbshape model starts from (see :func:`gmsh_model`), so meshing
#: neither leaks options into nor inherits them from other gmsh work
GMSH_OPTION_BASELINE = {
    "Mesh.MeshSizeMin": 0.0,
    "Mesh.MeshSizeMax": 1e22,
    "Mesh.MeshSizeFactor": 1.0,
    "Mesh.MeshSizeFromPoints": 1.0,
    "Mesh.MeshSizeFromCurvature": 0.0,
    "Mesh.MeshSizeExtendFromBoundary": 1.0,
    "Mesh.MinimumCirclePoints": 7.0,
    "Mesh.MinimumCurvePoints": 3.0,
    "Mesh.Algorithm": 6.0,
    "Mesh.Algorithm3D": 1.0,
    "Mesh.Optimize": 1.0,
    "Mesh.OptimizeNetgen": 0.0,
    "Mesh.ElementOrder": 1.0,
    "Mesh.RandomSeed": 1.0,
    "Mesh.MshFileVersion": 4.1,
    "Mesh.Binary": 0.0,
    "Mesh.SaveAll": 0.0,
}


_gmsh_depth = 0


@contextlib.contextmanager
def gmsh_session() -> Iterator:
    """Yield the ``gmsh`` module, initialised and silent; re-entrant.

    gmsh 4.8 cannot tell whether it is initialised, so every use in lbshape goes
    through this counter: the outermost session initialises and finalises.
    """
    import gmsh

    global _gmsh_depth
    if _gmsh_depth == 0:
        gmsh.initialize(["-noenv"], readConfigFiles=False)
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.Verbosity", 0)
    _gmsh_depth += 1
    try:
        yield gmsh
    finally:
        _gmsh_depth -= 1
        if _gmsh_depth == 0:
            gmsh.finalize()


@contextlib.contextmanager
def gmsh_model(name: str) -> Iterator:
    """Yield ``gmsh`` with a fresh, empty model ``name`` and the options of
    :data:`GMSH_OPTION_BASELINE`; the caller's options are restored and the model
    cleared on exit (deterministic meshing whatever ran before)."""
    with gmsh_session() as gmsh:
        saved = {key: gmsh.option.getNumber(key) for key in GMSH_OPTION_BASELINE}
        gmsh.clear()
        try:
            for key, value in GMSH_OPTION_BASELINE.items():
                gmsh.option.setNumber(key, value)
            gmsh.model.add(name)
            yield gmsh
        finally:
            gmsh.clear()
            for key, value in saved.items():
                gmsh.option.setNumber(key, value)


def write_gmsh_model(gmsh, path: str | Path) -> Path:
    """Write the current gmsh model to ``path`` (``.msh``) atomically.

    Raises:
        LbshapeError: gmsh wrote nothing, or the file cannot be written.
    """
    path = Path(path)

    def write(tmp: Path) -> None:
        gmsh.write(str(tmp))
        if tmp.stat().st_size == 0:
            raise LbshapeError(f"{path}: gmsh wrote nothing")

    try:
        write_atomic(path, write)
    except OSError as exc:
        raise LbshapeError(f"cannot write {path}: {exc.strerror or exc}") from None
    return path
