"""A free body measured the way the field measures one: before contact, per impact, at rest.

The whole-trajectory error of a free body (:mod:`lbshape.analysis.free_body`) mixes three
things: the flight (deterministic, should match to round-off), the impacts (where a
reduced body and the full reference differ) and the rest pose (where a symmetric object
may settle in an equivalent pose). The measures here take them apart:

* :func:`first_contact` / :func:`window_error` — the first sample at which any vertex of
  the reference penetrates a contact plane, and the trajectory error
  ``max_t ‖u − u_full‖_M / max_t ‖u_full‖_M`` over the samples strictly before it;
* :func:`surface_distance` — the symmetric Chamfer and Hausdorff distances between two
  surfaces (each vertex of one surface to the nearest point on the other's triangles,
  both ways), over the rest shape's bounding-box diagonal: a pose that differs by a
  symmetry of the object (a square bar turned 90° about its long axis) scores 0;
* :func:`project_state` — a full state (positions and velocities of the vertices)
  onto a reduced free body's coordinates: centre of mass, rotation, linear and angular
  momentum, deformation q and its rate (the synchronised restart of an impact);
* :func:`impact_measures` — one impact from sampled positions: restitution of the
  normal centre-of-mass velocity, the contact's change of linear and angular momentum
  (gravity's impulse removed), the mechanical energy lost, the deepest penetration.

Units: metres, seconds, kilograms; ratios dimensionless.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lbshape.analysis.norms import ROUNDOFF, m_norms, ratio
from lbshape.dynamics.rigid_frame import best_rigid_frame
from lbshape.errors import LbshapeError

#: sample-to-triangle distances are evaluated in chunks of this many points
_CHUNK = 256
#: a vertex counts as behind a plane from this depth on (m): a body whose rest mesh sits
#: on a plane touches it to round-off (1e-17 m) without being in contact
CONTACT_DEPTH = 1e-9


# ------------------------------------------------------------------ contact window
def penetration(points: np.ndarray, planes) -> np.ndarray:
    """The deepest penetration (m, ≥ 0) of each sample of ``points`` (k, n, 3) or (n, 3)
    into any of the ``planes`` (objects with ``point`` and unit ``normal``); (k,) or ()."""
    points = np.asarray(points, dtype=float)
    depth = np.zeros(points.shape[:-2])
    for plane in planes:
        signed = (points - np.asarray(plane.point, dtype=float)) @ np.asarray(plane.normal,
                                                                              dtype=float)
        depth = np.maximum(depth, np.maximum(-signed.min(axis=-1), 0.0))
    return depth


def first_contact(points: np.ndarray, planes) -> int | None:
    """Index of the first sample of ``points`` (k, n, 3) with a vertex more than
    :data:`CONTACT_DEPTH` behind a plane; None if none is (or there are no planes)."""
    touching = np.flatnonzero(penetration(points, planes) > CONTACT_DEPTH)
    return int(touching[0]) if touching.size else None


def window_error(u: np.ndarray, u_full: np.ndarray, mass, end: int) -> float | None:
    """``max ‖u − u_full‖_M / max ‖u_full‖_M`` over the samples ``[0, end)`` of two
    (k, n, 3) trajectories sampled at the same times; 0 when the numerator is round-off,
    None for an empty window or a reference that never moves in it."""
    u = np.asarray(u, dtype=float)
    u_full = np.asarray(u_full, dtype=float)
    if u.shape != u_full.shape:
        raise LbshapeError(f"trajectories of shapes {u.shape} and {u_full.shape}")
    end = int(end)
    if end <= 0:
        return None
    u, u_full = u[:end].reshape(end, -1), u_full[:end].reshape(end, -1)
    reference = float(m_norms(u_full, mass).max())
    return ratio(float(m_norms(u - u_full, mass).max()), reference, ROUNDOFF * reference)


# ----------------------------------------------------------------- surface distance
def _closest_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray,
                          c: np.ndarray) -> np.ndarray:
    """(P, T) distances of points p (P, 3) to triangles (a, b, c) (T, 3) each (Ericson's
    closest-point regions, vectorised)."""
    p = p[:, None, :]
    ab, ac = b - a, c - a
    ap = p - a
    d1, d2 = (ap * ab).sum(-1), (ap * ac).sum(-1)
    bp = p - b
    d3, d4 = (bp * ab).sum(-1), (bp * ac).sum(-1)
    cp = p - c
    d5, d6 = (cp * ab).sum(-1), (cp * ac).sum(-1)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    denom = va + vb + vc
    safe = np.where(np.abs(denom) > 0, denom, 1.0)
    v, w = vb / safe, vc / safe
    closest = a + v[..., None] * ab + w[..., None] * ac  # inside the face
    edges = ((vc <= 0) & (d1 >= 0) & (d3 <= 0), (vb <= 0) & (d2 >= 0) & (d6 <= 0),
             (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0))
    t_ab = d1 / np.where(d1 - d3 != 0, d1 - d3, 1.0)
    t_ac = d2 / np.where(d2 - d6 != 0, d2 - d6, 1.0)
    den_bc = (d4 - d3) + (d5 - d6)
    t_bc = (d4 - d3) / np.where(den_bc != 0, den_bc, 1.0)
    for mask, start, direction, t in ((edges[0], a, ab, t_ab), (edges[1], a, ac, t_ac),
                                      (edges[2], b, c - b, t_bc)):
        closest = np.where(mask[..., None], start + t[..., None] * direction, closest)
    corners = ((d1 <= 0) & (d2 <= 0), (d3 >= 0) & (d4 <= d3), (d6 >= 0) & (d5 <= d6))
    for mask, corner in zip(corners, (a, b, c), strict=True):
        closest = np.where(mask[..., None], np.broadcast_to(corner, closest.shape), closest)
    return np.linalg.norm(p - closest, axis=-1)


def point_surface_distances(points: np.ndarray, surface: np.ndarray,
                            triangles: np.ndarray) -> np.ndarray:
    """(P,) distance (m) of each point (P, 3) to the nearest point of the triangle surface
    (``surface`` (n, 3) vertex positions, ``triangles`` (T, 3) indices)."""
    points = np.asarray(points, dtype=float)
    surface = np.asarray(surface, dtype=float)
    a, b, c = (surface[triangles[:, i]] for i in range(3))
    out = np.empty(len(points))
    for start in range(0, len(points), _CHUNK):
        out[start:start + _CHUNK] = _closest_on_triangles(points[start:start + _CHUNK],
                                                          a, b, c).min(axis=1)
    return out


@dataclass(frozen=True)
class SurfaceDistance:
    """Two surfaces apart, over the rest shape's bounding-box diagonal (dimensionless).

    Attributes:
        chamfer: the symmetric Chamfer distance, the mean of each surface's vertices'
            distances to the other surface, averaged over both directions.
        hausdorff: the symmetric Hausdorff distance, the largest of those distances.
    """

    chamfer: float
    hausdorff: float


def surface_distance(points_a: np.ndarray, points_b: np.ndarray, triangles: np.ndarray,
                     diagonal: float) -> SurfaceDistance:
    """The symmetric surface-to-surface distance of two poses of one mesh.

    Args:
        points_a, points_b: (n, 3) the vertex positions of the two poses (m).
        triangles: (T, 3) the boundary triangles (vertex indices, the same for both).
        diagonal: the normalising length (m, > 0): the rest shape's bounding-box diagonal.

    Returns:
        The :class:`SurfaceDistance`; it ignores which vertex is where, so two poses that
        differ by a symmetry of the object are 0 apart (to round-off).
    """
    triangles = np.asarray(triangles, dtype=np.int64)
    if not (math.isfinite(diagonal) and diagonal > 0):
        raise LbshapeError(f"the normalising diagonal must be > 0 m, got {diagonal}")
    if np.shape(points_a) != np.shape(points_b) or triangles.ndim != 2 \
            or triangles.shape[1] != 3:
        raise LbshapeError(f"poses of shapes {np.shape(points_a)} and {np.shape(points_b)} "
                           f"with triangles {triangles.shape}")
    used = np.unique(triangles)
    ab = point_surface_distances(np.asarray(points_a)[used], points_b, triangles)
    ba = point_surface_distances(np.asarray(points_b)[used], points_a, triangles)
    chamfer = 0.5 * (float(ab.mean()) + float(ba.mean())) / diagonal
    hausdorff = max(float(ab.max()), float(ba.max())) / diagonal
    return SurfaceDistance(chamfer, hausdorff)


# ------------------------------------------------------------- projection, impacts
@dataclass(frozen=True)
class ProjectedState:
    """A full state as a reduced free body's state (world unless said otherwise).

    Attributes:
        c: (3,) centre of mass (m).
        R: (3, 3) body-to-world rotation (best mass-weighted rigid fit).
        p: (3,) linear momentum (kg m/s).
        L: (3,) angular momentum about c (kg m²/s).
        q, qd, qa: (r,) deformation (body frame), its rate and acceleration (the
            M-orthogonal projection onto the basis).
    """

    c: np.ndarray
    R: np.ndarray
    p: np.ndarray
    L: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qa: np.ndarray


def _momenta(scalar_mass, positions: np.ndarray, velocities: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(c, p, L about c)`` of vertex positions and velocities (n, 3) under M₁."""
    weights = np.asarray(scalar_mass.sum(axis=1)).ravel()
    mass = float(weights.sum())
    c = weights @ positions / mass
    p = weights @ velocities
    arm = positions - c
    moved = np.asarray(scalar_mass @ velocities)
    L = np.cross(arm, moved).sum(axis=0)
    return c, p, L


