"""The penalty pressure of a plane integrated over the surface's triangles, shared by the
reduced contact (:mod:`lbshape.dynamics.contact`) and the full reference
(:mod:`lbshape.dynamics.full_contact`).

A plane of stiffness k per area (N/m³) presses a surface point that penetrates it by d
with the pressure k d. The penetration is linear over a boundary triangle T (its
corners' depths ``d_j = −gap_j``), so the force the triangle takes,
``k c_T ∫_{T, d > 0} d dA`` (``c_T = max(β, −N_T · n)`` its facing share, N_T its unit
outward normal, β = :data:`FACING_FLOOR`), is integrated exactly over the part of T
that penetrates (a triangle or T minus a triangle, cut where d = 0) and shared by the
corners' linear shape functions φ_j: corner j takes ``F_j = k c_T Σ_l M_jl d_l``,
``M_jl = ∫_{T, d > 0} φ_j φ_l dA``; the energy is ``½ k c_T Σ M_jl d_j d_l``. A flat face
pressed into the plane, fully or tilted so that only a strip along an edge penetrates,
takes the same force at any mesh resolution. ``S_j = k c_T Σ_l M_jl`` (the force's
change with a common depth) is the vertex's lumped stiffness; the change of c_T and of
the cut with the pose is left out of the tangents.
"""

from __future__ import annotations

import numpy as np

from lbshape._jit import njit
from lbshape.geometry.mesh import boundary_faces

#: β, the least facing share of a triangle: a face standing on the plane or facing away
#: (a crumpled or buckled surface) still resists its penetration with β of its area. On
#: a face pressed by d its standing neighbours add β k d²/2 per metre of edge, second
#: order in d and independent of the mesh
FACING_FLOOR = 0.1


def surface_areas(points: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices (s,), area vectors (s, 3) m²)``: the surface vertices (sorted) and
    their lumped outward area vectors, a third of each boundary triangle's area times its
    outward unit normal at each of its corners (they sum to zero on a closed surface)."""
    faces = boundary_faces(np.asarray(tets))
    p = np.asarray(points, dtype=float)[faces]
    normal = 0.5 * np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])  # area × unit normal
    vertices, inverse = np.unique(faces.ravel(), return_inverse=True)
    inverse = inverse.ravel()
    share = np.repeat(normal / 3.0, 3, axis=0)
    vectors = np.column_stack([np.bincount(inverse, weights=share[:, a],
                                           minlength=vertices.size) for a in range(3)])
    return vertices, vectors


def surface_faces(points: np.ndarray, tets: np.ndarray,
                  vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(faces (f, 3) int64, area vectors (f, 3) m²)``: the boundary triangles as rows of
    ``vertices`` (the sorted surface vertices) and their outward area vectors."""
    faces = boundary_faces(np.asarray(tets))
    p = np.asarray(points, dtype=float)[faces]
    normal = 0.5 * np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return np.ascontiguousarray(np.searchsorted(vertices, faces), dtype=np.int64), normal


@njit
def face_loads(faces, face_list, depths, shares, k, F, S, blocks, work):
    """The pressure k d over the triangles ``face_list`` (indices into ``faces``, rising;
    module docstring) into the vertices' normal forces ``F`` (s,) N and lumped stiffnesses
    ``S`` (s,) N/m (both added to) and ``blocks`` (f, 9) the triangles' ``k c_T M`` (zero
    where nothing penetrates); ``depths`` (s,) the vertices' penetrations d (m, negative
    outside), ``shares`` (f,) the triangles' facing areas ``c_T |T|`` (m²), ``work``
    (6, 3). Returns the energy (J).
    """
    energy = 0.0
    M = work[0:3]
    for t in face_list:
        for e in range(9):
            blocks[t, e] = 0.0
        if shares[t] <= 0.0:
            continue
        i0, i1, i2 = faces[t, 0], faces[t, 1], faces[t, 2]
        d = (depths[i0], depths[i1], depths[i2])
        inside = (d[0] > 0.0) + (d[1] > 0.0) + (d[2] > 0.0)
        if inside == 0:
            continue
        _cut_mass(d, inside, M, work[3:6])
        scale = k * shares[t]
        for j in range(3):
            row = 0.0
            load = 0.0
            for m in range(3):
                value = scale * M[j, m]
                blocks[t, 3 * j + m] = value
                row += value
                load += value * d[m]
            F[faces[t, j]] += load
            S[faces[t, j]] += row
            energy += 0.5 * load * d[j]
    return energy


