"""The M-orthonormal rigid motions of a deformed shape, Ψ (3n, 6), and M Ψ: the full-space
reference's free body projects its co-rotated damping on them
(:mod:`lbshape.dynamics.full_damping`) and takes its fitted example pull's tangent from
them (:mod:`lbshape.dynamics.full_examples`), at every Newton evaluation."""

from __future__ import annotations

import numpy as np
import scipy.linalg
import scipy.sparse as sp

from lbshape._jit import njit
from lbshape.dynamics.kernels import cholesky_in_place
from lbshape.errors import SolverError


def rigid_modes(points: np.ndarray, mass: sp.spmatrix,
                 scalar_mass: sp.spmatrix | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(Ψ, M Ψ)``: :func:`~lbshape.elastic.modes.rigid_body_modes` of ``points`` and its
    product with the mass, from one sparse product (``M Ψ = (M F) L⁻ᵀ`` with the fields F
    and the Cholesky factor L of their Gram matrix). With ``scalar_mass`` M₁ (n, n), M =
    M₁ ⊗ I₃ on every dof: ``M F`` from ``M₁ [1 r]`` (the fields are 1 and e_c × r), in one
    compiled pass (:func:`_scalar_rigid_modes`)."""
    n = points.shape[0]
    if scalar_mass is not None and mass.shape[0] == 3 * n:
        M1 = scalar_mass if sp.isspmatrix_csr(scalar_mass) else sp.csr_matrix(scalar_mass)
        psi, mass_psi = np.empty((3 * n, 6)), np.empty((3 * n, 6))
        if not _scalar_rigid_modes(np.ascontiguousarray(points, dtype=float), M1.indptr,
                                   M1.indices, M1.data, psi, mass_psi):
            raise SolverError("the rigid motions' Gram matrix is not positive definite "
                              "(a degenerate or non-finite shape)")
        return psi, mass_psi
    r = points - points.mean(axis=0)
    F = _fields(np.ones(n), r)
    MF = np.asarray(mass @ F)
    gram = F.T @ MF
    lower = np.linalg.cholesky(0.5 * (gram + gram.T))
    inverse = scipy.linalg.solve_triangular(lower, np.eye(6), lower=True)  # L⁻¹ (6 × 6)
    return F @ inverse.T, MF @ inverse.T


@njit
def _field_row(one, rx, ry, rz, c, out):
    """Row c (0, 1, 2) of a vertex's (3, 6) fields ``[one e_c, e_c × r]`` into out (6,)."""
    for k in range(6):
        out[k] = 0.0
    out[c] = one
    if c == 0:
        out[4], out[5] = rz, -ry
    elif c == 1:
        out[3], out[5] = -rz, rx
    else:
        out[3], out[4] = ry, -rx


@njit
def _scalar_rigid_modes(points, indptr, indices, data, psi, mass_psi):
    """:func:`rigid_modes` with the scalar mass M₁ (CSR arrays): Ψ and M Ψ (3n, 6) into
    ``psi`` and ``mass_psi``; False when the Gram matrix is not positive definite."""
    n = points.shape[0]
    mean = np.zeros(3)
    for i in range(n):
        for a in range(3):
            mean[a] += points[i, a]
    for a in range(3):
        mean[a] /= n
    scaled = np.zeros((n, 4))  # M₁ [1 r]
    for i in range(n):
        for k in range(indptr[i], indptr[i + 1]):
            j, w = indices[k], data[k]
            scaled[i, 0] += w
            for a in range(3):
                scaled[i, 1 + a] += w * (points[j, a] - mean[a])
    # the Gram matrix Fᵀ M F from moments: with s = M₁ 1, q = M₁ r, Q = Σ q and
    # C_xy = Σ r_x q_y: [[Σs I, G], [Gᵀ, tr(C) I − Cᵀ]], G_ab = (e_b × Q)_a
    # ((e_a × r)·(e_b × q) = δ_ab r·q − r_b q_a)
    total = 0.0
    Q = np.zeros(3)
    C = np.zeros((3, 3))
    for i in range(n):
        total += scaled[i, 0]
        for x in range(3):
            Q[x] += scaled[i, 1 + x]
            for y in range(3):
                C[x, y] += (points[i, x] - mean[x]) * scaled[i, 1 + y]
    gram = np.zeros((6, 6))
    trace = C[0, 0] + C[1, 1] + C[2, 2]
    for a in range(3):
        gram[a, a] = total
        for b in range(3):
            gram[3 + a, 3 + b] = (trace if a == b else 0.0) - C[b, a]
    for b in range(3):  # translation a, rotation b: (e_b × Q)_a
        e = np.zeros(3)
        e[b] = 1.0
        cross = (e[1] * Q[2] - e[2] * Q[1], e[2] * Q[0] - e[0] * Q[2],
                 e[0] * Q[1] - e[1] * Q[0])
        for a in range(3):
            gram[a, 3 + b] = cross[a]
            gram[3 + b, a] = cross[a]
    lower = 0.5 * (gram + gram.T)
    if not cholesky_in_place(lower):
        return False
    inverse = np.zeros((6, 6))  # L⁻¹ by forward substitution
    for j in range(6):
        for i in range(j, 6):
            value = 1.0 if i == j else 0.0
            for k in range(j, i):
                value -= lower[i, k] * inverse[k, j]
            inverse[i, j] = value / lower[i, i]
    row, mrow = np.empty(6), np.empty(6)
    for i in range(n):  # the rows of F L⁻ᵀ and M F L⁻ᵀ
        rx, ry, rz = points[i, 0] - mean[0], points[i, 1] - mean[1], points[i, 2] - mean[2]
        for c in range(3):
            _field_row(1.0, rx, ry, rz, c, row)
            _field_row(scaled[i, 0], scaled[i, 1], scaled[i, 2], scaled[i, 3], c, mrow)
            for a in range(6):
                value, mvalue = 0.0, 0.0
                for b in range(a + 1):
                    value += row[b] * inverse[a, b]
                    mvalue += mrow[b] * inverse[a, b]
                psi[3 * i + c, a] = value
                mass_psi[3 * i + c, a] = mvalue
    return True


def _fields(one: np.ndarray, r: np.ndarray) -> np.ndarray:
    """(3n, 6) the translations ``one e_c`` and rotations ``e_c × r`` per vertex."""
    n = r.shape[0]
    fields = np.zeros((n, 3, 6))
    fields[:, [0, 1, 2], [0, 1, 2]] = one[:, None]
    fields[:, 1, 3], fields[:, 2, 3] = -r[:, 2], r[:, 1]  # e_c × r
    fields[:, 0, 4], fields[:, 2, 4] = r[:, 2], -r[:, 0]
    fields[:, 0, 5], fields[:, 1, 5] = -r[:, 1], r[:, 0]
    return fields.reshape(3 * n, 6)
