"""The regions of the local examples (paper §5): which tetrahedra, their own mesh, and
where each is attached to the rest of the object.

**Rules.** Regions are sets of tetrahedra: a physical group must be a volume
group; an expression selects the tetrahedra whose centroid satisfies it. Regions
must not share a tetrahedron (one-line error naming both). Tetrahedra in no region
feel no example force (the spring ``S`` then differs from M: the spring only acts on
covered elements). Each region must be one connected piece with more than m + 1
vertices (checked by :func:`lbshape.shapespace.local_build.build_local_space`).
With one region covering every tetrahedron the whole path equals the global one
(no anchor, see below). Messages number the examples from 0, as the scene's
``examples`` lists do.

**Anchor.** A region's target is attached where the region is attached
(:mod:`lbshape.shapespace.local_space`, "Forces"): its anchor is its vertices shared
with the rest of the object, and its fixed vertices (:func:`region_anchor`), and the
rigid motion of a field on it is its lumped-mass least-squares fit there
(:func:`anchor_fit`, with the rigid fields of :func:`rigid_fields`).

**A region without neighbours is not anchored.** The anchor attaches a region's
target to the rest of the object; a region covering every tetrahedron has no rest
of the object to attach to, so its anchor is empty (its fixed vertices alone do not
make one) and its target is placed as the global path places the examples: one
region covering the object with all the examples *is* the global path, with the
default settings. Anchoring it on its fixed vertices would be another model (the
target moved rigidly to fit the support), not the paper's §4 (numbers in
``docs/decisions.md``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh
from lbshape.geometry.regions import evaluate_region


def region_cells(mesh: TetMesh, *, group: str | None = None, region: str | None = None,
                 what: str = "region") -> np.ndarray:
    """(t_R,) sorted int64 tetrahedra of ``mesh`` in a region.

    Args:
        mesh: the mesh.
        group: a volume physical group of the mesh, or
        region: a safe expression in x, y, z (m) evaluated at tetrahedron centroids.
        what: label for error messages.

    Raises:
        LbshapeError: neither or both given, an unknown (or non-volume) group, or an
            empty selection.
    """
    if (group is None) == (region is None):
        raise LbshapeError(f"{what}: give exactly one of a group or an expression")
    if group is not None:
        if group not in mesh.cell_groups:
            raise LbshapeError(
                f"{what}: mesh has no volume group '{group}' (volume groups: "
                f"{', '.join(sorted(mesh.cell_groups)) or 'none'})")
        cells = np.unique(np.asarray(mesh.cell_groups[group], dtype=np.int64))
    else:
        centroids = mesh.points[mesh.tets].mean(axis=1)
        cells = np.flatnonzero(evaluate_region(region, centroids)).astype(np.int64)
    if cells.size == 0:
        raise LbshapeError(f"{what} selects no tetrahedron of the mesh")
    return cells


def check_partition(names: Sequence[str], cells: Sequence[np.ndarray], n_tets: int) -> np.ndarray:
    """(n_tets,) bool: covered tetrahedra; one-line error if two regions overlap."""
    owner = np.full(n_tets, -1, dtype=np.int64)
    for index, (name, selected) in enumerate(zip(names, cells, strict=True)):
        taken = owner[selected]
        if (taken >= 0).any():
            other = names[int(taken[taken >= 0][0])]
            count = int((taken >= 0).sum())
            raise LbshapeError(
                f"local-example regions '{other}' and '{name}' share {count} tetrahedra; "
                "regions must be disjoint")
        owner[selected] = index
    return owner >= 0


def submesh(mesh: TetMesh, cells: np.ndarray, *,
            what: str = "region") -> tuple[TetMesh, np.ndarray]:
    """The mesh of some tetrahedra and its vertices' indices in ``mesh``.

    Returns:
        ``(sub, vertices)``: the sub-mesh (vertices in increasing original order,
        no groups) and (n_R,) int64 original vertex indices.

    Raises:
        LbshapeError: the tetrahedra form more than one connected piece.
    """
    tets = np.asarray(mesh.tets, dtype=np.int64)[cells]
    vertices = np.unique(tets)
    local = np.searchsorted(vertices, tets)
    n = vertices.size
    rows = np.repeat(local, 4, axis=1).ravel()
    cols = np.tile(local, (1, 4)).ravel()
    graph = sp.csr_matrix((np.ones(rows.size), (rows, cols)), shape=(n, n))
    pieces, _ = connected_components(graph, directed=False)
    if pieces != 1:
        raise LbshapeError(f"{what} is not connected ({pieces} pieces); split it into regions")
    return TetMesh(np.asarray(mesh.points)[vertices], local), vertices


def rigid_fields(points: np.ndarray, mass: sp.spmatrix) -> np.ndarray:
    """(3n, 6) node-major translations and infinitesimal rotations about the mass
    centre of ``points`` (n, 3), orthonormal in ``mass`` (3n, 3n)."""
    points = np.asarray(points, dtype=float)
    n = points.shape[0]
    weights = np.asarray(mass[0::3, 0::3].sum(axis=1)).ravel()
    x = points - weights @ points / weights.sum()
    R = np.zeros((n, 3, 6))
    R[:, :, :3] = np.eye(3)
    for axis in range(3):  # e_axis × x
        R[:, :, 3 + axis] = np.cross(np.eye(3)[axis], x)
    R = R.reshape(3 * n, 6)
    gram = R.T @ (mass @ R)
    return np.linalg.solve(np.linalg.cholesky(gram), R.T).T


def region_anchor(mesh: TetMesh, cells: np.ndarray, vertices: np.ndarray,
                  fixed_vertices: np.ndarray | None = None) -> np.ndarray:
    """(n_R,) bool: where a region is attached to the rest of the object: its vertices
    shared with tetrahedra outside it, and its fixed vertices. All False for a region
    covering every tetrahedron (no neighbour to attach to: its target is placed as
    the global path's, see the module docstring)."""
    outside = np.ones(mesh.n_tets, dtype=bool)
    outside[cells] = False
    anchor = np.isin(vertices, np.asarray(mesh.tets)[outside])
    if fixed_vertices is not None and anchor.any():
        anchor |= np.isin(vertices, fixed_vertices)
    return anchor


def anchor_fit(points: np.ndarray, mass: sp.spmatrix, anchor: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rigid fit on a region's anchor.

    Args:
        points: (n_R, 3) region vertices.
        mass: (3n_R, 3n_R) the region's mass.
        anchor: (n_R,) bool anchor vertices; none: no fit (g = 0, an unanchored region).

    Returns:
        ``(Q, F, rows)``: Q (3n_R, 6) mass-orthonormal rigid fields, rows the
        node-major anchor rows and F (6, rows.size) with ``g = F v[rows]`` the
        lumped-mass least-squares rigid fit of a field v (3n_R,) on the anchor
        (``Q F v[rows] = v`` for a rigid v; a degenerate anchor, e.g. collinear,
        fits with the minimum-norm g; F is (6, 0) without anchor).
    """
    Q = rigid_fields(points, mass)
    anchor = np.asarray(anchor, dtype=bool)
    rows = (3 * np.flatnonzero(anchor)[:, None] + np.arange(3)).ravel()
    if rows.size == 0:
        return Q, np.zeros((6, 0)), rows
    w = np.asarray(mass.sum(axis=1)).ravel()[rows]
    QA = Q[rows]
    F = np.linalg.pinv((QA * w[:, None]).T @ QA, rcond=1e-10) @ (QA * w[:, None]).T
    return Q, F, rows