@njit
def _cut_mass(d, inside, M, corners):
    """``M_jl = ∫ φ_j φ_l dA`` over the part of the unit-area triangle where the linear
    d > 0 (``inside`` corners have d > 0), into M (3, 3); ``corners`` (3, 3) work."""
    for j in range(3):
        for m in range(3):
            M[j, m] = (2.0 if j == m else 1.0) / 12.0  # the whole triangle
    if inside == 3:
        return
    if inside == 1:  # the corner a's triangle alone
        a = 0 if d[0] > 0.0 else (1 if d[1] > 0.0 else 2)
        sign = 1.0
    else:  # the whole triangle minus the corner a's (the one outside)
        a = 0 if not d[0] > 0.0 else (1 if not d[1] > 0.0 else 2)
        sign = -1.0
    b, c = (a + 1) % 3, (a + 2) % 3
    tb = d[a] / (d[a] - d[b]) if d[a] != d[b] else 0.0  # the cut on the edge a–b
    tc = d[a] / (d[a] - d[c]) if d[a] != d[c] else 0.0
    area = tb * tc  # share of the triangle's area
    # the corners' barycentric coordinates: a, a + tb (b − a), a + tc (c − a)
    corners[:, :] = 0.0
    corners[0, a] = 1.0
    corners[1, a], corners[1, b] = 1.0 - tb, tb
    corners[2, a], corners[2, c] = 1.0 - tc, tc
    if inside == 1:
        M[:, :] = 0.0
    for j in range(3):
        for m in range(3):
            total_j = corners[0, j] + corners[1, j] + corners[2, j]
            total_m = corners[0, m] + corners[1, m] + corners[2, m]
            pair = (corners[0, j] * corners[0, m] + corners[1, j] * corners[1, m]
                    + corners[2, j] * corners[2, m])
            M[j, m] += sign * area / 12.0 * (pair + total_j * total_m)


@njit
def body_arm(i, rotation, deformed, arm):
    """The world arm ``R y_i`` (3,) about the centre of mass of surface point i, deformed
    ``y_i = X̄_i + U_i q`` (``deformed`` (s, 3), body frame, m), written into arm."""
    for a in range(3):
        arm[a] = (rotation[a, 0] * deformed[i, 0] + rotation[a, 1] * deformed[i, 1]
                  + rotation[a, 2] * deformed[i, 2])


@njit
def plane_gap(arm, center, planes, p):
    """Signed distance (m) of the point ``center + arm`` from plane p (negative: inside);
    ``planes`` (P, 8): point, unit normal, k, μ."""
    gap = 0.0
    for a in range(3):
        gap += (arm[a] + (center[a] - planes[p, a])) * planes[p, 3 + a]
    return gap


