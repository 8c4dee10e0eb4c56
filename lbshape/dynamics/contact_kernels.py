"""The compiled passes of :class:`~lbshape.dynamics.contact.PlaneContact` over the surface
vertices, and the buffers they write: the bounding-sphere test (:func:`reach_kernel`),
the normal pass (:func:`contact_kernel`) and the friction pass (:func:`friction_kernel`);
the law and its symbols are in :mod:`lbshape.dynamics.contact`'s docstring.

The deformation's r × r tangents are sums over the loaded vertices of products of
r-vectors; the passes gather those vectors as rows and add them up as BLAS products
(vertex by vertex they took 37 of a contact evaluation's 52 µs on a bar resting on 127
vertices).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from lbshape._jit import njit, py_func
from lbshape.dynamics.kernels import check_size, take


@njit
def reach_kernel(center, q, radius0, u_max, points, normals, reach):
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


class ContactOutput(NamedTuple):
    """The outputs of an evaluation
    (:meth:`~lbshape.dynamics.contact.PlaneContact.evaluate_into`): views of the
    buffer ``data`` (:func:`contact_output`), as :mod:`lbshape.dynamics.kernels` describes."""

    #: the buffer every field below views
    data: np.ndarray
    #: (3,) total force (N, world)
    force: np.ndarray
    #: (3,) torque about the centre of mass (N·m, world)
    torque: np.ndarray
    #: (r,) generalized force on q
    generalized: np.ndarray
    #: (r, r) its stiffness (``−∂/∂q``)
    Kq: np.ndarray
    #: (6, 6) the stiffness of (force, torque) w.r.t. the rigid motion
    K6: np.ndarray
    #: (6, 6) the friction's rate matrix C₆
    C6: np.ndarray
    #: (6, r) the friction's coupling of the rigid velocity and q̇
    X: np.ndarray
    #: (3,) [energy (J), active vertices, largest penetration (m)]
    scalars: np.ndarray

    @staticmethod
    def size(r: int) -> int:
        """Floats in the buffer of a basis of r columns."""
        return 3 + 3 + r + r * r + 36 + 36 + 6 * r + 3

    @classmethod
    def allocate(cls, r: int) -> ContactOutput:
        """Zero arrays."""
        return py_func(contact_output)(np.zeros(cls.size(r)), r)


class ContactWork(NamedTuple):
    """The kernels' work arrays: views of the buffer ``data`` (:func:`contact_work`)."""

    #: the buffer every field below views
    data: np.ndarray
    #: (r,) ``g = U_iᵀ Rᵀ n``
    g: np.ndarray
    #: (12,) the normal pass's small work: J (6), arm (3), Rᵀ n (3)
    small: np.ndarray
    #: (39,) the friction's small work: e₁, arm, w, t (3 each), C (9), f, e₂, U_i q̇
    #: (3 each), then Rᵀ e₁, Rᵀ e₂, Rᵀ n (3 × 3)
    friction_small: np.ndarray
    #: (r, r) the friction tangent's products: Σ Gᵀ C G, then Σ (Gᵀ T) gᵀ
    Kf: np.ndarray

    @staticmethod
    def size(r: int) -> int:
        """Floats in the buffer of a basis of r columns."""
        return r + 12 + 39 + r * r

    @classmethod
    def allocate(cls, r: int) -> ContactWork:
        """Zero arrays."""
        return py_func(contact_work)(np.zeros(cls.size(r)), r)


@njit
def contact_output(data, r):
    """The :class:`ContactOutput` views of a buffer of :meth:`ContactOutput.size` floats."""
    force, at = take(data, 0, 3)
    torque, at = take(data, at, 3)
    generalized, at = take(data, at, r)
    Kq, at = take(data, at, r * r)
    K6, at = take(data, at, 36)
    C6, at = take(data, at, 36)
    X, at = take(data, at, 6 * r)
    scalars, at = take(data, at, 3)
    check_size(data, at)
    return ContactOutput(data, force, torque, generalized, Kq.reshape((r, r)),
                         K6.reshape((6, 6)), C6.reshape((6, 6)), X.reshape((6, r)), scalars)


