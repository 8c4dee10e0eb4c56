"""The directions from which a plane can meet an object: its convex hull's features.

A plane pressed against a body along −n touches the body's support set in that
direction, a face of its convex hull. The throws that load the most of the surface at
once are those whose plane lies flat on a hull feature:

* **faces** — the hull's facets grouped by normal (facets within :data:`GROUP_ANGLE_DEG`
  of a larger group's first facet join it; a flat side of the object, triangulated,
  is one group): one direction per group, its normal;
* **edges** — two groups whose facets share a hull edge: the bisector of their normals
  (a plane resting on the crease between two sides);
* **corners** — a hull vertex where three or more groups meet: the normalised mean of
  their normals.

A cuboid gives 6 + 12 + 8 directions. A rounded surface gives many small groups; the
largest :data:`MAX_FACES` are kept (by area), and the edges and corners among them.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass

import numpy as np
import scipy.spatial

from lbshape.errors import LbshapeError

#: facets whose normals are within this angle (degrees) of a group's first facet join it
GROUP_ANGLE_DEG = 10.0
#: at most this many face groups (the largest by area) give directions
MAX_FACES = 12


@dataclass(frozen=True)
class HullDirections:
    """Unit directions (outward normals of the plane's contact side) by kind.

    Attributes:
        faces: (f, 3) one per facet group.
        edges: (e, 3) one per pair of neighbouring groups.
        corners: (c, 3) one per hull vertex where three or more groups meet.
    """

    faces: np.ndarray
    edges: np.ndarray
    corners: np.ndarray

    @property
    def all(self) -> np.ndarray:
        """(f + e + c, 3) faces, then edges, then corners."""
        return np.vstack([self.faces, self.edges, self.corners])

    @property
    def kinds(self) -> tuple[str, ...]:
        """The kind of each row of :attr:`all`."""
        return (("face",) * len(self.faces) + ("edge",) * len(self.edges)
                + ("corner",) * len(self.corners))


def hull_points(points: np.ndarray) -> np.ndarray:
    """(h, 3) the vertices of the convex hull of ``points`` (n, 3)."""
    points = np.asarray(points, dtype=float)
    return points[scipy.spatial.ConvexHull(points).vertices]


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _facet_groups(hull, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(group of each facet, each group's unit normal (g, 3), each group's area (g,)),
    groups in order of their largest facet."""
    normals = hull.equations[:, :3]
    corners = points[hull.simplices]
    areas = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0],
                                          corners[:, 2] - corners[:, 0]), axis=1)
    cosine = np.cos(np.radians(GROUP_ANGLE_DEG))
    group = -np.ones(len(normals), dtype=np.int64)
    seeds: list[np.ndarray] = []
    for facet in np.argsort(-areas, kind="stable"):
        if seeds:
            match = np.flatnonzero(np.asarray(seeds) @ normals[facet] > cosine)
            if match.size:
                group[facet] = match[0]
                continue
        group[facet] = len(seeds)
        seeds.append(normals[facet])
    count = len(seeds)
    summed = np.zeros((count, 3))
    np.add.at(summed, group, normals * areas[:, None])
    area = np.bincount(group, weights=areas, minlength=count)
    return group, _unit(summed), area


def hull_directions(points: np.ndarray) -> HullDirections:
    """The face, edge and corner directions of the convex hull of ``points`` (n, 3) (m).

    Raises:
        LbshapeError: the points are flat or too few for a hull.
    """
    points = np.asarray(points, dtype=float)
    try:
        hull = scipy.spatial.ConvexHull(points)
    except scipy.spatial.QhullError as exc:
        raise LbshapeError(f"the object has no convex hull (flat or too few points): "
                           f"{str(exc).splitlines()[0]}") from None
    group, normals, area = _facet_groups(hull, points)
    kept = np.argsort(-area, kind="stable")[:MAX_FACES]
    keep = np.zeros(len(normals), dtype=bool)
    keep[kept] = True
    pairs = set()
    for facet, neighbours in enumerate(hull.neighbors):
        for other in group[neighbours]:
            a, b = sorted((int(group[facet]), int(other)))
            if a != b and keep[a] and keep[b]:
                pairs.add((a, b))
    meeting: dict[int, set[int]] = defaultdict(set)
    for facet, simplex in enumerate(hull.simplices):
        for vertex in simplex:
            meeting[int(vertex)].add(int(group[facet]))
    triples = {tuple(sorted(g)) for g in meeting.values()
               if len(g) >= 3 and all(keep[i] for i in g)}
    edges = [_unit(normals[a] + normals[b]) for a, b in sorted(pairs)]
    corners = [_unit(normals[list(t)].sum(axis=0)) for t in sorted(triples)]
    return HullDirections(normals[np.sort(kept)], np.reshape(edges, (-1, 3)),
                          np.reshape(corners, (-1, 3)))


def neighbouring_pairs(directions: np.ndarray) -> np.ndarray:
    """(e, 2) the pairs of ``directions`` (t, 3) whose regions on the unit sphere meet
    (indices, each pair ascending, the pairs sorted): the edges of the convex hull of the
    unit directions, their spherical Delaunay triangulation. A normal on the border of
    two directions' regions is nearest to both, so a set of columns for the pair holds a
    hit there from either side; 26 directions give 3 · 26 − 6 = 72 pairs.

    Raises:
        LbshapeError: the directions do not surround the origin (fewer than 4, or flat).
    """
    directions = np.asarray(directions, dtype=float)
    unit = directions / np.linalg.norm(directions, axis=1)[:, None]
    try:
        hull = scipy.spatial.ConvexHull(unit)
    except scipy.spatial.QhullError as exc:
        raise LbshapeError(f"{len(unit)} hull directions have no neighbours on the sphere "
                           f"(flat or too few): {str(exc).splitlines()[0]}") from None
    if len(hull.vertices) < len(unit) or not np.all(hull.equations[:, -1] < 0):
        raise LbshapeError(f"{len(unit)} hull directions do not surround the object "
                           "(some lie inside the others' hull, or all on one side)")
    pairs = {tuple(sorted((int(a), int(b)))) for simplex in hull.simplices
             for a, b in ((simplex[0], simplex[1]), (simplex[1], simplex[2]),
                          (simplex[0], simplex[2]))}
    return np.array(sorted(pairs), dtype=int).reshape(-1, 2)