def project_state(frames: np.ndarray, dt: float, rest: np.ndarray, mass, basis: np.ndarray
                  ) -> ProjectedState:
    """Project the full state at the middle of three consecutive samples onto a reduced
    free body.

    Args:
        frames: (3, n, 3) world positions at t − dt, t, t + dt (m).
        dt: their spacing (s).
        rest: (n, 3) rest positions (m).
        mass: (3n, 3n) consistent mass (kg); its scalar block weights the fits.
        basis: (3n, r) the deformation basis U (body frame).

    Returns:
        The :class:`ProjectedState` at t: the middle frame's best rigid fit (c, R), the
        momenta of the central-difference vertex velocities, and q at the three frames
        (least squares in M) with its central differences as q̇ and q̈.
    """
    frames = np.asarray(frames, dtype=float)
    if frames.shape[0] != 3 or frames.shape[1:] != np.shape(rest):
        raise LbshapeError(f"three frames of shape {np.shape(rest)} needed, got {frames.shape}")
    scalar_mass = mass[0::3, 0::3]
    basis = np.asarray(basis, dtype=float)
    gram = basis.T @ (mass @ basis)
    qs, fits = [], []
    for positions in frames:
        c, R, body = best_rigid_frame(scalar_mass, rest, positions)
        fits.append((c, R))
        qs.append(np.linalg.solve(gram, basis.T @ (mass @ body.reshape(-1))))
    velocities = (frames[2] - frames[0]) / (2.0 * dt)
    c, p, L = _momenta(scalar_mass, frames[1], velocities)
    qd = (qs[2] - qs[0]) / (2.0 * dt)
    qa = (qs[2] - 2.0 * qs[1] + qs[0]) / dt**2
    return ProjectedState(fits[1][0], fits[1][1], p, L, qs[1], qd, qa)


