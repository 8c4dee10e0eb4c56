"""Penalty contact of a full-space object's surface vertices with planes
(:class:`FullSpaceContact`; a vertex's stiffness is the plane's k per area times its
lumped area facing the plane on the deformed surface, as in
:mod:`lbshape.dynamics.contact`), with the planes' regularised Coulomb friction, as the
full-space reference (:mod:`lbshape.dynamics.full`) evaluates it on full displacements."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp

from lbshape.dynamics.contact import (
    ContactPlane,
    friction_force,
    plane_frictions,
    surface_areas,
)
from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import boundary_faces


class FullSpaceContact:
    """Penalty contact of the surface vertices with planes, on full displacements, with
    the planes' regularised Coulomb friction (:mod:`lbshape.dynamics.contact`).

    Args:
        planes: the :class:`~lbshape.dynamics.contact.ContactPlane` list.
        points: (n, 3) rest positions (m); ``tets`` (t, 4) give the surface.
    """

    def __init__(self, planes: Sequence[ContactPlane], points: np.ndarray, tets: np.ndarray):
        self.vertices, _ = surface_areas(points, tets)
        faces = boundary_faces(np.asarray(tets))
        #: (f, 3) the boundary triangles as rows of the surface vertices
        self.faces = np.searchsorted(self.vertices, faces)
        self.rest = np.asarray(points, dtype=float)[self.vertices]
        self.n = points.shape[0]
        self.planes = list(planes)
        normals = np.array([p.normal for p in self.planes], dtype=float).reshape(-1, 3)
        lengths = np.linalg.norm(normals, axis=1)
        if np.any(lengths == 0):
            raise LbshapeError("contact plane normals must be non-zero")
        #: (P, 3) unit normals (as :class:`~lbshape.dynamics.contact.PlaneContact` uses)
        self.normals = normals / lengths[:, None]
        self.friction = plane_frictions(self.planes)
        #: some plane has friction (the force then depends on the velocity)
        self.has_friction = bool(np.any(self.friction > 0))

    def area_vectors(self, x: np.ndarray) -> np.ndarray:
        """(s, 3) the surface vertices' lumped outward area vectors (m²) on the deformed
        surface x (s, 3) (:func:`~lbshape.dynamics.contact.surface_areas`)."""
        p = x[self.faces]
        share = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]) / 6.0
        out = np.zeros_like(x)
        for corner in range(3):
            np.add.at(out, self.faces[:, corner], share)
        return out

    def evaluate(self, u: np.ndarray, v: np.ndarray | None = None, rate: float = 0.0):
        """``(f (3n,) = +∂E/∂u − f_friction, K (3n, 3n) CSR or None, energy J)`` for
        u (3n,) m and the vertex velocities v (3n,) m/s (zero when ``None``).

        The friction force ``f_t`` (:func:`~lbshape.dynamics.contact.friction_force`)
        enters ``f`` with the internal-force sign; its tangent per vertex is
        ``rate C − μ k T nᵀ`` (``rate = ∂v/∂u`` of the step in 1/s, C the rate matrix,
        T the slip direction): the consistent tangent, not symmetric.
        """
        x = self.rest + u.reshape(-1, 3)[self.vertices]
        areas = self.area_vectors(x)
        force = np.zeros((self.n, 3))
        rows, cols, vals = [], [], []
        energy = 0.0
        for plane, n, mu in zip(self.planes, self.normals, self.friction, strict=True):
            gap = (x - np.asarray(plane.point)) @ n
            hit = np.flatnonzero(gap < 0.0)
            if hit.size == 0:
                continue
            d = -gap[hit]
            k = plane.stiffness * np.maximum(-(areas[hit] @ n), 0.0)  # (h,) N/m
            energy += 0.5 * float(k @ (d * d))
            np.add.at(force, self.vertices[hit], -(k * d)[:, None] * n[None, :])
            blocks = k[:, None, None] * np.outer(n, n)[None]
            if mu > 0:
                w = (np.zeros((hit.size, 3)) if v is None
                     else v.reshape(-1, 3)[self.vertices[hit]])
                friction, rates, direction = friction_force(w, n, k * d, mu)
                np.add.at(force, self.vertices[hit], -friction)
                blocks = (blocks + rate * rates
                          - mu * k[:, None, None] * direction[:, :, None] * n[None, None, :])
            dofs = 3 * self.vertices[hit][:, None] + np.arange(3)[None, :]  # (h, 3)
            rows.append(np.repeat(dofs, 3, axis=1).ravel())
            cols.append(np.tile(dofs, (1, 3)).ravel())
            vals.append(np.ascontiguousarray(blocks).ravel())
        if not rows:
            return force.ravel(), None, 0.0
        K = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(3 * self.n, 3 * self.n))
        return force.ravel(), K, energy
