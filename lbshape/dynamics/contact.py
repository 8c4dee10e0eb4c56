"""Penalty contact of an object's surface vertices with the scene's planes.

A plane is a point p (m), a unit normal n pointing into the free side and a
penalty stiffness k per area (N/m³: a pressure per metre of penetration). A surface
vertex at world position x penetrates by ``d = −(x − p)·n`` where positive; the pressure
k d, linear over each boundary triangle, is integrated exactly over the triangles' parts
that penetrate, weighted by the triangle's facing share ``max(0, −N_T·n)``
(:mod:`lbshape.dynamics.contact_faces`: the triangles' outward normals N_T in the body
frame turned by the rotation R; the full reference takes them from the deformed
surface), and shared by the corners: vertex i feels ``f = F_i n`` (N, world) with the
lumped stiffness S_i (N/m), the potential the integral of ``½ k d²``. A face resting on
the plane, or a strip of it along an edge, is held by the same force at any mesh
resolution. Below, for a vertex, ``k d`` stands for F_i and k for S_i.

**Friction** (regularised Coulomb). A plane's coefficient μ ≥ 0 adds, at every
penetrating vertex, the tangential force ``f_t = −μ k d · v_t / √(|v_t|² + ε²)`` (N,
world), ``v_t = (I − n nᵀ) w`` the tangential part of the vertex's world velocity w
relative to the static plane and ε = :data:`SLIP_SPEED`. Its size tends to the Coulomb
limit μ |f_n| for |v_t| ≫ ε and is linear in v_t below ε, so the implicit steps stay
smooth; the price is a creep: a block held by friction on a slope whose ratio
``tan θ / μ = s < 1`` slides at ``ε s / √(1 − s²)`` instead of sticking. Friction has no
potential (it only dissipates). Its rate matrix ``C = μ k d (P − t tᵀ/s²)/s``
(``P = I − n nᵀ``, ``t = v_t``, ``s = √(|t|² + ε²)``; symmetric positive
semi-definite, ``−∂f_t/∂w``) gives the 6 × 6 rigid rate matrix
``C₆ = Σ Bᵀ C B``, ``B = [I, −[arm]×]`` (:attr:`PlaneContact.damping_rigid`), and,
with the step's ``rate = ∂q̇₁/∂q₁``, the deformation's tangent ``rate Σ U_iᵀ Rᵀ C R U_i``
plus the normal force's share ``−μ k Σ U_iᵀ Rᵀ T gᵀ`` (``T = v_t/s``, ``g = U_iᵀ Rᵀ n``),
added to :attr:`PlaneContact.stiffness_q` (then not symmetric). The turn of the arm
with q (``ω × R U_i δq``) is left out of the tangent: exact for a body that does not
spin.

Positions follow the frame convention of :mod:`lbshape.dynamics.fictitious`:
``x_i = c + R (X̄_i + U_i q)`` (free body: c the centre of mass, R the rotation)
or ``x_i = X_i + U_i q`` (fixed object: c = 0, R = I, X̄ = X). The contact force
acts on the rigid body as a force and a torque about c (world) and on the
deformation as the generalized force ``Σ_i U_iᵀ Rᵀ f_i`` (r,); its stiffnesses
(6 × 6 rigid, r × r deformation) make implicit treatment possible.

Only surface vertices are touched, and not even those when a bounding sphere
shows that no plane can be reached: the sphere is centred at c with radius
``ρ₀ + u_max |q|``, ``ρ₀ = max |X̄_i|`` over the surface and ``u_max`` the largest
spectral norm of the vertex blocks U_i (so ``|U_i q| ≤ u_max |q|``). Within reach, an
evaluation over every surface vertex also makes the **near set**: the faces with a
corner closer than :data:`NEAR_MARGIN` ρ₀ to a reached plane, and their corners. Until a
surface point may have moved by that margin since (bounded by
``|Δc| + ‖ΔR‖_F (ρ₀ + u_max |q|) + u_max |Δq|``) or a new plane comes within reach, the
evaluations take only the near set: every other vertex stays clear of the planes, so
the outputs are those of the whole surface, bit for bit.

**Run-time path.** :meth:`PlaneContact.evaluate_into` writes every output into arrays
the contact owns (:attr:`PlaneContact.force`, …), through compiled kernels: the face
pass over the near set or every surface vertex (positions, gaps, forces and stiffnesses
of all reached planes; :mod:`lbshape.dynamics.contact_faces`), then the normal pass and,
when a plane has friction and a vertex penetrates, the friction pass over the loaded
vertices (:mod:`lbshape.dynamics.contact_kernels`); it allocates nothing but the near
set's two index views when it makes the set again.
:meth:`PlaneContact.evaluate` returns a copy as a :class:`ContactResult`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from lbshape.dynamics.contact_faces import (
    deform_kernel,
    face_kernel,
    near_holds,
    near_lists,
    surface_areas,
    surface_faces,
)
from lbshape.dynamics.contact_kernels import (
    ContactOutput,
    ContactWork,
    contact_kernel,
    friction_kernel,
    pack_motion,
    reach_kernel,
)
from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import boundary_faces

#: the near set's margin, a share of the body's radius ρ₀: the face pass takes only the
#: faces with a corner this close to a reached plane (and their corners) until some
#: surface point may have moved by as much (:meth:`PlaneContact._face_pass`)
NEAR_MARGIN = 0.05
#: ε of the regularised Coulomb friction (m/s): the slip speed below which the friction
#: force grows linearly with the slip (module docstring). Held by friction a block creeps
#: at about ε (tests/dynamics/test_friction.py; results/contact.md); the kick and the
#: deformation solve take its rate implicitly, with its tangent. The full reference
#: reaches its steps at this ε through a slip continuation where Newton from the
#: predictor fails (:func:`lbshape.dynamics.full_contact.step_with_slip_continuation`)
SLIP_SPEED = 5e-4
#: machine ε (the contact's round-off level)
_EPS = float(np.finfo(float).eps)


@dataclass(frozen=True)
class ContactPlane:
    """A contact plane: point (3,) m, unit normal (3,) into the free side, k in N/m³
    (per area of the surface: a vertex of lumped area A feels k A d), Coulomb friction
    coefficient μ ≥ 0 (0: frictionless)."""

    point: tuple[float, float, float]
    normal: tuple[float, float, float]
    stiffness: float
    friction: float = 0.0


@dataclass(frozen=True)
class ContactResult:
    """Contact forces of one configuration.

    Attributes:
        force: (3,) total force on the body (N, world).
        torque: (3,) total torque about c (N·m, world).
        generalized: (r,) ``Σ U_iᵀ Rᵀ f_i`` (reduced force, pushes q).
        stiffness_q: (r, r) ``−∂generalized/∂q`` (symmetric positive semi-definite
            without friction; with it, the step's ``rate`` share is included and the
            matrix is not symmetric).
        stiffness_rigid: (6, 6) ``Σ k [n; a][n; a]ᵀ``, ``a = (x − c) × n``: minus the
            derivative of the normal (force, torque) w.r.t. a translation and a small
            world rotation.
        damping_rigid: (6, 6) the friction's ``C₆``: minus the derivative of (force,
            torque) w.r.t. the rigid velocity (v, ω) (N·s/m …; zero without friction).
        energy: penalty energy (J).
        active: number of penetrating vertices.
        depth: largest penetration (m).
    """

    force: np.ndarray
    torque: np.ndarray
    generalized: np.ndarray
    stiffness_q: np.ndarray
    stiffness_rigid: np.ndarray
    damping_rigid: np.ndarray
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
        faces: (f, 3) the boundary triangles as rows of the surface vertices and
            ``face_areas`` (f, 3) their outward area vectors (m², body frame,
            :func:`~lbshape.dynamics.contact_faces.surface_faces`).
    """

    def __init__(self, planes: Sequence[ContactPlane], body_points: np.ndarray,
                 basis: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                 face_areas: np.ndarray):
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
            raise LbshapeError("contact stiffness must be > 0 N/m^3")
        self.friction = plane_frictions(planes)
        #: some plane has friction (the contact then depends on the velocities)
        self.has_friction = bool(np.any(self.friction > 0))
        self._k_max = float(self.stiffness.max())
        self._mu_max = float(self.friction.max())
        self.body_points = np.ascontiguousarray(body_points, dtype=float)
        self.basis = np.ascontiguousarray(basis, dtype=float)
        self.vertices = np.asarray(vertices, dtype=np.int64)
        #: (f, 3) the boundary triangles (rows of the surface vertices) and (f, 3) their
        #: outward area vectors (m², body frame)
        self.faces = np.ascontiguousarray(faces, dtype=np.int64)
        self.face_areas = np.ascontiguousarray(face_areas, dtype=float)
        if (self.face_areas.shape != self.faces.shape
                or not np.all(np.isfinite(self.face_areas))):
            raise LbshapeError("contact faces and their area vectors must be (f, 3), finite")
        s_count, P = self.body_points.shape[0], len(planes)
        #: per plane and vertex: [depth (m), normal force F (N), lumped stiffness S (N/m)]
        self._loads = np.zeros((P, 3, s_count))
        self._shares = np.zeros(self.faces.shape[0])
        self._blocks = np.zeros((self.faces.shape[0], 9))
        self._face_work = np.zeros((6, 3))
        self._face_buffers = (self._shares, self._blocks, self._face_work)
        self._arms = np.zeros((s_count, 3))
        r = self.basis.shape[2]
        self.r = r
        self.radius0 = float(np.linalg.norm(self.body_points, axis=1).max())
        self.u_max = float(max((np.linalg.norm(b, 2) for b in self.basis), default=0.0))
        self._near_init(s_count, P, r)
        #: vertex loops skipped by the bounding-sphere test / evaluated (counters)
        self.skipped = 0
        self.evaluated = 0
        #: the planes as the kernels read them, (P, 8): point, unit normal, k, μ
        self._planes = np.ascontiguousarray(np.column_stack(
            [self.points, self.normals, self.stiffness, self.friction]))
        #: outputs of the last :meth:`evaluate_into` (see :class:`ContactResult`): views of
        #: one buffer (:class:`ContactOutput`)
        self._out = ContactOutput.allocate(r)
        self.force, self.torque = self._out.force, self._out.torque
        self.generalized = self._out.generalized
        self.stiffness_q, self.stiffness_rigid = self._out.Kq, self._out.K6
        self.damping_rigid = self._out.C6
        #: (6, r) the friction's coupling ``Σ Bᵀ C R U_i`` of the rigid velocity and q̇:
        #: minus the derivative of (force, torque) w.r.t. q̇
        self.coupling = self._out.X
        #: [energy (J), active vertices, largest penetration (m)] of the last evaluation
        self.scalars = self._out.scalars
        self._reach = np.zeros(len(planes), dtype=np.bool_)
        self._work = ContactWork.allocate(r)
        # (s, r) the rows √S g of the loaded vertices: stiffness_q = Σ S g gᵀ as one
        # BLAS product (vertex by vertex it took 37 µs of 52 on a bar resting on 127)
        self._stiffness_rows = np.zeros((s_count * P, r))
        # (4 s P, r) the friction's rows: 2 per pair of √C G (C = L Lᵀ), then Gᵀ T, Gᵀ n
        self._friction_rows = np.zeros((4 * s_count * P, r))
        # the columns (L e; arm × L e) (2 s P, 6) of the coupling X = Σ Bᵀ C G, one
        # product, and the friction's pairs [vertex, plane, world velocity (3)] (s P, 5)
        self._friction_gathered = (self._friction_rows, np.zeros((2 * s_count * P, 6)),
                                   np.zeros((s_count * P, 5)))
        # the surface deformed in the body frame, y_i = X̄_i + U_i q, of the vertices the
        # face pass takes (the near set's: a BLAS product over the whole surface took
        # 4 µs of a 30 µs evaluation on the resting car)
        self._deformed = np.zeros(self.body_points.shape)
        # friction: the velocities of an evaluation without them (at rest), and the motion
        # the friction kernel reads: [v (3), ω (3), rate, q̇ (r)]
        self._rest3, self._rest_q = np.zeros(3), np.zeros(r)
        self._motion = np.zeros(7 + r)

    @classmethod
    def for_mesh(cls, planes: Sequence[ContactPlane], points: np.ndarray, tets: np.ndarray,
                 U: np.ndarray, *, center: np.ndarray | None = None) -> PlaneContact:
        """Contact of a mesh's surface; ``center`` (3,) is subtracted (free bodies)."""
        idx, _ = surface_areas(points, tets)
        faces, face_areas = surface_faces(points, tets, idx)
        n = points.shape[0]
        r = U.shape[1]
        body = points[idx] - (np.zeros(3) if center is None else np.asarray(center))
        basis = np.asarray(U).reshape(n, 3, r)[idx]
        return cls(planes, body, basis, idx, faces, face_areas)

    def may_touch(self, center: np.ndarray, q: np.ndarray) -> np.ndarray:
        """(P,) bool: planes the bounding sphere around ``center`` reaches."""
        reach_kernel(np.asarray(center, dtype=float), np.asarray(q, dtype=float),
                     self.radius0, self.u_max, self.points, self.normals, self._reach)
        return self._reach.copy()

    def evaluate_into(self, center: np.ndarray, rotation: np.ndarray, q: np.ndarray,
                      rigid: bool = True, velocity: np.ndarray | None = None,
                      omega: np.ndarray | None = None, qd: np.ndarray | None = None,
                      rate: float = 0.0) -> int:
        """Contact forces at (c (3,), R (3, 3), q (r,)) written into :attr:`force`,
        :attr:`torque`, :attr:`generalized`, :attr:`stiffness_q`, :attr:`stiffness_rigid`,
        :attr:`damping_rigid` and :attr:`scalars`; returns the number of penetrating
        vertices. No allocation.

        ``rigid=False`` leaves the torque and the 6 × 6 matrices at zero (fixed objects).
        Friction reads the motion: ``velocity`` (3,) of c (m/s, world), ``omega`` (3,)
        the world angular velocity (rad/s), ``qd`` (r,) the deformation's rate (each
        zero when ``None``), and ``rate`` = ∂q̇/∂q of the step (1/s) for the tangent.
        """
        if reach_kernel(center, q, self.radius0, self.u_max, self.points, self.normals,
                        self._reach):
            self.evaluated += 1
            self._face_pass(center, rotation, q)
        else:
            self.skipped += 1
        active = contact_kernel(self._arms, self.basis, self._loads, rotation, self._planes,
                                self._reach, rigid, self._work.data, self._out.data,
                                self._stiffness_rows)
        if self.has_friction and active:
            pack_motion(self._rest3 if velocity is None else velocity,
                        self._rest3 if omega is None else omega,
                        self._rest_q if qd is None else qd, float(rate), self._motion)
            friction_kernel(rotation, self._motion, self._arms, self.basis, self._loads,
                            self._planes, SLIP_SPEED, self._reach, rigid, self._work.data,
                            self._out.data, self._friction_gathered)
        elif self.has_friction:
            self.damping_rigid[:] = 0.0
            self.coupling[:] = 0.0
        return active

    def _near_init(self, s_count: int, planes: int, r: int) -> None:
        """The near set's arrays: the faces within :data:`NEAR_MARGIN` of a plane and
        their corners, made at an evaluation of every vertex, the pose it was made at
        ([c, R, q], (12 + r,)) and the planes reached then."""
        self._all_listed = (np.arange(s_count), np.arange(self.faces.shape[0]))
        self._near_vertices = np.zeros(s_count, dtype=np.int64)
        self._near_faces = np.zeros(self.faces.shape[0], dtype=np.int64)
        self._near_marks = np.zeros(s_count, dtype=np.int8)
        self._near_reference = np.zeros(12 + r)
        self._near_reach = np.zeros(planes, dtype=np.bool_)
        self._near_listed: tuple[np.ndarray, np.ndarray] | None = None
        self.margin = NEAR_MARGIN * self.radius0
        #: face passes over the near set / over every vertex (counters)
        self.near_passes = 0
        self.full_passes = 0

    def _face_pass(self, center: np.ndarray, rotation: np.ndarray, q: np.ndarray) -> None:
        """The vertices' arms and, per reached plane, their depths, normal forces and
        lumped stiffnesses (:func:`~lbshape.dynamics.contact_faces.face_kernel`) into
        ``_arms`` and ``_loads``: over the near set while it holds
        (:func:`~lbshape.dynamics.contact_faces.near_holds`; the same numbers bit for bit,
        every other vertex stays clear of the planes), else over every vertex, and the
        near set made again."""
        near = self._near_listed is not None and near_holds(
            center, rotation, q, self._near_reference, self.radius0, self.u_max,
            self.margin, self._reach, self._near_reach)
        listed = self._near_listed if near else self._all_listed
        self.near_passes += near
        self.full_passes += not near
        deform_kernel(listed[0], self.body_points, self.basis, q, self._deformed)
        self.scalars[0] = face_kernel(center, rotation, self._deformed, self.faces,
                                       self.face_areas, self._planes, self._reach,
                                       self._arms, self._loads, self._face_buffers, listed)
        if not near:
            count, faces = near_lists(self.faces, self._loads, self._reach, self.margin,
                                      self._near_marks, self._near_vertices,
                                      self._near_faces)
            self._near_listed = (self._near_vertices[:count], self._near_faces[:faces])
            reference = self._near_reference
            reference[:3], reference[3:12], reference[12:] = center, rotation.ravel(), q
            self._near_reach[:] = self._reach

    def evaluate(self, center: np.ndarray, rotation: np.ndarray, q: np.ndarray,
                 *, rigid: bool = True, velocity: np.ndarray | None = None,
                 omega: np.ndarray | None = None, qd: np.ndarray | None = None,
                 rate: float = 0.0) -> ContactResult:
        """Contact forces at the configuration (c (3,), R (3, 3), q (r,)) and motion
        (``velocity``, ``omega``, ``qd``, ``rate``: :meth:`evaluate_into`), as a new
        :class:`ContactResult` (:meth:`evaluate_into` is the allocation-free path).

        ``rigid=False`` skips the 6 × 6 matrices and the torque (fixed objects).
        """
        def vector(value):
            return None if value is None else np.asarray(value, dtype=float)

        active = self.evaluate_into(np.asarray(center, dtype=float),
                                    np.asarray(rotation, dtype=float),
                                    np.asarray(q, dtype=float), rigid, vector(velocity),
                                    vector(omega), vector(qd), rate)
        return ContactResult(self.force.copy(), self.torque.copy(), self.generalized.copy(),
                             self.stiffness_q.copy(), self.stiffness_rigid.copy(),
                             self.damping_rigid.copy(), float(self.scalars[0]), int(active),
                             float(self.scalars[2]))

    def round_off(self, center: np.ndarray, q: np.ndarray) -> float:
        """Round-off level of :attr:`generalized` of the last evaluation (pushes q): a gap
        is known to ε (machine) of the positions' size ``|c| + ρ₀ + u_max |q|`` (m), so
        each of the ``active`` penetrations' force ``k d`` to ``k`` times that, reaching q
        through ``|g| ≤ u_max``."""
        size = (math.sqrt(float(center @ center)) + self.radius0
                + self.u_max * math.sqrt(float(q @ q)))
        return float(_EPS * self._k_max * size * self.u_max * self.scalars[1]
                     * (1.0 + self._mu_max))