@njit
def contact_work(data, r):
    """The :class:`ContactWork` views of a buffer of :meth:`ContactWork.size` floats."""
    g, at = take(data, 0, r)
    small, at = take(data, at, 12)
    friction_small, at = take(data, at, 39)
    Kf, at = take(data, at, r * r)
    check_size(data, at)
    return ContactWork(data, g, small, friction_small, Kf.reshape((r, r)))


@njit
def pack_motion(velocity, omega, qd, rate, motion):
    """``motion = [v (3), ω (3), rate, q̇ (r)]``: what the friction kernel reads."""
    for a in range(3):
        motion[a] = velocity[a]
        motion[3 + a] = omega[a]
    motion[6] = rate
    for j in range(qd.shape[0]):
        motion[7 + j] = qd[j]


@njit
def contact_kernel(arms, basis, loads, rotation, planes, reach, rigid, work, out, rows):
    """One pass over the surface vertices (see
    :meth:`~lbshape.dynamics.contact.PlaneContact.evaluate_into`), after
    :func:`~lbshape.dynamics.contact_faces.face_kernel` (its arms and loads; ``out``'s
    energy already set).

    Vertex i with a stiffness S > 0 on a reached plane (normal force F, arm a): adds
    ``F n`` to the force, ``F (a × n)`` to the torque, ``F g`` with ``g = U_iᵀ Rᵀ n`` to the
    generalized force, ``S g gᵀ`` to ``stiffness_q`` (the rows √S g gathered in ``rows``
    (≥ pairs, r), their product at the end) and ``S J Jᵀ`` (J = [n; a × n]) to the 6 × 6
    stiffness. ``planes`` (P, 8): point, unit normal, k (per area), μ; ``work`` and
    ``out`` the buffers of :class:`ContactWork` and :class:`ContactOutput`.
    Returns the number of loaded (vertex, plane) pairs.
    """
    r = basis.shape[2]
    views, result = contact_work(work, r), contact_output(out, r)
    force, torque, generalized = result.force, result.torque, result.generalized
    Kq, K6, scalars, g = result.Kq, result.K6, result.scalars, views.g
    force[:] = 0.0
    torque[:] = 0.0
    generalized[:] = 0.0
    Kq[:, :] = 0.0
    K6[:, :] = 0.0
    depth = 0.0
    active = 0
    J, nb = views.small[0:6], views.small[9:12]
    if not reach.any():
        scalars[0] = scalars[1] = scalars[2] = 0.0
        return 0
    for p in range(planes.shape[0]):
        if not reach[p]:
            continue
        for a in range(3):
            nb[a] = (rotation[0, a] * planes[p, 3] + rotation[1, a] * planes[p, 4]
                     + rotation[2, a] * planes[p, 5])  # Rᵀ n
        n0, n1, n2 = planes[p, 3], planes[p, 4], planes[p, 5]
        for i in range(arms.shape[0]):
            k = loads[p, 2, i]
            if not k > 0.0:
                continue
            fn = loads[p, 1, i]
            arm = arms[i]
            active += 1
            depth = max(depth, loads[p, 0, i])
            for a in range(3):
                force[a] += fn * planes[p, 3 + a]
            root = np.sqrt(k)
            for j in range(r):
                g[j] = basis[i, 0, j] * nb[0] + basis[i, 1, j] * nb[1] + basis[i, 2, j] * nb[2]
                generalized[j] += fn * g[j]
                rows[active - 1, j] = root * g[j]
            if rigid:
                J[0], J[1], J[2] = n0, n1, n2
                J[3] = arm[1] * n2 - arm[2] * n1
                J[4] = arm[2] * n0 - arm[0] * n2
                J[5] = arm[0] * n1 - arm[1] * n0
                for a in range(3):
                    torque[a] += fn * J[3 + a]
                for a in range(6):
                    for b in range(a + 1):
                        K6[a, b] += k * J[a] * J[b]
    if active:
        np.dot(rows[:active].T, rows[:active], Kq)
        for j in range(r):  # exactly symmetric
            for k2 in range(j):
                Kq[k2, j] = Kq[j, k2]
    for a in range(6):
        for b in range(a):
            K6[b, a] = K6[a, b]
    scalars[1] = active
    scalars[2] = depth
    return active


