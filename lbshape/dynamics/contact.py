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

**Run-time path.** :meth:`PlaneContact.evaluate_into` writes every output into arrays
the contact owns (:attr:`PlaneContact.force`, …), through one compiled kernel that
loops over the surface vertices once (positions, gaps, forces and stiffnesses of all
reached planes); it allocates nothing. :meth:`PlaneContact.evaluate` returns a copy as
a :class:`ContactResult`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from lbshape._jit import njit
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
        r = self.basis.shape[2]
        self.r = r
        self.radius0 = float(np.linalg.norm(self.body_points, axis=1).max())
        self.u_max = float(max((np.linalg.norm(b, 2) for b in self.basis), default=0.0))
        #: vertex loops skipped by the bounding-sphere test / evaluated (counters)
        self.skipped = 0
        self.evaluated = 0
        #: outputs of the last :meth:`evaluate_into` (see :class:`ContactResult`)
        self.force, self.torque = np.zeros(3), np.zeros(3)
        self.generalized = np.zeros(r)
        self.stiffness_q, self.stiffness_rigid = np.zeros((r, r)), np.zeros((6, 6))
        #: [energy (J), active vertices, largest penetration (m)] of the last evaluation
        self.scalars = np.zeros(3)
        self._reach = np.zeros(len(planes), dtype=np.bool_)
        self._work, self._small = np.zeros(r), np.zeros(12)

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
        _reach_kernel(np.asarray(center, dtype=float), np.asarray(q, dtype=float),
                      self.radius0, self.u_max, self.points, self.normals, self._reach)
        return self._reach.copy()

    def evaluate_into(self, center: np.ndarray, rotation: np.ndarray, q: np.ndarray,
                      rigid: bool = True) -> int:
        """Contact forces at (c (3,), R (3, 3), q (r,)) written into :attr:`force`,
        :attr:`torque`, :attr:`generalized`, :attr:`stiffness_q`, :attr:`stiffness_rigid`
        and :attr:`scalars`; returns the number of penetrating vertices. No allocation.

        ``rigid=False`` leaves the torque and the 6 × 6 stiffness at zero (fixed objects).
        """
        if _reach_kernel(center, q, self.radius0, self.u_max, self.points, self.normals,
                         self._reach):
            self.evaluated += 1
        else:
            self.skipped += 1
        return _contact_kernel(center, rotation, q, self.body_points, self.basis, self.points,
                               self.normals, self.stiffness, self._reach, rigid, self._work,
                               self._small, self.force, self.torque, self.generalized,
                               self.stiffness_q, self.stiffness_rigid, self.scalars)

    def evaluate(self, center: np.ndarray, rotation: np.ndarray, q: np.ndarray,
                 *, rigid: bool = True) -> ContactResult:
        """Contact forces at the configuration (c (3,), R (3, 3), q (r,)), as a new
        :class:`ContactResult` (:meth:`evaluate_into` is the allocation-free path).

        ``rigid=False`` skips the 6 × 6 stiffness and the torque (fixed objects).
        """
        active = self.evaluate_into(np.asarray(center, dtype=float),
                                    np.asarray(rotation, dtype=float),
                                    np.asarray(q, dtype=float), rigid)
        return ContactResult(self.force.copy(), self.torque.copy(), self.generalized.copy(),
                             self.stiffness_q.copy(), self.stiffness_rigid.copy(),
                             float(self.scalars[0]), int(active), float(self.scalars[2]))


@njit
def _reach_kernel(center, q, radius0, u_max, points, normals, reach):
    """reach[p] = the bounding sphere reaches plane p; True if any plane is reached."""
    radius = radius0 + u_max * np.sqrt(np.dot(q, q))
    anything = False
    for p in range(points.shape[0]):
        distance = 0.0
        for a in range(3):
            distance += (center[a] - points[p, a]) * normals[p, a]
        reach[p] = distance <= radius
        anything = anything or reach[p]
    return anything


@njit
def _contact_kernel(center, rotation, q, body_points, basis, points, normals, stiffness,
                    reach, rigid, g, small, force, torque, generalized, Kq, K6, scalars):
    """One pass over the surface vertices (see :meth:`PlaneContact.evaluate_into`).

    Vertex i: ``y = X̄_i + U_i q`` (body), arm ``R y`` (world), gap per reached plane
    ``(R y + c − p)·n``; a penetration d > 0 adds ``k d n`` to the force, ``k d (arm × n)``
    to the torque, ``k d g`` with ``g = U_iᵀ Rᵀ n`` to the generalized force, ``k g gᵀ`` to
    ``stiffness_q`` and ``k J Jᵀ`` (J = [n; arm × n]) to the 6 × 6 stiffness.
    Returns the number of penetrations (vertex, plane). Work arrays: g (r,), small (12,).
    """
    r = q.shape[0]
    force[:] = 0.0
    torque[:] = 0.0
    generalized[:] = 0.0
    Kq[:, :] = 0.0
    K6[:, :] = 0.0
    energy = 0.0
    depth = 0.0
    active = 0
    J, arm, nb, y = small[0:6], small[6:9], small[9:12], small[0:3]  # y dies before J
    planes = points.shape[0]
    if not reach.any():
        scalars[0] = scalars[1] = scalars[2] = 0.0
        return 0
    for i in range(body_points.shape[0]):
        for a in range(3):
            value = 0.0
            for j in range(r):
                value += basis[i, a, j] * q[j]
            y[a] = body_points[i, a] + value
        for a in range(3):
            arm[a] = rotation[a, 0] * y[0] + rotation[a, 1] * y[1] + rotation[a, 2] * y[2]
        for p in range(planes):
            if not reach[p]:
                continue
            gap = 0.0
            for a in range(3):
                gap += (arm[a] + (center[a] - points[p, a])) * normals[p, a]
            if not gap < 0.0:
                continue
            d = -gap
            k = stiffness[p]
            active += 1
            depth = max(depth, d)
            energy += 0.5 * k * d * d
            for a in range(3):
                force[a] += k * d * normals[p, a]
                nb[a] = (rotation[0, a] * normals[p, 0] + rotation[1, a] * normals[p, 1]
                         + rotation[2, a] * normals[p, 2])  # Rᵀ n
            for j in range(r):
                g[j] = basis[i, 0, j] * nb[0] + basis[i, 1, j] * nb[1] + basis[i, 2, j] * nb[2]
                generalized[j] += k * d * g[j]
            for j in range(r):
                kg = k * g[j]
                for k2 in range(j + 1):
                    Kq[j, k2] += kg * g[k2]
            if rigid:
                n0, n1, n2 = normals[p, 0], normals[p, 1], normals[p, 2]
                J[0], J[1], J[2] = n0, n1, n2
                J[3] = arm[1] * n2 - arm[2] * n1
                J[4] = arm[2] * n0 - arm[0] * n2
                J[5] = arm[0] * n1 - arm[1] * n0
                for a in range(3):
                    torque[a] += k * d * J[3 + a]
                for a in range(6):
                    for b in range(a + 1):
                        K6[a, b] += k * J[a] * J[b]
    for j in range(r):
        for k2 in range(j):
            Kq[k2, j] = Kq[j, k2]
    for a in range(6):
        for b in range(a):
            K6[b, a] = K6[a, b]
    scalars[0] = energy
    scalars[1] = active
    scalars[2] = depth
    return active
