"""Exact reduced StVK energy as a quartic polynomial (Barbič & James 2005 style).

For a St. Venant-Kirchhoff material and a displacement ``u = B y`` (basis B
(3n, p)) of a rest shape X, each element's displacement gradient is linear in y,
``H_e = G_e y`` (G_e: (9, p)), its Green strain quadratic,
``E_ab = s_abᵀ y + ½ yᵀ Q_ab y``, and its energy density quartic. Summed over
*all* elements the energy is

    E(y) = ½ yᵀ K y + Σ_ijk C_ijk y_i y_j y_k + Σ_ijkl D_ijkl y_i y_j y_k y_l,

with K (p,p), C (p,p,p) and D (p,p,p,p) precomputed once (n-sized work). At run
time energy, gradient and Hessian cost O(p⁴), independent of the mesh: the
Euclidean-space energy of Zhu et al. evaluated exactly in the reduced space. Only
StVK has this polynomial form.

Derivation: ``Ψ = μ Σ_ab E_ab² + λ/2 (tr E)²`` is a weighted sum of squares of
terms ``t_j(y) = l_jᵀ y + ½ yᵀ A_j y``; with ``t² = (lᵀy)² + (lᵀy)(yᵀAy) +
¼(yᵀAy)²`` the coefficient tensors are sums over the terms j with weights α_j.
"""

from __future__ import annotations

import numpy as np

from lbshape.elastic.element_kernels import ElementKernel
from lbshape.elastic.materials import Material
from lbshape.errors import LbshapeError

#: terms per element gathered at once (bounds the temporary memory)
_CHUNK_TERMS = 4096


class StVKPolynomialEnergy:
    """Exact StVK energy of ``u = B y`` on a rest shape, with gradient and Hessian.

    Args:
        rest_points: (n, 3) rest shape in metres.
        tets: (t, 4) tetrahedra.
        material: an ``stvk`` material.
        basis: (3n, p) node-major basis B.
    """

    def __init__(self, rest_points: np.ndarray, tets: np.ndarray, material: Material,
                 basis: np.ndarray):
        if material.model != "stvk":
            raise LbshapeError("the polynomial reduced energy exists only for StVK materials")
        B = np.asarray(basis, dtype=float)
        n = np.asarray(rest_points).shape[0]
        if B.ndim != 2 or B.shape[0] != 3 * n:
            raise LbshapeError(f"basis must have shape (3n={3 * n}, p), got {B.shape}")
        p = B.shape[1]
        kernel = ElementKernel(rest_points, tets, material)
        rows = (3 * np.asarray(tets)[:, :, None] + np.arange(3)).reshape(-1, 12)
        G = np.einsum("eij,ejp->eip", kernel.gradient_operator, B[rows])  # (e, 9, p)
        G = G.reshape(-1, 3, 3, p)  # H_ab = G[e, a, b] · y  (H = ∂u_a/∂X_b)
        mu, lam = material.mu, material.lam
        volume = kernel.volumes
        # terms: E_ab for a <= b (weight μV, 2μV off the diagonal) and tr E (weight λV/2)
        pairs = [(a, b) for a in range(3) for b in range(a, 3)]
        linear, quadratic, alpha = [], [], []
        for a, b in pairs:
            s_ab = 0.5 * (G[:, a, b] + G[:, b, a])  # (e, p)
            q_ab = 0.5 * (np.einsum("ecp,ecq->epq", G[:, :, a], G[:, :, b])
                          + np.einsum("ecp,ecq->epq", G[:, :, b], G[:, :, a]))
            linear.append(s_ab)
            quadratic.append(q_ab)
            alpha.append(mu * volume * (1.0 if a == b else 2.0))
        trace_l = G[:, 0, 0] + G[:, 1, 1] + G[:, 2, 2]
        trace_q = np.einsum("ecap,ecaq->epq", G, G)
        linear.append(trace_l)
        quadratic.append(trace_q)
        alpha.append(0.5 * lam * volume)
        l_terms = np.concatenate(linear)  # (N, p)
        a_terms = np.concatenate(quadratic).reshape(-1, p * p)  # (N, p²)
        w = np.concatenate(alpha)  # (N,)
        self.p = p
        self.K = 2.0 * (l_terms * w[:, None]).T @ l_terms
        C = np.zeros((p, p * p))
        D = np.zeros((p * p, p * p))
        for start in range(0, w.size, _CHUNK_TERMS):
            sl = slice(start, start + _CHUNK_TERMS)
            weighted = a_terms[sl] * w[sl, None]
            C += l_terms[sl].T @ weighted
            D += 0.25 * weighted.T @ a_terms[sl]
        # C_ijk = Σ α l_i A_jk (symmetric in j, k); D_ijkl = ¼ Σ α A_ij A_kl
        self._C_first = np.ascontiguousarray(C)  # (p, p²): rows i
        self._C_pair = np.ascontiguousarray(C.reshape(p * p, p))  # (p², p): rows (i, j)
        self._D_cubic = np.ascontiguousarray(D.reshape(p * p * p, p))  # rows (i, j, k)

    def energy(self, y: np.ndarray) -> float:
        """E(y) in J."""
        y = np.asarray(y, dtype=float)
        p = self.p
        Dyy = ((self._D_cubic @ y).reshape(p * p, p) @ y).reshape(p, p)
        return float(y @ (0.5 * self.K @ y + self._cubic(y) + Dyy @ y))

    def _cubic(self, y: np.ndarray) -> np.ndarray:
        """(p,) Σ_jk C_ijk y_j y_k."""
        return (self._C_pair @ y).reshape(self.p, self.p) @ y

    def force_and_tangent(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(∇E (p,), ∇²E (p,p)) at y (one pass over the quartic tensor)."""
        return self.energy_force_and_tangent(y)[1:]

    def energy_force_and_tangent(self, y: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        """(E, ∇E (p,), ∇²E (p,p)) at y, sharing one pass over the quartic tensor."""
        y = np.asarray(y, dtype=float)
        p = self.p
        Dy = (self._D_cubic @ y).reshape(p, p, p)  # Σ_l D_ijkl y_l
        Dyy = Dy.reshape(p * p, p) @ y  # Σ_kl D_ijkl y_k y_l
        Dyy = Dyy.reshape(p, p)
        Dy_y = (y @ Dy.reshape(p, p * p)).reshape(p, p)  # Σ_il y_i D_ijkl y_l [j, k]
        Cy = (self._C_pair @ y).reshape(p, p)  # Σ_k C_ijk y_k
        M1 = (y @ self._C_first).reshape(p, p)  # Σ_i y_i C_ijk
        Ky, cubic, quartic = self.K @ y, Cy @ y, Dyy @ y
        energy = float(y @ (0.5 * Ky + cubic + quartic))
        gradient = Ky + cubic + 2.0 * M1 @ y + 4.0 * quartic
        hessian = self.K + 2.0 * (Cy + Cy.T + M1) + 4.0 * Dyy + 8.0 * Dy_y
        return energy, gradient, 0.5 * (hessian + hessian.T)
