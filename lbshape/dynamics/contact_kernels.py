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
    #: (6, r) the friction's G = R U_i (3 rows) and C G (3)
    rows: np.ndarray
    #: (27,) the friction's small work: e₁, arm, w, t (3 each), C (9), f, e₂ (3 each)
    friction_small: np.ndarray
    #: (r, r) the friction tangent's products: Σ Gᵀ C G, then Σ (Gᵀ T) gᵀ
    Kf: np.ndarray

    @staticmethod
    def size(r: int) -> int:
        """Floats in the buffer of a basis of r columns."""
        return r + 12 + 6 * r + 27 + r * r

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
    rows, at = take(data, at, 6 * r)
    friction_small, at = take(data, at, 27)
    Kf, at = take(data, at, r * r)
    check_size(data, at)
    return ContactWork(data, g, small, rows.reshape((6, r)), friction_small,
                       Kf.reshape((r, r)))


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
                    out, rows):
    """The friction of the loaded vertices (:mod:`lbshape.dynamics.contact`), added to
    ``force``, ``torque``, ``generalized`` and ``Kq`` of ``out``; its ``C6`` (6, 6)
    receives ``C₆``.

    Vertex i (arm a, row i of ``arms``, :func:`~lbshape.dynamics.contact_faces.face_kernel`),
    world velocity ``w = v + ω × a + R U_i q̇`` (``motion`` = [v, ω, rate, q̇],
    :func:`pack_motion`); per
    reached plane with μ > 0 on which it has a stiffness, :func:`_plane_friction` with its
    normal force and stiffness (``loads``). ``work`` and ``out`` are the buffers of
    :class:`ContactWork` and :class:`ContactOutput`; ``rows`` (4 pairs, r) gathers each
    pair's rows of ``Σ Gᵀ C G`` and ``Σ (Gᵀ T)(Gᵀ n)ᵀ``, summed as BLAS products.
    """
    r = basis.shape[2]
    views, result = contact_work(work, r), contact_output(out, r)
    result.C6[:, :] = 0.0
    result.X[:, :] = 0.0
    arm, w = views.friction_small[3:6], views.friction_small[6:9]
    G = views.rows[0:3]
    pairs = 0
    for i in range(arms.shape[0]):
        touching = False
        for p in range(planes.shape[0]):
            if reach[p] and planes[p, 7] != 0.0 and loads[p, 2, i] > 0.0:
                touching = True
        if not touching:
            continue
        for a in range(3):
            arm[a] = arms[i, a]
        for a in range(3):  # G = R U_i, w = v + ω × a + G q̇
            for j in range(r):
                G[a, j] = (rotation[a, 0] * basis[i, 0, j] + rotation[a, 1] * basis[i, 1, j]
                           + rotation[a, 2] * basis[i, 2, j])
        w[0] = motion[0] + motion[4] * arm[2] - motion[5] * arm[1]
        w[1] = motion[1] + motion[5] * arm[0] - motion[3] * arm[2]
        w[2] = motion[2] + motion[3] * arm[1] - motion[4] * arm[0]
        for a in range(3):
            value = 0.0
            for j in range(r):
                value += G[a, j] * motion[7 + j]
            w[a] += value
        for p in range(planes.shape[0]):
            if reach[p] and planes[p, 7] != 0.0 and loads[p, 2, i] > 0.0:
                _plane_friction(planes, p, loads[p, 1, i], loads[p, 2, i], eps, rigid, views,
                                result, rows, pairs)
                pairs += 1
    if pairs == 0:
        return
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