@njit
def face_kernel(center, rotation, deformed, faces, face_areas, planes, reach, arms, loads,
                buffers, listed):
    """The world arms ``R y_i`` of the ``listed`` vertices into ``arms`` (s, 3) and, per
    reached plane p, ``loads[p]`` = [depth d (m, negative outside), normal force F (N),
    lumped stiffness S (N/m)] of each from the pressure over the listed triangles
    (:func:`~lbshape.dynamics.contact_faces.face_loads`; ``buffers`` = (shares (f,),
    blocks (f, 9), work (6, 3)) its work). ``listed`` = (vertices, faces), rising
    indices: every vertex and face, or a near set (:func:`near_lists`) outside which
    nothing penetrates and every F and S is zero. Returns the penalty energy (J)."""
    shares, blocks, work = buffers
    vertices, face_list = listed
    for i in vertices:
        body_arm(i, rotation, deformed, arms[i])
    energy = 0.0
    for p in range(planes.shape[0]):
        if not reach[p]:
            continue
        depth, F, S = loads[p, 0], loads[p, 1], loads[p, 2]
        deepest = 0.0
        for i in vertices:
            depth[i] = -plane_gap(arms[i], center, planes, p)
            F[i] = 0.0
            S[i] = 0.0
            deepest = max(deepest, depth[i])
        if not deepest > 0.0:
            continue
        for t in face_list:  # c_T |T| = max(β |a_T|, −(R a_T)·n)
            if not (depth[faces[t, 0]] > 0.0 or depth[faces[t, 1]] > 0.0
                    or depth[faces[t, 2]] > 0.0):
                shares[t] = 0.0  # nothing of it penetrates: face_loads passes it by
                continue
            value = 0.0
            for a in range(3):
                value -= (rotation[a, 0] * face_areas[t, 0] + rotation[a, 1] * face_areas[t, 1]
                          + rotation[a, 2] * face_areas[t, 2]) * planes[p, 3 + a]
            least = FACING_FLOOR * np.sqrt(face_areas[t, 0] ** 2 + face_areas[t, 1] ** 2
                                           + face_areas[t, 2] ** 2)
            shares[t] = value if value > least else least
        energy += face_loads(faces, face_list, depth, shares, planes[p, 6], F, S, blocks,
                             work)
    return energy


@njit
def deform_kernel(vertices, body_points, basis, q, deformed):
    """``deformed[i] = X̄_i + U_i q`` (body frame, m) for the ``vertices`` listed
    (``body_points`` (s, 3), ``basis`` (s, 3, r)): the same sums whichever vertices are
    listed, so a near set's vertices sit where a pass over every vertex puts them."""
    r = q.shape[0]
    for i in vertices:
        for a in range(3):
            value = 0.0
            for j in range(r):
                value += basis[i, a, j] * q[j]
            deformed[i, a] = body_points[i, a] + value


@njit
def near_lists(faces, loads, reach, margin, marks, vertices, face_list):
    """The near set of an evaluation of every vertex (``loads`` as :func:`face_kernel`
    left it): the faces with a corner less than ``margin`` (m) from a reached plane into
    ``face_list``, their corners into ``vertices`` (both rising); ``marks`` (s,) int8
    work. Returns (vertices, faces) counts."""
    marks[:] = 0
    for p in range(reach.shape[0]):
        if reach[p]:
            for i in range(marks.shape[0]):
                if loads[p, 0, i] > -margin:
                    marks[i] = 1
    count = 0
    for t in range(faces.shape[0]):
        if marks[faces[t, 0]] == 1 or marks[faces[t, 1]] == 1 or marks[faces[t, 2]] == 1:
            face_list[count] = t
            count += 1
    for u in range(count):
        for c in range(3):
            marks[faces[face_list[u], c]] = max(marks[faces[face_list[u], c]], 2)
    listed = 0
    for i in range(marks.shape[0]):
        if marks[i]:
            vertices[listed] = i
            listed += 1
    return listed, count


@njit
def near_holds(center, rotation, q, reference, radius0, u_max, margin, reach, reach_then):
    """Whether a near set made at ``reference`` = [c (3), R (9, row-major), q (r)] still
    holds at (c, R, q): no plane reached now that was not then, and every surface point
    moved by less than ``margin`` (m): ``|Δc| + ‖ΔR‖_F (ρ₀ + u_max |q|) + u_max |Δq|``
    (``radius0`` ρ₀ the largest |X̄_i|, ``u_max`` the largest ‖U_i‖₂) bounds it."""
    for p in range(reach.shape[0]):
        if reach[p] and not reach_then[p]:
            return False
    dc = dR = dq = size = 0.0
    for a in range(3):
        dc += (center[a] - reference[a]) ** 2
        for b in range(3):
            dR += (rotation[a, b] - reference[3 + 3 * a + b]) ** 2
    for j in range(q.shape[0]):
        dq += (q[j] - reference[12 + j]) ** 2
        size += q[j] * q[j]
    moved = (np.sqrt(dc) + np.sqrt(dR) * (radius0 + u_max * np.sqrt(size))
             + u_max * np.sqrt(dq))
    return moved < margin