@njit
def friction_kernel(rotation, motion, arms, basis, loads, planes, eps, reach, rigid, work,
                    out, gathered):
    """The friction of the loaded vertices (:mod:`lbshape.dynamics.contact`), added to
    ``force``, ``torque``, ``generalized`` and ``Kq`` of ``out``; its ``C6`` (6, 6)
    receives ``C₆`` and its ``X`` (6, r) the coupling.

    Vertex i (arm a, row i of ``arms``, :func:`~lbshape.dynamics.contact_faces.face_kernel`),
    world velocity ``w = v + ω × a + R U_i q̇`` (``motion`` = [v, ω, rate, q̇],
    :func:`pack_motion`), pressed onto a reached plane p with μ > 0 on which it has a
    stiffness is a pair; the pairs are listed first, then :func:`_pairs_friction` takes
    them in one pass. ``work`` and ``out`` are the buffers of :class:`ContactWork` and
    :class:`ContactOutput`; ``gathered`` = (rows (4 pairs, r), columns (2 pairs, 6),
    pairs (pairs, 5)): ``rows`` gathers each pair's rows of ``Σ Gᵀ C G`` and
    ``Σ (Gᵀ T)(Gᵀ n)ᵀ``, ``columns`` the matching columns of X (each sum is one BLAS
    product), ``pairs`` the list [i, p, w].
    """
    r = basis.shape[2]
    views, result = contact_work(work, r), contact_output(out, r)
    result.C6[:, :] = 0.0
    result.X[:, :] = 0.0
    rows, columns, listed = gathered
    w, rate_body = views.friction_small[6:9], views.friction_small[27:30]
    pairs = 0
    for i in range(arms.shape[0]):
        touching = False
        for p in range(planes.shape[0]):
            if reach[p] and planes[p, 7] != 0.0 and loads[p, 2, i] > 0.0:
                touching = True
        if not touching:
            continue
        for a in range(3):  # U_i q̇, the vertex's deformation rate in the body frame
            value = 0.0
            for j in range(r):
                value += basis[i, a, j] * motion[7 + j]
            rate_body[a] = value
        w[0] = motion[0] + motion[4] * arms[i, 2] - motion[5] * arms[i, 1]
        w[1] = motion[1] + motion[5] * arms[i, 0] - motion[3] * arms[i, 2]
        w[2] = motion[2] + motion[3] * arms[i, 1] - motion[4] * arms[i, 0]
        for a in range(3):  # + R U_i q̇
            w[a] += (rotation[a, 0] * rate_body[0] + rotation[a, 1] * rate_body[1]
                     + rotation[a, 2] * rate_body[2])
        for p in range(planes.shape[0]):
            if reach[p] and planes[p, 7] != 0.0 and loads[p, 2, i] > 0.0:
                listed[pairs, 0], listed[pairs, 1] = i, p
                listed[pairs, 2], listed[pairs, 3], listed[pairs, 4] = w[0], w[1], w[2]
                pairs += 1
    if pairs == 0:
        return
    _pairs_friction(planes, loads, eps, rigid, rotation, basis, arms, views, result,
                    gathered, pairs)
    rate, Kq, Kf, limit = motion[6], result.Kq, views.Kf, rows.shape[0] // 4
    np.dot(rows[:2 * pairs].T, rows[:2 * pairs], Kf)  # Σ Gᵀ C G
    for j in range(r):  # rate Σ Gᵀ C G from its upper triangle
        Kq[j, j] += rate * Kf[j, j]
        for k2 in range(j + 1, r):
            value = rate * Kf[j, k2]
            Kq[k2, j] += value
            Kq[j, k2] += value
    np.dot(rows[2 * limit:2 * limit + pairs].T, rows[3 * limit:3 * limit + pairs], Kf)
    for j in range(r):  # − μ k Σ (Gᵀ T) gᵀ
        for k2 in range(r):
            Kq[j, k2] -= Kf[j, k2]
    if rigid:  # X = Σ Bᵀ C G = Σ (L e; a × L e)(L eᵀ G)
        np.dot(columns[:2 * pairs].T, rows[:2 * pairs], result.X)


