"""Penalty contact of an object's surface vertices with the scene's planes.

A plane is a point p (m), a unit normal n pointing into the free side and a
penalty stiffness k (N/m per surface vertex). A surface vertex at world position
x penetrates by ``d = max(0, −(x − p)·n)`` and feels ``f = k d n`` (N, world),
with the potential ``½ k d²``. No friction.

Positions follow the frame convention of :mod:`lbshape.dynamics.fictitious`:
``x_i = c + R (X̄_i + U_i q)`` (free body: c the centre of mass, R the rotation)
or ``x_i = X_i + U_i q`` (fixed object: c = 0, R = I, X̄ = X). The contact force
acts on the rigid body as a force and a torque about c (world) and on the
deformation as the generalized force ``Σ_i U_iᵀ Rᵀ f_i`` (r,); its stiffnesses
(6 × 6 rigid, r × r deformation) make implicit treatment possible.

Only surface vertices are touched, and not even those when a bounding sphere
shows that no plane can be reached: the sphere is centred at c with radius
``ρ₀ + u_max |q|``, ``ρ₀ = max |X̄_i|`` over the surface and ``u_max`` the largest
spectral norm of the vertex blocks U_i (so ``|U_i q| ≤ u_max |q|``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import boundary_faces


@dataclass(frozen=True)
class ContactPlane:
    """A contact plane: point (3,) m, unit normal (3,) into the free side, k in N/m."""

    point: tuple[float, float, float]
    normal: tuple[float, float, float]
    stiffness: float


@dataclass(frozen=True)
class ContactResult:
    """Contact forces of one configuration.

    Attributes:
        force: (3,) total force on the body (N, world).
        torque: (3,) total torque about c (N·m, world).
        generalized: (r,) ``Σ U_iᵀ Rᵀ f_i`` (reduced force, pushes q).
        stiffness_q: (r, r) ``−∂generalized/∂q`` (symmetric positive semi-definite).
        stiffness_rigid: (6, 6) ``Σ k [n; a][n; a]ᵀ``, ``a = (x − c) × n``: minus the
            derivative of (force, torque) w.r.t. a translation and a small world rotation.
        energy: penalty energy (J).
        active: number of penetrating vertices.
        depth: largest penetration (m).
    """

    force: np.ndarray
    torque: np.ndarray
    generalized: np.ndarray
    stiffness_q: np.ndarray
    stiffness_rigid: np.ndarray
    energy: float
    active: int
    depth: float


def surface_vertices(tets: np.ndarray) -> np.ndarray:
    """(s,) sorted indices of the vertices on the boundary of ``tets`` (t, 4)."""
    return np.unique(boundary_faces(np.asarray(tets)).ravel())


class PlaneContact:
    """Penalty contact of a body's surface vertices with planes (module docstring).

    Args:
        planes: the contact planes (at least one).
        body_points: (s, 3) surface vertex positions X̄ in the body frame (m).
        basis: (s, 3, r) the surface vertices' rows of U.
        vertices: (s,) their indices in the mesh (for reference).
    """

    def __init__(self, planes: Sequence[ContactPlane], body_points: np.ndarray,
                 basis: np.ndarray, vertices: np.ndarray):
        if not planes:
            raise LbshapeError("contact needs at least one plane")
        self.points = np.array([p.point for p in planes], dtype=float)
        normals = np.array([p.normal for p in planes], dtype=float)
        lengths = np.linalg.norm(normals, axis=1)
        if np.any(lengths == 0):
            raise LbshapeError("contact plane normals must be non-zero")
        self.normals = normals / lengths[:, None]
        self.stiffness = np.array([p.stiffness for p in planes], dtype=float)
        if np.any(~np.isfinite(self.stiffness)) or np.any(self.stiffness <= 0):
            raise LbshapeError("contact stiffness must be > 0 N/m")
        self.body_points = np.ascontiguousarray(body_points, dtype=float)
        self.basis = np.ascontiguousarray(basis, dtype=float)
        self.vertices = np.asarray(vertices, dtype=np.int64)
        s, r = self.basis.shape[0], self.basis.shape[2]
        self.r = r
        self._flat = self.basis.reshape(s * 3, r)
        self.radius0 = float(np.linalg.norm(self.body_points, axis=1).max())
        self.u_max = float(max((np.linalg.norm(b, 2) for b in self.basis), default=0.0))
        #: vertex loops skipped by the bounding-sphere test / evaluated (counters)
        self.skipped = 0
        self.evaluated = 0

    @classmethod
    def for_mesh(cls, planes: Sequence[ContactPlane], points: np.ndarray, tets: np.ndarray,
                 U: np.ndarray, *, center: np.ndarray | None = None) -> PlaneContact:
        """Contact of a mesh's surface; ``center`` (3,) is subtracted (free bodies)."""
        idx = surface_vertices(tets)
        n = points.shape[0]
        r = U.shape[1]
        body = points[idx] - (np.zeros(3) if center is None else np.asarray(center))
        basis = np.asarray(U).reshape(n, 3, r)[idx]
        return cls(planes, body, basis, idx)

    def may_touch(self, center: np.ndarray, q: np.ndarray) -> np.ndarray:
        """(P,) bool: planes the bounding sphere around ``center`` reaches."""
        radius = self.radius0 + self.u_max * float(np.sqrt(q @ q))
        distance = np.einsum("pk,pk->p", center[None, :] - self.points, self.normals)
        return distance <= radius

    def evaluate(self, center: np.ndarray, rotation: np.ndarray, q: np.ndarray,
                 *, rigid: bool = True) -> ContactResult:
        """Contact forces at the configuration (c (3,), R (3, 3), q (r,)).

        ``rigid=False`` skips the 6 × 6 stiffness and the torque (fixed objects).
        """
        r = self.r
        force, torque = np.zeros(3), np.zeros(3)
        generalized, Kq, K6 = np.zeros(r), np.zeros((r, r)), np.zeros((6, 6))
        energy, active, depth = 0.0, 0, 0.0
        reach = self.may_touch(center, q)
        if not reach.any():
            self.skipped += 1
            return ContactResult(force, torque, generalized, Kq, K6, 0.0, 0, 0.0)
        self.evaluated += 1
        local = self.body_points + (self._flat @ q).reshape(-1, 3)  # (s, 3) body frame
        arm = local @ rotation.T  # (s, 3) x − c, world
        for plane in np.flatnonzero(reach):
            n, k = self.normals[plane], self.stiffness[plane]
            gap = (arm + (center - self.points[plane])) @ n
            hit = np.flatnonzero(gap < 0.0)
            if hit.size == 0:
                continue
            d = -gap[hit]
            active += hit.size
            depth = max(depth, float(d.max()))
            energy += 0.5 * k * float(d @ d)
            total = k * float(d.sum())
            force += total * n
            nb = rotation.T @ n  # normal in the body frame
            g = np.einsum("sar,a->sr", self.basis[hit], nb)  # (h, r): U_iᵀ Rᵀ n
            generalized += k * (d @ g)
            Kq += k * (g.T @ g)
            if rigid:
                a = np.cross(arm[hit], n)  # (h, 3)
                torque += k * (d @ a)
                J = np.concatenate([np.broadcast_to(n, a.shape), a], axis=1)  # (h, 6)
                K6 += k * (J.T @ J)
        return ContactResult(force, torque, generalized, Kq, K6, energy, active, depth)
