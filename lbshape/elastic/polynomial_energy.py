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

Building (n-sized, once): the terms are formed for **chunks of elements** whose
temporaries stay below ``max_bytes`` and summed (with an MPI communicator, each rank
sums its share of the chunks, :func:`lbshape.fem.mpi.rank_share`, and the parts are
summed over the ranks). Each A_j is symmetric, so only its upper triangle enters
the sums (``D`` from a symmetric rank-k update). For the LB displacement basis
``B = Φ ⊗ I₃`` (column ``3i + c`` moves component c by φ_i, detected from B) every
``A_j = I₃ ⊗ Â_j`` with ``Â_j`` (m, m) built from the element gradients of the m
eigenfunctions, so the sums run over m(m+1)/2 instead of p(p+1)/2 entries (81 times
fewer products for D) and are expanded once at the end; any other basis takes the
general path.
"""

from __future__ import annotations

import numpy as np

from lbshape.elastic.element_kernels import ElementKernel
from lbshape.elastic.materials import Material
from lbshape.elastic.reduced_forces import gradient_basis
from lbshape.errors import LbshapeError
from lbshape.fem.mpi import rank_share, sum_over_ranks

#: default bound (bytes) on the temporary arrays of one chunk of elements
DEFAULT_MAX_BYTES = 256 * 2**20
#: the strain terms: E_ab for a <= b, then tr E (index pairs into the 3 × 3 strain)
_PAIRS = [(a, b) for a in range(3) for b in range(a, 3)]


class StVKPolynomialEnergy:
    """Exact StVK energy of ``u = B y`` on a rest shape, with gradient and Hessian.

    Args:
        rest_points: (n, 3) rest shape in metres.
        tets: (t, 4) tetrahedra.
        material: an ``stvk`` material.
        basis: (3n, p) node-major basis B.
        max_bytes: bound (bytes) on the temporaries of one chunk of elements (same
            result, to round-off, for any bound).
        comm: MPI communicator: the element chunks are split across its ranks (every
            rank gets the whole model); None: serial.
        structured: use the m-sized sums when B is ``Φ ⊗ I₃`` (False: always the
            general path; the two agree to round-off).

    Attributes:
        p: number of coordinates.
        K: (p, p) stiffness at rest (N/m per unit of y²).
    """

    def __init__(self, rest_points: np.ndarray, tets: np.ndarray, material: Material,
                 basis: np.ndarray, *, max_bytes: int = DEFAULT_MAX_BYTES, comm=None,
                 structured: bool = True):
        if material.model != "stvk":
            raise LbshapeError("the polynomial reduced energy exists only for StVK materials")
        B = np.asarray(basis, dtype=float)
        rest_points = np.asarray(rest_points, dtype=float)
        tets = np.asarray(tets)
        n = rest_points.shape[0]
        if B.ndim != 2 or B.shape[0] != 3 * n:
            raise LbshapeError(f"basis must have shape (3n={3 * n}, p), got {B.shape}")
        p = B.shape[1]
        phi = _scalar_basis(B) if structured else None
        width = p if phi is None else phi.shape[1]  # side of the summed quadratic terms
        upper = np.triu_indices(width)
        per_element = 8 * (30 * p + 7 * (2 * width * width + 3 * upper[0].size))
        size = int(max(1, max_bytes // per_element))
        chunks = [(start, min(tets.shape[0], start + size))
                  for start in range(0, tets.shape[0], size)]
        K = np.zeros((p, p))
        C = np.zeros((p, upper[0].size))
        D = np.zeros((upper[0].size, upper[0].size))
        for index in rank_share(comm, len(chunks)):
            start, stop = chunks[index]
            kernel = ElementKernel(rest_points, tets[start:stop], material)
            if phi is None:
                linear, quadratic = _general_terms(kernel, tets[start:stop], B)
            else:
                linear, quadratic = _scalar_terms(kernel, tets[start:stop], phi)
            volume = kernel.volumes
            alpha = np.concatenate([material.mu * volume * (1.0 if a == b else 2.0)
                                    for a, b in _PAIRS] + [0.5 * material.lam * volume])
            packed = quadratic[:, upper[0], upper[1]]  # (N, w(w+1)/2)
            K += 2.0 * (linear * alpha[:, None]).T @ linear
            C += (linear * alpha[:, None]).T @ packed
            D += 0.25 * _weighted_gram(packed, alpha)
        K, C, D = (sum_over_ranks(comm, value) for value in (K, C, D))
        # unpack the upper triangles: index of (i, j) in the packed columns
        where = np.zeros((width, width), dtype=np.int64)
        where[upper] = np.arange(upper[0].size)
        where = np.maximum(where, where.T).reshape(-1)
        C, D = C[:, where], D[np.ix_(where, where)]
        if phi is not None:
            C, D = _expand_components(C, D, width)
        # C_ijk = Σ α l_i A_jk (symmetric in j, k); D_ijkl = ¼ Σ α A_ij A_kl
        self.p = p
        self.K = K
        self._C_first = np.ascontiguousarray(C)  # (p, p²): rows i
        self._C_pair = np.ascontiguousarray(C.reshape(p * p, p))  # (p², p): rows (i, j)
        self._D_cubic = np.ascontiguousarray(D.reshape(p * p * p, p))  # rows (i, j, k)
    def cubic_tensor(self) -> np.ndarray:
        """(p, p, p) C with ``E₃ = Σ C_ijk y_i y_j y_k`` (symmetric in j, k)."""
        return self._C_first.reshape(self.p, self.p, self.p).copy()

    def quartic_tensor(self) -> np.ndarray:
        """(p, p, p, p) D with ``E₄ = Σ D_ijkl y_i y_j y_k y_l`` (symmetric in i ↔ j,
        k ↔ l and (i, j) ↔ (k, l))."""
        return self._D_cubic.reshape(self.p, self.p, self.p, self.p).copy()

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


# -- building ---------------------------------------------------------------------------
def _general_terms(kernel: ElementKernel, tets: np.ndarray, B: np.ndarray):
    """Terms of a chunk for any basis: (linear (7s, p), quadratic (7s, p, p))."""
    s, p = tets.shape[0], B.shape[1]
    rows = (3 * tets[:, :, None].astype(np.int64) + np.arange(3)).reshape(s, 12)
    G = gradient_basis(kernel.gradients, B[rows]).reshape(s, 3, 3, p)  # H_ab = G[e,a,b]·y
    linear = [0.5 * (G[:, a, b] + G[:, b, a]) for a, b in _PAIRS]
    linear.append(G[:, 0, 0] + G[:, 1, 1] + G[:, 2, 2])
    columns = [np.ascontiguousarray(G[:, :, a].transpose(0, 2, 1)) for a in range(3)]  # (s,p,3)
    quadratic = []
    for a, b in _PAIRS:
        product = columns[a] @ columns[b].transpose(0, 2, 1)  # Σ_c G[c,a,p] G[c,b,q]
        quadratic.append(0.5 * (product + product.transpose(0, 2, 1)))
    quadratic.append(sum(c @ c.transpose(0, 2, 1) for c in columns))
    return np.concatenate(linear), np.concatenate(quadratic)


def _scalar_terms(kernel: ElementKernel, tets: np.ndarray, phi: np.ndarray):
    """Terms of a chunk for ``B = Φ ⊗ I₃``: (linear (7s, 3m), quadratic Â (7s, m, m)).

    With ``g[i, b] = ∂_b φ_i`` on the element, ``G[a, b, (i, c)] = δ_ac g[i, b]``, so
    ``A_ab = I₃ ⊗ ½(g_a g_bᵀ + g_b g_aᵀ)`` and ``A_tr = I₃ ⊗ g gᵀ``.
    """
    s, m = tets.shape[0], phi.shape[1]
    g = np.einsum("evi,evb->eib", phi[tets], kernel.gradients)  # (s, m, 3)
    linear = np.zeros((7, s, m, 3))  # column 3i + c
    for term, (a, b) in enumerate(_PAIRS):
        linear[term, :, :, a] += 0.5 * g[:, :, b]
        linear[term, :, :, b] += 0.5 * g[:, :, a]
    linear[6] = g
    quadratic = [0.5 * (g[:, :, a, None] * g[:, None, :, b] + g[:, :, b, None] * g[:, None, :, a])
                 for a, b in _PAIRS]
    quadratic.append(g @ g.transpose(0, 2, 1))
    return linear.reshape(7 * s, 3 * m), np.concatenate(quadratic)


def _weighted_gram(X: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """``Xᵀ diag(weights) X`` as symmetric rank-k updates (weights of either sign)."""
    out = np.zeros((X.shape[1], X.shape[1]))
    for sign in (1.0, -1.0):
        rows = sign * weights > 0
        if rows.any():
            Y = X[rows] * np.sqrt(sign * weights[rows])[:, None]
            out += sign * (Y.T @ Y)
    return out


def _expand_components(C_hat: np.ndarray, D_hat: np.ndarray, m: int):
    """C (p, p²) and D (p², p²) of ``A = I₃ ⊗ Â`` from Ĉ (p, m²) and D̂ (m², m²)."""
    p = 3 * m
    C = np.zeros((p, m, 3, m, 3))
    D = np.zeros((m, 3, m, 3, m, 3, m, 3))
    C_hat = C_hat.reshape(p, m, m)
    D_hat = D_hat.reshape(m, m, m, m)
    for c in range(3):
        C[:, :, c, :, c] = C_hat
        for d in range(3):
            D[:, c, :, c, :, d, :, d] = D_hat
    return C.reshape(p, p * p), D.reshape(p * p, p * p)


def _scalar_basis(B: np.ndarray) -> np.ndarray | None:
    """Φ (n, m) when ``B = Φ ⊗ I₃`` (node-major rows, column ``3i + c``), else None."""
    if B.shape[1] % 3:
        return None
    n, m = B.shape[0] // 3, B.shape[1] // 3
    blocks = B.reshape(n, 3, m, 3)
    phi = blocks[:, 0, :, 0]
    for a in range(3):
        for c in range(3):
            if not np.array_equal(blocks[:, a, :, c], phi if a == c else 0.0 * phi):
                return None
    return np.ascontiguousarray(phi)