@njit
def _pairs_friction(planes, loads, eps, rigid, rotation, basis, arms, views, result,
                    gathered, count):
    """The friction of the ``count`` listed pairs (vertex i on plane p, velocity w; see
    :func:`friction_kernel`) with the normal force fn (N) and the lumped stiffness kn (N/m)
    of ``loads[p, 1:3, i]``: ``t = (I − n nᵀ) w``, ``s = √(|t|² + ε²)``, ``T = t/s``,
    ``f_t = −μ fn T``, ``C = μ fn (P − T Tᵀ)/s``, added to ``result``
    (:class:`ContactOutput`).

    On the plane's directions e₁ ∥ T and e₂ = n × e₁ (T = τ e₁), C = L Lᵀ with the columns
    √(μ fn (1 − τ²)/s) e₁ and √(μ fn / s) e₂, so every r-vector the tangents need is a
    multiple of ``eᵀ G`` (G = R U_i, taken as ``U_iᵀ (Rᵀ e)``): the pair's rows ``Lᵀ G``
    into ``gathered``'s rows, then μ k Gᵀ T = μ k τ e₁ᵀ G and g = Gᵀ n, and the columns
    ``(L e; arm × L e)`` of X into its columns. One call for all pairs: a call per pair,
    with the buffers' views, cost more than its arithmetic."""
    r = basis.shape[2]
    rows, columns, listed = gathered
    limit = rows.shape[0] // 4
    small = views.friction_small
    t, f, e1, e2 = small[9:12], small[21:24], small[0:3], small[24:27]
    C = small[12:21].reshape((3, 3))
    projections = small[30:39].reshape((3, 3))  # Rᵀ e₁, Rᵀ e₂, Rᵀ n
    force, torque, generalized = result.force, result.torque, result.generalized
    for pair in range(count):
        i, p = int(listed[pair, 0]), int(listed[pair, 1])
        fn, kn, mu = loads[p, 1, i], loads[p, 2, i], planes[p, 7]
        n = planes[p, 3:6]
        wn = listed[pair, 2] * n[0] + listed[pair, 3] * n[1] + listed[pair, 4] * n[2]
        for a in range(3):
            t[a] = listed[pair, 2 + a] - wn * n[a]
        s = np.sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2] + eps * eps)
        scale = mu * fn / s
        for a in range(3):
            t[a] /= s  # T
            f[a] = -scale * s * t[a]
            force[a] += f[a]
        for a in range(3):  # C = μ k d / s (P − T Tᵀ)
            for b in range(3):
                C[a, b] = scale * ((1.0 if a == b else 0.0) - n[a] * n[b] - t[a] * t[b])
        _plane_directions(n, t, e1, e2)
        tau = np.sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2])
        size = max(scale, 0.0)  # μ fn / s; fn ≥ 0 but for round-off
        root1, root2 = np.sqrt(size * max(1.0 - tau * tau, 0.0)), np.sqrt(size)
        R = rotation
        for a in range(3):
            projections[0, a] = R[0, a] * e1[0] + R[1, a] * e1[1] + R[2, a] * e1[2]
            projections[1, a] = R[0, a] * e2[0] + R[1, a] * e2[1] + R[2, a] * e2[2]
            projections[2, a] = R[0, a] * n[0] + R[1, a] * n[1] + R[2, a] * n[2]
        along, tangent = -mu * fn * tau, mu * kn * tau  # f = along e₁; μ k Gᵀ T / e₁ᵀ G
        for j in range(r):
            b0, b1, b2 = basis[i, 0, j], basis[i, 1, j], basis[i, 2, j]
            g1 = b0 * projections[0, 0] + b1 * projections[0, 1] + b2 * projections[0, 2]
            g2 = b0 * projections[1, 0] + b1 * projections[1, 1] + b2 * projections[1, 2]
            generalized[j] += along * g1
            rows[2 * pair, j], rows[2 * pair + 1, j] = root1 * g1, root2 * g2
            rows[2 * limit + pair, j] = tangent * g1
            rows[3 * limit + pair, j] = (b0 * projections[2, 0] + b1 * projections[2, 1]
                                         + b2 * projections[2, 2])
        if rigid:
            arm = arms[i]
            torque[0] += arm[1] * f[2] - arm[2] * f[1]
            torque[1] += arm[2] * f[0] - arm[0] * f[2]
            torque[2] += arm[0] * f[1] - arm[1] * f[0]
            _add_rigid_rate(C, arm, result.C6)
            _rigid_column(arm, e1, root1, columns[2 * pair])
            _rigid_column(arm, e2, root2, columns[2 * pair + 1])