@dataclass(frozen=True)
class ImpactMeasures:
    """One impact from sampled positions (see :func:`impact_measures`).

    Attributes:
        restitution: ``−v_n(after) / v_n(before)``, v_n the centre-of-mass velocity
            along the plane's normal.
        delta_p: (3,) the contact's change of linear momentum (kg m/s; gravity's
            impulse over the window removed).
        delta_L: (3,) change of angular momentum about the centre of mass (kg m²/s).
        energy_lost: the kinetic plus gravitational energy lost, over the centre of
            mass's kinetic energy before (dimensionless; the vibration's elastic energy
            counts as lost).
        depth: the deepest penetration in the window (m).
    """

    restitution: float
    delta_p: np.ndarray
    delta_L: np.ndarray
    energy_lost: float
    depth: float


def impact_measures(points: np.ndarray, mass, dt: float, normal: np.ndarray,
                    gravity: np.ndarray, planes, before: int, after: int) -> ImpactMeasures:
    """The impact between samples ``before`` and ``after`` of a trajectory.

    Args:
        points: (k, n, 3) world positions sampled every ``dt`` (s); ``before`` and
            ``after`` need a neighbour on each side (central differences).
        mass: (3n, 3n) consistent mass (kg).
        normal: (3,) the unit normal of the plane hit.
        gravity: (3,) the gravity acceleration (m/s²).
        planes: the contact planes, for the deepest penetration.
    """
    points = np.asarray(points, dtype=float)
    if not 1 <= before < after <= len(points) - 2:
        raise LbshapeError(f"impact window [{before}, {after}] outside 1..{len(points) - 2}")
    scalar_mass = mass[0::3, 0::3]
    total = float(scalar_mass.sum())
    states = []
    for index in (before, after):
        velocities = (points[index + 1] - points[index - 1]) / (2.0 * dt)
        c, p, L = _momenta(scalar_mass, points[index], velocities)
        kinetic = 0.5 * float(np.einsum("ij,ij->", velocities,
                                        np.asarray(scalar_mass @ velocities)))
        states.append((c, p, L, kinetic - total * float(np.asarray(gravity) @ c)))
    (c0, p0, L0, e0), (_, p1, L1, e1) = states
    normal = np.asarray(normal, dtype=float)
    delta_p = p1 - p0 - total * np.asarray(gravity, dtype=float) * (after - before) * dt
    v_before = float(p0 @ normal) / total
    restitution = -float(p1 @ normal) / total / v_before if v_before != 0.0 else math.nan
    kinetic0 = 0.5 * float(p0 @ p0) / total
    depth = float(penetration(points[before:after + 1], planes).max())
    return ImpactMeasures(restitution, delta_p, L1 - L0, (e0 - e1) / kinetic0, depth)
