"""Compiled stress and stress derivative of the s cubature elements (the real-time kernel).

The same closed forms as :mod:`lbshape.elastic.energy_densities` (StVK and the stable
Neo-Hookean of Smith, de Goes and Kim 2018), written as one loop over the elements
so that a reduced step costs one call instead of dozens of small numpy operations.
Layouts match :class:`~lbshape.elastic.reduced_forces.ReducedForceModel`'s fast path:

* input ``H9`` (9, s): displacement gradients ``H = F − I``, row ``3i + j`` = ``H_ij``
  (component-major, the layout of ``BU_k @ q``);
* output ``P9`` (9, s): first Piola-Kirchhoff stress in Pa, same layout;
* output ``A`` (s, 9, 9): ``A[e, 3i + j, 3k + l] = ∂P_ij/∂F_kl`` in Pa.

:func:`stress` fills only ``P9`` (the cubature training's passes over all elements).

Written in H (not F) like the numpy densities, so small strains keep their digits.
"""

from __future__ import annotations

import numpy as np

from lbshape._jit import njit
from lbshape.elastic.materials import Material

#: density codes of the kernels
STVK, STABLE_NEOHOOKEAN = 0, 1


def density_parameters(material: Material) -> tuple[int, np.ndarray]:
    """(code, parameters (3,)) of the kernel: StVK (μ, λ, 0), stable NH (μ', λ', α)."""
    if material.model == "stvk":
        return STVK, np.array([material.mu, material.lam, 0.0])
    return STABLE_NEOHOOKEAN, np.array([float(v) for v in material.stable_nh_parameters])


@njit
def stress_and_tangent(code, parameters, H9, P9, A):
    """Fill P9 (9, s) and A (s, 9, 9) from H9 (9, s); see the module docstring."""
    s = H9.shape[1]
    work = np.empty((6, 3, 3))
    for e in range(s):
        _element(code, parameters, H9, P9, A, e, work, True)


@njit
def stress(code, parameters, H9, P9):
    """Fill P9 (9, s) from H9 (9, s), without the stress derivative."""
    s = H9.shape[1]
    work = np.empty((6, 3, 3))
    unused = np.empty((1, 9, 9))
    for e in range(s):
        _element(code, parameters, H9, P9, unused, e, work, False)


@njit
def _element(code, parameters, H9, P9, A, e, work, tangent):
    H = work[0]
    F = work[1]
    for i in range(3):
        for j in range(3):
            H[i, j] = H9[3 * i + j, e]
            F[i, j] = H[i, j] + (1.0 if i == j else 0.0)
    if code == 0:
        _stvk(parameters[0], parameters[1], H, F, P9, A, e, work, tangent)
    else:
        _stable_nh(parameters[0], parameters[1], parameters[2], F, P9, A, e, work, tangent)


@njit
def _stvk(mu, lam, H, F, P9, A, e, work, tangent):
    # E = (H + Hᵀ + HᵀH)/2, S = 2μE + λ tr(E) I, P = F S
    E = work[2]
    for i in range(3):
        for j in range(3):
            value = H[i, j] + H[j, i]
            for m in range(3):
                value += H[m, i] * H[m, j]
            E[i, j] = 0.5 * value
    trace = E[0, 0] + E[1, 1] + E[2, 2]
    S = work[3]
    for i in range(3):
        for j in range(3):
            S[i, j] = 2.0 * mu * E[i, j] + (lam * trace if i == j else 0.0)
    B = work[4]  # F Fᵀ
    for i in range(3):
        for j in range(3):
            value = 0.0
            pij = 0.0
            for m in range(3):
                value += F[i, m] * F[j, m]
                pij += F[i, m] * S[m, j]
            B[i, j] = value
            P9[3 * i + j, e] = pij
    if not tangent:
        return
    # A_ijkl = δ_ik S_lj + μ F_il F_kj + μ B_ik δ_jl + λ F_ij F_kl
    for i in range(3):
        for j in range(3):
            row = 3 * i + j
            for k in range(3):
                for l in range(3):
                    value = mu * F[i, l] * F[k, j] + lam * F[i, j] * F[k, l]
                    if i == k:
                        value += S[l, j]
                    if j == l:
                        value += mu * B[i, k]
                    A[e, row, 3 * k + l] = value


@njit
def _stable_nh(mu, lam, alpha, F, P9, A, e, work, tangent):
    cof = work[2]
    for i in range(3):
        for j in range(3):
            i1, i2 = (i + 1) % 3, (i + 2) % 3
            j1, j2 = (j + 1) % 3, (j + 2) % 3
            cof[i, j] = F[i1, j1] * F[i2, j2] - F[i1, j2] * F[i2, j1]
    J = F[0, 0] * cof[0, 0] + F[0, 1] * cof[0, 1] + F[0, 2] * cof[0, 2]
    ic = 0.0
    for i in range(3):
        for j in range(3):
            ic += F[i, j] * F[i, j]
    inv = 1.0 / (1.0 + ic)
    c1 = mu * (1.0 - inv)
    cj = lam * (J - alpha)
    cf = 2.0 * mu * inv * inv
    for i in range(3):
        for j in range(3):
            P9[3 * i + j, e] = c1 * F[i, j] + cj * cof[i, j]
    if not tangent:
        return
    for i in range(3):
        for j in range(3):
            row = 3 * i + j
            for k in range(3):
                for l in range(3):
                    value = cf * F[i, j] * F[k, l] + lam * cof[i, j] * cof[k, l]
                    if row == 3 * k + l:
                        value += c1
                    # ∂²J/∂F_ij∂F_kl = ε_ikn ε_jlq F_nq (zero unless i != k and j != l)
                    if i != k and j != l:
                        n = 3 - i - k
                        q = 3 - j - l
                        value += cj * _eps(i, k, n) * _eps(j, l, q) * F[n, q]
                    A[e, row, 3 * k + l] = value


@njit
def _eps(a, b, c):
    """Levi-Civita symbol of distinct indices a, b, c in {0, 1, 2}."""
    return 1.0 if (b - a) % 3 == 1 else -1.0