@njit
def _plane_directions(n, t, e1, e2):
    """Orthonormal e₁, e₂ (3,) of the plane of unit normal n: e₁ along t (in the plane)
    or, for t = 0, along the axis least aligned with n; e₂ = n × e₁."""
    size = np.sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2])
    if size > 0.0:
        for a in range(3):
            e1[a] = t[a] / size
    else:
        axis = 0
        for a in range(1, 3):
            if abs(n[a]) < abs(n[axis]):
                axis = a
        for a in range(3):
            e1[a] = (1.0 if a == axis else 0.0) - n[axis] * n[a]
        size = np.sqrt(e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2])
        for a in range(3):
            e1[a] /= size
    e2[0] = n[1] * e1[2] - n[2] * e1[1]
    e2[1] = n[2] * e1[0] - n[0] * e1[2]
    e2[2] = n[0] * e1[1] - n[1] * e1[0]


@njit
def _add_rigid_rate(C, arm, C6):
    """C₆ += Bᵀ C B with ``B = [I, −[arm]×]`` (3, 6): the rate matrix of (force, torque)
    about c with respect to (v, ω) of a point force with rate matrix C (3, 3).

    B's columns are e_a (a < 3) and ``e_b × arm`` (3 + b); with D = C B (3, 6) each
    column of Bᵀ D is ``(d; arm × d)`` for the column d of D."""
    a0, a1, a2 = arm[0], arm[1], arm[2]
    for col in range(6):
        if col < 3:
            d0, d1, d2 = C[0, col], C[1, col], C[2, col]
        else:  # C (e_b × arm)
            if col == 3:
                e0, e1, e2 = 0.0, -a2, a1
            elif col == 4:
                e0, e1, e2 = a2, 0.0, -a0
            else:
                e0, e1, e2 = -a1, a0, 0.0
            d0 = C[0, 0] * e0 + C[0, 1] * e1 + C[0, 2] * e2
            d1 = C[1, 0] * e0 + C[1, 1] * e1 + C[1, 2] * e2
            d2 = C[2, 0] * e0 + C[2, 1] * e1 + C[2, 2] * e2
        C6[0, col] += d0
        C6[1, col] += d1
        C6[2, col] += d2
        C6[3, col] += a1 * d2 - a2 * d1
        C6[4, col] += a2 * d0 - a0 * d2
        C6[5, col] += a0 * d1 - a1 * d0


@njit
def _rigid_column(arm, e, root, column):
    """``column`` (6,) = root (e; arm × e): a column of Bᵀ L."""
    column[0], column[1], column[2] = root * e[0], root * e[1], root * e[2]
    column[3] = root * (arm[1] * e[2] - arm[2] * e[1])
    column[4] = root * (arm[2] * e[0] - arm[0] * e[2])
    column[5] = root * (arm[0] * e[1] - arm[1] * e[0])