@njit
def _plane_friction(planes, p, fn, kn, eps, rigid, views, result, rows, pair):
    """The friction of one vertex pressed onto plane p with the normal force fn (N) and
    the lumped stiffness kn (N/m), its arm and velocity w and its G = R U_i in ``views``
    (:class:`ContactWork`): ``t = (I − n nᵀ) w``, ``s = √(|t|² + ε²)``, ``T = t/s``,
    ``f_t = −μ fn T``, ``C = μ fn (P − T Tᵀ)/s``, added to ``result``
    (:class:`ContactOutput`); the ``pair``-th rows of the deformation tangent into
    ``rows`` (:func:`friction_kernel`): C = L Lᵀ on the plane's directions e₁ ∥ T
    (eigenvalue μ fn (1 − |T|²)/s) and e₂ = n × e₁ (μ fn / s), so that Gᵀ C G is the
    product of the rows Lᵀ G; then μ k Gᵀ T and g = Gᵀ n."""
    r = views.g.shape[0]
    G, CG = views.rows[0:3], views.rows[3:6]
    limit = rows.shape[0] // 4
    GT, GN = rows[2 * limit + pair], rows[3 * limit + pair]
    small = views.friction_small
    arm, w, t = small[3:6], small[6:9], small[9:12]
    C = small[12:21].reshape((3, 3))
    f = small[21:24]
    force, torque, generalized = result.force, result.torque, result.generalized
    n = planes[p, 3:6]
    wn = w[0] * n[0] + w[1] * n[1] + w[2] * n[2]
    for a in range(3):
        t[a] = w[a] - wn * n[a]
    s = np.sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2] + eps * eps)
    mu = planes[p, 7]
    mu_k = mu * kn
    scale = mu * fn / s
    for a in range(3):
        t[a] /= s  # T
        f[a] = -scale * s * t[a]
    for a in range(3):  # C = μ k d / s (P − T Tᵀ)
        for b in range(3):
            C[a, b] = scale * ((1.0 if a == b else 0.0) - n[a] * n[b] - t[a] * t[b])
    for a in range(3):
        force[a] += f[a]
    # deformation tangent: rate Gᵀ C G − μ k (Gᵀ T) gᵀ, g = Gᵀ n: the rows of each
    e1, e2 = small[0:3], small[24:27]
    _plane_directions(n, t, e1, e2)
    tau2 = t[0] * t[0] + t[1] * t[1] + t[2] * t[2]
    size = max(scale, 0.0)  # μ fn / s; fn ≥ 0 but for round-off
    root1, root2 = np.sqrt(size * max(1.0 - tau2, 0.0)), np.sqrt(size)
    for j in range(r):
        generalized[j] += G[0, j] * f[0] + G[1, j] * f[1] + G[2, j] * f[2]
        CG[0, j] = C[0, 0] * G[0, j] + C[0, 1] * G[1, j] + C[0, 2] * G[2, j]
        CG[1, j] = C[1, 0] * G[0, j] + C[1, 1] * G[1, j] + C[1, 2] * G[2, j]
        CG[2, j] = C[2, 0] * G[0, j] + C[2, 1] * G[1, j] + C[2, 2] * G[2, j]
        GT[j] = mu_k * (G[0, j] * t[0] + G[1, j] * t[1] + G[2, j] * t[2])
        GN[j] = G[0, j] * n[0] + G[1, j] * n[1] + G[2, j] * n[2]
    for j in range(r):
        rows[2 * pair, j] = root1 * (G[0, j] * e1[0] + G[1, j] * e1[1] + G[2, j] * e1[2])
        rows[2 * pair + 1, j] = root2 * (G[0, j] * e2[0] + G[1, j] * e2[1] + G[2, j] * e2[2])
    if rigid:
        _friction_rigid(arm, f, C, CG, torque, result.C6, result.X)


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
def _friction_rigid(arm, f, C, CG, torque, C6, X):
    """A friction force f at the arm: its torque, its rate on the rigid motion C₆ and the
    coupling X += Bᵀ C G: (C G; arm × C G) per column."""
    torque[0] += arm[1] * f[2] - arm[2] * f[1]
    torque[1] += arm[2] * f[0] - arm[0] * f[2]
    torque[2] += arm[0] * f[1] - arm[1] * f[0]
    _add_rigid_rate(C, arm, C6)
    for j in range(CG.shape[1]):
        c0, c1, c2 = CG[0, j], CG[1, j], CG[2, j]
        X[0, j] += c0
        X[1, j] += c1
        X[2, j] += c2
        X[3, j] += arm[1] * c2 - arm[2] * c1
        X[4, j] += arm[2] * c0 - arm[0] * c2
        X[5, j] += arm[0] * c1 - arm[1] * c0


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