def plane_frictions(planes: Sequence[ContactPlane]) -> np.ndarray:
    """(P,) the planes' friction coefficients μ; :class:`LbshapeError` unless finite ≥ 0."""
    friction = np.array([p.friction for p in planes], dtype=float)
    if np.any(~np.isfinite(friction)) or np.any(friction < 0):
        raise LbshapeError("contact friction must be a finite number >= 0")
    return friction


def friction_force(velocity: np.ndarray, normal: np.ndarray, normal_force: np.ndarray,
                   friction: float, slip_speed: float = SLIP_SPEED
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Regularised Coulomb friction of many contact points on one plane (module docstring).

    Args:
        velocity: (h, 3) the points' world velocities w (m/s).
        normal: (3,) the plane's unit normal n.
        normal_force: (h,) the penalty force sizes k d (N).
        friction: μ.
        slip_speed: the regularisation ε in m/s.

    Returns:
        ``(f_t (h, 3) N, C (h, 3, 3) N·s/m, T (h, 3))``: the friction forces, their rate
        matrices ``C = −∂f_t/∂w = μ k d (P − T Tᵀ)/s`` and the slip directions
        ``T = v_t / s`` (``s = √(|v_t|² + ε²)``).
    """
    slip = velocity - (velocity @ normal)[:, None] * normal[None, :]
    s = np.sqrt(np.einsum("ha,ha->h", slip, slip) + slip_speed**2)
    scale = friction * normal_force / s
    direction = slip / s[:, None]
    projection = np.eye(3) - np.outer(normal, normal)
    rates = scale[:, None, None] * (projection[None]
                                    - direction[:, :, None] * direction[:, None, :])
    return -(friction * normal_force)[:, None] * direction, rates, direction
