"""Elastic energy over all elements in a block basis ``L = Φ ⊗ I₃``, compiled.

The Euclidean example energy of the target search
(:class:`~lbshape.shapespace.euclidean_energy.EuclideanExampleEnergy`) is
``E(y) = Σ_e V_e Ψ(F_e(L y))`` with the LB block basis L (3n, 3m), ``y[3k + c]`` the
coefficient of eigenvector k in component c. The block structure gives the element
gradients in m columns instead of 3m: with ``(GΦ)_e[j, k] = Σ_a ∂_j N_a Φ[v_a, k]``
(3, m),

* ``H_e[c, j] = Σ_k y[3k + c] (GΦ)_e[j, k]`` (``H = F − I``),
* ``g[3k + c] = Σ_e V_e Σ_j P_e[c, j] (GΦ)_e[j, k]``,
* ``∇²E[3k + c, 3l + d] = Σ_e V_e Σ_{j,q} (GΦ)_e[j, k] A_e[3c + j, 3d + q] (GΦ)_e[q, l]``,

the last one a single ``m × 3s × 6m`` matrix product (the six blocks c ≤ d; the others
by symmetry), a third of the work of the general ``(3m) × 9s × (3m)`` product of
:class:`~lbshape.elastic.reduced_forces.ReducedForceModel`. The stress and its
derivative are the compiled ones (:mod:`lbshape.elastic.jit_densities`), the energy the
numpy density's in :meth:`BlockBasisEnergy.energy`, compiled alongside in
:meth:`BlockBasisEnergy.energy_force_and_tangent`. Same quantities as the general model
to round-off. The last evaluation is kept: the target search of a time step starts where
the previous one ended (other weights, the same coordinates), and gets it for free.
"""

from __future__ import annotations

import numpy as np

from lbshape._jit import njit
from lbshape.elastic.element_kernels import ElementKernel
from lbshape.elastic.energy_densities import density_model
from lbshape.elastic.jit_densities import _element, density_parameters
from lbshape.elastic.materials import Material
from lbshape.errors import LbshapeError

#: the component pairs (c, d), c ≤ d, of the Hessian's computed blocks
_PAIRS = np.array([(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)], dtype=np.int64)


def block_basis_factor(basis: np.ndarray, atol: float = 0.0) -> np.ndarray | None:
    """Φ (n, m) when ``basis`` (3n, 3m) is exactly ``Φ ⊗ I₃`` (node-major rows ``3j + c``,
    columns ``3k + c``), else None."""
    basis = np.asarray(basis)
    if basis.ndim != 2 or basis.shape[0] % 3 or basis.shape[1] % 3:
        return None
    n, m = basis.shape[0] // 3, basis.shape[1] // 3
    blocks = basis.reshape(n, 3, m, 3)
    phi = blocks[:, 0, :, 0]
    expected = phi[:, None, :, None] * np.eye(3)[None, :, None, :]
    exact = np.array_equal(blocks, expected) if atol == 0.0 else bool(
        np.abs(blocks - expected).max() <= atol)
    if not exact:
        return None
    return np.ascontiguousarray(phi)


