"""Penalty contact of a full-space object's surface vertices with planes
(:class:`FullSpaceContact`; a vertex's stiffness is the plane's k per area times its
the pressure integrated over the deformed surface's triangles, as in
:mod:`lbshape.dynamics.contact`), with the planes' regularised Coulomb friction, as the
full-space reference (:mod:`lbshape.dynamics.full`) evaluates it on full displacements."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp

from lbshape.dynamics.contact import (
    SLIP_SPEED,
    ContactPlane,
    friction_force,
    plane_frictions,
    surface_areas,
)
from lbshape.dynamics.contact_faces import FACING_FLOOR, face_loads, surface_faces
from lbshape.errors import LbshapeError, NewtonFailure

#: the widened slip speeds (multiples of ε) whose converged steps lead the full
#: reference's Newton back to ε when a step with friction does not converge from the
#: scheme's predictor (:func:`step_with_slip_continuation`)
SLIP_CONTINUATION = (16.0, 4.0)


class FullSpaceContact:
    """Penalty contact of the surface vertices with planes, on full displacements, with
    the planes' regularised Coulomb friction (:mod:`lbshape.dynamics.contact`).

    Args:
        planes: the :class:`~lbshape.dynamics.contact.ContactPlane` list.
        points: (n, 3) rest positions (m); ``tets`` (t, 4) give the surface.
    """

    def __init__(self, planes: Sequence[ContactPlane], points: np.ndarray, tets: np.ndarray):
        self.vertices, _ = surface_areas(points, tets)
        #: (f, 3) the boundary triangles as rows of the surface vertices
        self.faces, _ = surface_faces(points, tets, self.vertices)
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
        #: the friction's regularisation ε in m/s (widened for a while by the full
        #: reference's slip continuation, :meth:`FullSpaceSimulator.step`)
        self.slip_speed = SLIP_SPEED
        #: steps taken through the slip continuation so far
        self.continued_steps = 0
        self._positions = None  # (pattern, positions) of add_into's in-place additions

    def touches(self, u: np.ndarray) -> bool:
        """Whether a surface vertex of the displacement u (3n,) m lies behind a plane."""
        x = self.rest + u.reshape(-1, 3)[self.vertices]
        return any(float(np.min((x - np.asarray(plane.point)) @ n)) < 0.0
                   for plane, n in zip(self.planes, self.normals, strict=True))

    def face_shares(self, x: np.ndarray, normal: np.ndarray) -> np.ndarray:
        """(f,) the boundary triangles' areas facing a plane of unit normal ``normal``,
        ``max(β |a_T|, −a_T · n)`` (m², a_T the outward area vector on the deformed
        surface x (s, 3), β :data:`~lbshape.dynamics.contact_faces.FACING_FLOOR`)."""
        p = x[self.faces]
        vectors = 0.5 * np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        return np.maximum(-(vectors @ normal), FACING_FLOOR * np.linalg.norm(vectors, axis=1))

    def evaluate(self, u: np.ndarray, v: np.ndarray | None = None, rate: float = 0.0):
        """``(f (3n,) = +∂E/∂u − f_friction, K (3n, 3n) CSR or None, energy J)`` for
        u (3n,) m and the vertex velocities v (3n,) m/s (zero when ``None``).

        The normal forces F_i and their pair blocks ``k c_T M_jl n nᵀ`` come from the
        pressure over the triangles (:func:`~lbshape.dynamics.contact_faces.face_loads`).
        The friction force ``f_t = −μ F_i T_i`` (:func:`~lbshape.dynamics.contact.friction_force`)
        enters ``f`` with the internal-force sign; its tangent is ``rate C`` per vertex
        (``rate = ∂v/∂u`` of the step in 1/s, C the rate matrix) and ``−μ k c_T M_jl T_j nᵀ``
        per pair (T the slip direction): not symmetric. The change of the triangles'
        facing shares with u is left out.
        """
        force, parts, energy = self.evaluate_parts(u, v, rate)
        if not parts:
            return force, None, 0.0
        return force, self.matrix(parts), energy

    def matrix(self, parts) -> sp.csr_matrix:
        """The tangent (3n, 3n) CSR of :meth:`evaluate_parts`' ``parts``."""
        rows, cols, vals = [], [], []
        for faces, pair, loaded, rates in parts:
            corners = self.vertices[self.faces[faces]]
            if loaded is not None:
                self._add_blocks(rows, cols, vals, self.vertices[loaded],
                                 self.vertices[loaded], rates)
            self._add_blocks(rows, cols, vals, np.repeat(corners, 3, axis=1).ravel(),
                             np.tile(corners, (1, 3)).ravel(), pair.reshape(-1, 3, 3))
        return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows),
                                                     np.concatenate(cols))),
                             shape=(3 * self.n, 3 * self.n))

    def add_into(self, K: sp.csr_matrix, parts, free_dofs: np.ndarray, compiled=None, add=None):
        """K (free dofs) plus the tangent ``parts`` of :meth:`evaluate_parts`: in place on
        K's data through positions kept per ``compiled`` pattern
        (:class:`~lbshape.elastic.assembly.CompiledElasticity`) when K is on it, else
        ``add(K, tangent restricted to the free dofs)``."""
        if compiled is not None and compiled.on_pattern(K):
            kept = self._positions
            if kept is None or kept[0] is not compiled:
                kept = (compiled, self.pattern_positions(compiled.positions))
                self._positions = kept
            if kept[1] is not None:
                self.add_tangent(K.data, kept[1], parts)
                return K
        return add(K, self.matrix(parts)[free_dofs][:, free_dofs]).tocsr()

    def evaluate_parts(self, u: np.ndarray, v: np.ndarray | None = None, rate: float = 0.0,
                       *, tangent: bool = True, shares: bool = False):
        """``(f (3n,), parts, energy J)`` of :meth:`evaluate`, the tangent as its blocks: per
        plane touched ``(faces (m,), pair (m, 3, 3, 3, 3), loaded (h,) or None, rates
        (h, 3, 3))``, ``pair[t, j, l]`` the 3 × 3 block of the triangle's corners (j, l) and
        ``rates`` the friction's vertex blocks (``loaded`` surface rows; None: no friction).
        ``tangent=False`` (a residual or an energy alone): each touched plane's part is
        ``(None, None, None, None)``, its blocks not formed. ``shares``: the pairs hold the
        facing areas' change with the positions too (:meth:`_share_blocks`; the fast full
        reference; not symmetric), else it is left out (as :meth:`evaluate` does)."""
        x = self.rest + u.reshape(-1, 3)[self.vertices]
        s_count = x.shape[0]
        force = np.zeros((self.n, 3))
        parts = []
        energy = 0.0
        for plane, n, mu in zip(self.planes, self.normals, self.friction, strict=True):
            depth = -((x - np.asarray(plane.point)) @ n)
            if not depth.max() > 0.0:
                continue
            F, S = np.zeros(s_count), np.zeros(s_count)
            blocks = np.zeros((self.faces.shape[0], 9))
            energy += face_loads(self.faces, np.arange(self.faces.shape[0]), depth,
                                 self.face_shares(x, n),
                                 float(plane.stiffness), F, S, blocks, np.zeros((6, 3)))
            loaded = np.flatnonzero(S > 0.0)
            np.add.at(force, self.vertices[loaded], -F[loaded, None] * n[None, :])
            if mu > 0:
                w = (np.zeros((loaded.size, 3)) if v is None
                     else v.reshape(-1, 3)[self.vertices[loaded]])
                friction, rates, direction = friction_force(w, n, F[loaded], mu,
                                                            self.slip_speed)
                np.add.at(force, self.vertices[loaded], -friction)
            if not tangent:
                parts.append((None, None, None, None))
                continue
            touched = np.flatnonzero(np.any(blocks != 0.0, axis=1))
            M = blocks[touched].reshape(-1, 3, 3)  # (m, 3, 3) the triangles' pairs
            pair = M[:, :, :, None, None] * np.outer(n, n)[None, None, None]
            if shares:
                pair = pair + self._share_blocks(x[self.faces[touched]], n, M,
                                                 depth[self.faces[touched]])
            if not mu > 0:
                parts.append((touched, pair, None, None))
                continue
            slip = np.zeros((s_count, 3))
            slip[loaded] = direction
            pair = pair - mu * (M[:, :, :, None, None]
                                * slip[self.faces[touched]][:, :, None, :, None]
                                * n[None, None, None, None, :])
            parts.append((touched, pair, loaded, rate * rates))
        return force.ravel(), parts, energy

    @staticmethod
    def _share_blocks(corners: np.ndarray, normal: np.ndarray, M: np.ndarray,
                      depths: np.ndarray) -> np.ndarray:
        """(m, 3, 3, 3, 3) the pair blocks of the facing areas' change with the corners:
        ``− (k s (M d)_j / s) n ⊗ ∂s/∂p_l`` for corner j's force and corner l's position,
        s = ``max(β |a|, −a · n)`` (:meth:`face_shares`) and ``∂(a · ν)/∂p_l =
        ½ (p_{l+1} − p_{l−1}) × ν``.

        Args:
            corners: (m, 3, 3) the touched triangles' corner positions (m).
            normal: (3,) the plane's unit normal.
            M: (m, 3, 3) their blocks ``k s M_jl`` (N/m) of :func:`face_loads`.
            depths: (m, 3) the corners' penetrations (m).
        """
        vectors = 0.5 * np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        facing = -(vectors @ normal)
        length = np.linalg.norm(vectors, axis=1)
        floor = FACING_FLOOR * length
        share = np.maximum(facing, floor)
        along = np.where((facing >= floor)[:, None], -normal[None, :],
                         FACING_FLOOR * vectors / np.maximum(length, 1e-300)[:, None])
        gradient = 0.5 * np.cross(np.roll(corners, -1, axis=1) - np.roll(corners, 1, axis=1),
                                  along[:, None, :])  # (m, 3, 3): ∂s/∂p_l
        per_area = np.einsum("tjl,tl->tj", M, depths) / share[:, None]  # k (M d)_j
        return -(per_area[:, :, None, None, None] * normal[None, None, None, :, None]
                 * gradient[:, None, :, None, :])

    def add_tangent(self, data: np.ndarray, positions, parts) -> None:
        """Add the tangent ``parts`` of :meth:`evaluate_parts` into a CSR data array in
        place, through ``positions = (face (f, 81), vertex (s, 9))`` from
        :meth:`pattern_positions` (−1: an entry of a fixed dof, left out)."""
        face_positions, vertex_positions = positions
        where, values = [], []
        for faces, pair, loaded, rates in parts:
            where.append(face_positions[faces].ravel())  # pair's (m, j, l, a, b) order
            values.append(pair.ravel())
            if loaded is not None:
                where.append(vertex_positions[loaded].ravel())
                values.append(rates.ravel())
        where, values = np.concatenate(where), np.concatenate(values)
        kept = where >= 0
        if not kept.all():
            where, values = where[kept], values[kept]
        data += np.bincount(where, weights=values, minlength=data.size)

    def pattern_positions(self, locate):
        """``(face (f, 81), vertex (s, 9))`` positions of the tangent blocks' entries in a
        CSR data array, rows ``3 v_j + a`` by columns ``3 v_l + b`` in (j, l, a, b) order,
        from ``locate(rows, cols) -> positions`` over full dofs (−1: a fixed dof), or None
        when ``locate`` returns None (an entry outside the pattern)."""
        dofs = 3 * self.vertices[self.faces][:, :, None] + np.arange(3)  # (f, 3, 3): j, a
        shape = (dofs.shape[0], 3, 3, 3, 3)
        rows = np.broadcast_to(dofs[:, :, None, :, None], shape)
        cols = np.broadcast_to(dofs[:, None, :, None, :], shape)
        face = locate(rows.reshape(-1), cols.reshape(-1))
        own = 3 * self.vertices[:, None] + np.arange(3)
        vertex = locate(np.repeat(own, 3, axis=1).ravel(), np.tile(own, (1, 3)).ravel())
        if face is None or vertex is None:
            return None
        return face.reshape(-1, 81), vertex.reshape(-1, 9)

    @staticmethod
    def _add_blocks(rows: list, cols: list, vals: list, left: np.ndarray, right: np.ndarray,
                    blocks: np.ndarray) -> None:
        """3 × 3 ``blocks`` (m, 3, 3) at the vertex pairs (left, right) (m,) as COO lists."""
        a = 3 * left[:, None] + np.arange(3)[None, :]
        b = 3 * right[:, None] + np.arange(3)[None, :]
        rows.append(np.repeat(a, 3, axis=1).ravel())
        cols.append(np.tile(b, (1, 3)).ravel())
        vals.append(np.ascontiguousarray(blocks).ravel())


def step_with_slip_continuation(stepper, contact: FullSpaceContact | None,
                                guess: np.ndarray | None = None):
    """``stepper.step(guess)`` (an :class:`~lbshape.dynamics.integrators.ImplicitStepper`;
    ``guess`` the Newton iteration's first increment, None: the scheme's predictor);
    where its Newton iteration fails and the contact has friction, the same step again from
    the increment converged with the slip speed widened (:data:`SLIP_CONTINUATION`, each
    from the last, the first from ``guess``): regularised friction is steep within ε of
    the slip speed, where Newton may cycle between sticking and slipping vertices. The
    step taken is the one at ε, to the same residual test; only its starting point differs.

    Raises:
        SolverError: the step failed (at ε, or on the way down).
    """
    try:
        return stepper.step(guess)
    except NewtonFailure:
        if contact is None or not contact.has_friction:
            raise
    slip_speed = contact.slip_speed
    try:
        for factor in SLIP_CONTINUATION:
            contact.slip_speed = factor * slip_speed
            guess = stepper.trial_increment(guess)
    finally:
        contact.slip_speed = slip_speed
    info = stepper.step(guess)
    contact.continued_steps += 1
    return info