class BlockBasisEnergy:
    """Energy, gradient and Hessian of ``E(y) = Σ_e V_e Ψ(F_e(L y))``, ``L = Φ ⊗ I₃``.

    Args:
        rest_points: (n, 3) rest shape in metres.
        tets: (t, 4) the elements summed over.
        material: the hyperelastic material.
        phi: (n, m) the block basis' factor Φ.
    """

    def __init__(self, rest_points: np.ndarray, tets: np.ndarray, material: Material,
                 phi: np.ndarray):
        phi = np.asarray(phi, dtype=np.float64)
        tets = np.asarray(tets)
        if phi.ndim != 2 or phi.shape[0] != np.shape(rest_points)[0]:
            raise LbshapeError(f"Φ must have shape (n, m), got {phi.shape}")
        kernel = ElementKernel(rest_points, tets, material)
        s, m = kernel.n_elements, phi.shape[1]
        # (GΦ)_e[j, k] = Σ_a G[e, a, j] Φ[v_a, k]
        self._gphi = np.ascontiguousarray(np.einsum("eaj,eak->ejk", kernel.gradients,
                                                    phi[tets]))
        self._x = self._gphi.reshape(3 * s, m)
        self._volumes = np.ascontiguousarray(kernel.volumes)
        self._code, self._parameters = density_parameters(material)
        self._density = density_model(material)
        self.n_elements, self.m = s, m
        self.n_coordinates = 3 * m
        self._h = np.empty((9, s))
        self._pv = np.empty((3 * s, 3))
        self._last = None  # (y, E, g, H) of the last evaluation
        self._z = np.empty((3 * s, 6 * m))

    def _gradients(self, y: np.ndarray) -> np.ndarray:
        y = np.asarray(y, dtype=np.float64)
        if y.shape != (self.n_coordinates,):
            raise LbshapeError(f"coordinates must have shape ({self.n_coordinates},), "
                               f"got {y.shape}")
        # H[(e, j), c] = Σ_k (GΦ)[(e, j), k] Y[k, c]
        Hej = self._x @ y.reshape(self.m, 3)  # (3s, 3)
        self._h[...] = Hej.reshape(self.n_elements, 3, 3).transpose(2, 1, 0).reshape(9, -1)
        return self._h

    def energy(self, y: np.ndarray) -> float:
        """E(y) in J."""
        H = self._gradients(y)
        return float(self._volumes @ self._density.energy_t(H.reshape(3, 3, -1)))

    def force_and_tangent(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(∇E (3m,), ∇²E (3m, 3m))."""
        return self.energy_force_and_tangent(y)[1:]

    def energy_force_and_tangent(self, y: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        """(E J, ∇E (3m,), ∇²E (3m, 3m) symmetric) at y (3m,), sharing the element work."""
        y = np.asarray(y, dtype=np.float64)
        if y.shape != (self.n_coordinates,):
            raise LbshapeError(f"coordinates must have shape ({self.n_coordinates},), "
                               f"got {y.shape}")
        last = self._last
        if last is not None and np.array_equal(last[0], y):
            # the target search starts where the last one ended (other weights, same y)
            return last[1], last[2].copy(), last[3].copy()
        energy = _fused(self._code, self._parameters, self._gphi, self._volumes,
                        np.ascontiguousarray(y.reshape(self.m, 3)), self._pv, self._z)
        m = self.m
        g = (self._x.T @ self._pv).reshape(-1)  # (m, 3) -> 3k + c
        blocks = self._x.T @ self._z  # (m, 6m)
        K = np.empty((m, 3, m, 3))
        for p, (c, d) in enumerate(_PAIRS):
            block = blocks[:, p * m:(p + 1) * m]
            K[:, c, :, d] = block
            if c != d:
                K[:, d, :, c] = block.T
        K = K.reshape(3 * m, 3 * m)
        self._last = (y.copy(), energy, g.copy(), K.copy())
        return energy, g, K

    def energy_and_force(self, y: np.ndarray) -> tuple[float, np.ndarray]:
        """(E J, ∇E (3m,)) at y (3m,): one pass without the stress derivative (a modified
        Newton's iterate, :class:`~lbshape.shapespace.reused_hessian.ReusedHessianTargetSolver`)."""
        y = np.asarray(y, dtype=np.float64)
        if y.shape != (self.n_coordinates,):
            raise LbshapeError(f"coordinates must have shape ({self.n_coordinates},), "
                               f"got {y.shape}")
        last = self._last
        if last is not None and np.array_equal(last[0], y):
            return last[1], last[2].copy()
        Y = np.ascontiguousarray(y.reshape(self.m, 3))
        if self._code == 0:  # StVK: the stress and energy in registers
            energy = _stvk_gradient(self._parameters[0], self._parameters[1], self._gphi,
                                    self._volumes, Y, self._pv)
        else:
            energy = _fused_gradient(self._code, self._parameters, self._gphi,
                                     self._volumes, Y, self._pv)
        return energy, (self._x.T @ self._pv).reshape(-1)


@njit
def _displacement_gradient(YT, gphi, e, m, H9):
    """Element e's displacement gradient ``H = F − I`` into the column ``H9`` (9, 1),
    row-major: ``H[c, j] = Σ_k Y[k, c] ∂_j φ_k`` from the block coefficients ``YT`` (3, m)
    and the LB functions' gradients ``gphi`` (s, 3, m) (1/m)."""
    g0 = gphi[e, 0]
    g1 = gphi[e, 1]
    g2 = gphi[e, 2]
    for c in range(3):
        yc = YT[c]
        h0 = 0.0
        h1 = 0.0
        h2 = 0.0
        for k in range(m):
            h0 += yc[k] * g0[k]
            h1 += yc[k] * g1[k]
            h2 += yc[k] * g2[k]
        H9[3 * c, 0] = h0
        H9[3 * c + 1, 0] = h1
        H9[3 * c + 2, 0] = h2


@njit
def _fused(code, parameters, gphi, volumes, Y, pv, z):
    """One pass over the elements: returns the energy (J) and fills
    ``pv[(e, j), c] = V P[c, j]`` and ``z[(e, j), p m + l] = V Σ_q A[3c + j, 3d + q] GΦ[q, l]``
    (p the index of the pair c ≤ d)."""
    s, _, m = gphi.shape
    H9 = np.empty((9, 1))
    P9 = np.empty((9, 1))
    A = np.empty((1, 9, 9))
    work = np.empty((6, 3, 3))
    YT = np.ascontiguousarray(Y.T)  # (3, m)
    energy = 0.0
    for e in range(s):
        V = volumes[e]
        _displacement_gradient(YT, gphi, e, m, H9)
        g0, g1, g2 = gphi[e, 0], gphi[e, 1], gphi[e, 2]
        _element(code, parameters, H9, P9, A, 0, work, True)
        energy += V * _energy(code, parameters, H9)
        for j in range(3):
            row = 3 * e + j
            for c in range(3):
                pv[row, c] = V * P9[3 * c + j, 0]
            p = 0
            for c in range(3):
                for d in range(c, 3):  # the order of _PAIRS
                    a0 = V * A[0, 3 * c + j, 3 * d]
                    a1 = V * A[0, 3 * c + j, 3 * d + 1]
                    a2 = V * A[0, 3 * c + j, 3 * d + 2]
                    zr = z[row, p * m:(p + 1) * m]
                    for l in range(m):
                        zr[l] = a0 * g0[l] + a1 * g1[l] + a2 * g2[l]
                    p += 1
    return energy


@njit
def _fused_gradient(code, parameters, gphi, volumes, Y, pv):
    """:func:`_fused` without the stress derivative: the energy (J) and ``pv``."""
    s, _, m = gphi.shape
    H9 = np.empty((9, 1))
    P9 = np.empty((9, 1))
    unused = np.empty((1, 9, 9))
    work = np.empty((6, 3, 3))
    YT = np.ascontiguousarray(Y.T)  # (3, m)
    energy = 0.0
    for e in range(s):
        _displacement_gradient(YT, gphi, e, m, H9)
        _element(code, parameters, H9, P9, unused, 0, work, False)
        V = volumes[e]
        energy += V * _energy(code, parameters, H9)
        for j in range(3):
            for c in range(3):
                pv[3 * e + j, c] = V * P9[3 * c + j, 0]
    return energy


@njit
def stvk_stress(h, mu, lam):
    """StVK at the displacement gradient ``h`` (the 9-tuple H[i, j], row-major):
    ``(P as a 9-tuple row-major, Ψ)`` with ``E = (H + Hᵀ + HᵀH)/2``, ``S = 2μE + λ tr(E) I``,
    ``P = F S``, ``Ψ = μ E:E + λ/2 (tr E)²`` (J/m³) — the operations of
    :func:`~lbshape.elastic.jit_densities._stvk` and :func:`_energy` in their order (equal
    bit for bit), in scalars."""
    h00, h01, h02, h10, h11, h12, h20, h21, h22 = h
    e00 = 0.5 * (h00 + h00 + h00 * h00 + h10 * h10 + h20 * h20)
    e11 = 0.5 * (h11 + h11 + h01 * h01 + h11 * h11 + h21 * h21)
    e22 = 0.5 * (h22 + h22 + h02 * h02 + h12 * h12 + h22 * h22)
    e01 = 0.5 * (h01 + h10 + h00 * h01 + h10 * h11 + h20 * h21)
    e02 = 0.5 * (h02 + h20 + h00 * h02 + h10 * h12 + h20 * h22)
    e12 = 0.5 * (h12 + h21 + h01 * h02 + h11 * h12 + h21 * h22)
    trace = e00 + e11 + e22
    ee = (e00 * e00 + e01 * e01 + e02 * e02 + e01 * e01 + e11 * e11 + e12 * e12
          + e02 * e02 + e12 * e12 + e22 * e22)
    psi = mu * ee + 0.5 * lam * trace * trace
    two_mu = 2.0 * mu
    s00, s11, s22 = two_mu * e00 + lam * trace, two_mu * e11 + lam * trace, \
        two_mu * e22 + lam * trace
    s01, s02, s12 = two_mu * e01, two_mu * e02, two_mu * e12
    f00, f11, f22 = 1.0 + h00, 1.0 + h11, 1.0 + h22
    return ((f00 * s00 + h01 * s01 + h02 * s02, f00 * s01 + h01 * s11 + h02 * s12,
             f00 * s02 + h01 * s12 + h02 * s22,
             h10 * s00 + f11 * s01 + h12 * s02, h10 * s01 + f11 * s11 + h12 * s12,
             h10 * s02 + f11 * s12 + h12 * s22,
             h20 * s00 + h21 * s01 + f22 * s02, h20 * s01 + h21 * s11 + f22 * s12,
             h20 * s02 + h21 * s12 + f22 * s22), psi)


@njit
def _stvk_gradient(mu, lam, gphi, volumes, Y, pv):
    """:func:`_fused_gradient` for StVK (:func:`stvk_stress`, in scalars): the energy (J)
    and ``pv[(e, j), c] = V P[c, j]``."""
    s, _, m = gphi.shape
    YT = np.ascontiguousarray(Y.T)  # (3, m)
    y0, y1, y2 = YT[0], YT[1], YT[2]
    energy = 0.0
    for e in range(s):
        g0, g1, g2 = gphi[e, 0], gphi[e, 1], gphi[e, 2]
        h00 = h01 = h02 = h10 = h11 = h12 = h20 = h21 = h22 = 0.0
        for k in range(m):
            a, b, c = g0[k], g1[k], g2[k]
            h00 += y0[k] * a
            h01 += y0[k] * b
            h02 += y0[k] * c
            h10 += y1[k] * a
            h11 += y1[k] * b
            h12 += y1[k] * c
            h20 += y2[k] * a
            h21 += y2[k] * b
            h22 += y2[k] * c
        P, psi = stvk_stress((h00, h01, h02, h10, h11, h12, h20, h21, h22), mu, lam)
        V = volumes[e]
        energy += V * psi
        row = 3 * e
        pv[row, 0], pv[row, 1], pv[row, 2] = V * P[0], V * P[3], V * P[6]
        pv[row + 1, 0], pv[row + 1, 1], pv[row + 1, 2] = V * P[1], V * P[4], V * P[7]
        pv[row + 2, 0], pv[row + 2, 1], pv[row + 2, 2] = V * P[2], V * P[5], V * P[8]
    return energy


@njit
def _energy(code, parameters, H9):
    """Ψ(I + H) − Ψ(I) (J/m³) of H9 (9, 1), in H like the numpy densities' ``energy_t``."""
    if code == 0:  # StVK: μ E:E + λ/2 (tr E)², E = (H + Hᵀ + HᵀH)/2
        mu, lam = parameters[0], parameters[1]
        ee = 0.0
        trace = 0.0
        for i in range(3):
            for j in range(3):
                value = H9[3 * i + j, 0] + H9[3 * j + i, 0]
                for k in range(3):
                    value += H9[3 * k + i, 0] * H9[3 * k + j, 0]
                value *= 0.5
                ee += value * value
                if i == j:
                    trace += value
        return mu * ee + 0.5 * lam * trace * trace
    # stable Neo-Hookean: μ'/2 (δ − ln(1 + δ/4)) + λ'/2 (J − 1)(J − 1 + 2(1 − α)),
    # δ = I_C − 3 = 2 tr H + H:H, J − 1 = tr H + I₂(H) + det H
    mu, lam, alpha = parameters[0], parameters[1], parameters[2]
    c00 = H9[4, 0] * H9[8, 0] - H9[5, 0] * H9[7, 0]
    c01 = H9[5, 0] * H9[6, 0] - H9[3, 0] * H9[8, 0]
    c02 = H9[3, 0] * H9[7, 0] - H9[4, 0] * H9[6, 0]
    c11 = H9[8, 0] * H9[0, 0] - H9[6, 0] * H9[2, 0]
    c22 = H9[0, 0] * H9[4, 0] - H9[1, 0] * H9[3, 0]
    trace = H9[0, 0] + H9[4, 0] + H9[8, 0]
    dj = trace + c00 + c11 + c22 + (H9[0, 0] * c00 + H9[1, 0] * c01 + H9[2, 0] * c02)
    hh = 0.0
    for i in range(9):
        hh += H9[i, 0] * H9[i, 0]
    delta = 2.0 * trace + hh
    return 0.5 * mu * (delta - np.log1p(0.25 * delta)) + 0.5 * lam * dj * (
        dj + 2.0 * (1.0 - alpha))
