"""Compiled full-space assembly of the elastic force and tangent on the free dofs.

The same element quantities as :class:`~lbshape.elastic.element_kernels.FullSpaceElasticity`
(``f_ai = V Σ_j P_ij ∂_j N_a``, ``K_(ai)(bk) = V Σ_jl ∂_j N_a A_ijkl ∂_l N_b``, with the
stress P and its derivative A of :mod:`lbshape.elastic.jit_densities`), evaluated in one
compiled loop over all elements and scattered straight into the CSR data array of the
free-dof tangent through slots computed once (fixed dofs are skipped). A call allocates
only its output vector and data array; the pattern arrays are shared (read-only).

The sums run in element order like the numpy path's ``bincount``; the element matrices
are grouped differently, so the two agree to round-off (a few ulps of the largest
entry), not bit for bit.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from lbshape._jit import njit
from lbshape.elastic.block_energy import _energy, stvk_stress
from lbshape.elastic.element_kernels import ElementKernel
from lbshape.elastic.jit_densities import _element, density_parameters
from lbshape.elastic.materials import Material
from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh


class CompiledElasticity:
    """Elastic force and tangent of a whole mesh restricted to its free dofs, compiled.

    Args:
        mesh: the mesh; its points are the rest shape.
        material: the hyperelastic material.
        free_dofs: (nf,) sorted node-major indices of the free dofs (default: all 3n).

    Attributes:
        n_dofs: 3n.
        free_dofs: (nf,) the free dofs.
        indptr, indices: the CSR pattern (nf, nf) of the free-dof tangent (every
            (row, col) pair two free dofs of one element share; sorted columns).
    """

    def __init__(self, mesh: TetMesh, material: Material,
                 free_dofs: np.ndarray | None = None):
        kernel = ElementKernel(mesh.points, mesh.tets, material)
        n3 = 3 * mesh.n_vertices
        self.n_dofs = n3
        free = np.arange(n3) if free_dofs is None else np.asarray(free_dofs, dtype=np.int64)
        if free.ndim != 1 or free.size == 0 or np.any(np.diff(free) <= 0) or free[0] < 0 \
                or free[-1] >= n3:
            raise LbshapeError("free dofs must be a non-empty increasing array in [0, 3n)")
        self.free_dofs = free
        local = np.full(n3, -1, dtype=np.int64)  # full dof -> free index (-1: fixed)
        local[free] = np.arange(free.size)
        tets = np.asarray(mesh.tets, dtype=np.int64)
        dofs = local[(3 * tets[:, :, None] + np.arange(3)).reshape(-1, 12)]  # (e, 12)
        rows = np.broadcast_to(dofs[:, :, None], (len(dofs), 12, 12)).reshape(-1)
        cols = np.broadcast_to(dofs[:, None, :], (len(dofs), 12, 12)).reshape(-1)
        kept = (rows >= 0) & (cols >= 0)
        nf = free.size
        keys = rows[kept] * nf + cols[kept]
        unique, inverse = np.unique(keys, return_inverse=True)
        slots = np.full(rows.size, -1, dtype=np.int64)
        slots[kept] = inverse.ravel()
        self._slots = slots.reshape(-1, 144)
        self._nnz = unique.size
        self.indices = (unique % nf).astype(np.int32)
        counts = np.bincount(unique // nf, minlength=nf)
        self.indptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
        self._element_dofs = dofs
        self._full_dofs = (3 * tets[:, :, None] + np.arange(3)).reshape(-1, 12)
        self._gradients = np.ascontiguousarray(kernel.gradients)
        self._volumes = np.ascontiguousarray(kernel.volumes)
        self._code, self._parameters = density_parameters(material)
        self._shape = (nf, nf)
        rows_of = np.repeat(np.arange(nf, dtype=np.int64), counts)
        self._keys = rows_of * nf + self.indices  # sorted: the pattern's (row, col) keys
        self._constant: dict[int, tuple] = {}  # add_into's kept positions
        # whole vertices free: rows 3I..3I+2 share their columns, in aligned triples
        counts3 = counts.reshape(-1, 3) if nf % 3 == 0 else None
        #: the free dofs form whole vertices: the pattern is made of 3 × 3 blocks
        self.blocked = bool(
            counts3 is not None and np.all(free.reshape(-1, 3) % 3 == np.arange(3))
            and np.all(free.reshape(-1, 3)[:, 0] // 3 == free.reshape(-1, 3)[:, 2] // 3)
            and np.all(counts3 == counts3[:, :1]) and np.all(counts3 % 3 == 0)
            and np.all(self.indices.reshape(-1, 3) % 3 == np.arange(3)))

    def pattern_data(self, matrix: sp.spmatrix) -> tuple[np.ndarray, np.ndarray] | None:
        """(positions, values): ``matrix``'s (nf, nf) entries (duplicates summed) as distinct
        positions in the tangent's CSR data array and their values; None when an entry
        lies outside the pattern."""
        coo = sp.coo_matrix(matrix)
        coo.sum_duplicates()  # unique positions
        if coo.shape != self._shape:
            return None
        position = self._find(coo.row.astype(np.int64), coo.col)
        return None if position is None else (position, coo.data)

    def _find(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray | None:
        """Positions in the CSR data array of the free-dof entries (rows, cols), or None
        when one lies outside the pattern."""
        wanted = rows * self._shape[0] + cols
        position = np.searchsorted(self._keys, wanted)
        position[position >= self._keys.size] = 0
        return position if np.array_equal(self._keys[position], wanted) else None

    def positions(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray | None:
        """Positions in the tangent's CSR data array of the entries (rows, cols) given as
        full dofs (−1 where either is a fixed dof), or None when a pair of free dofs lies
        outside the pattern."""
        local = np.full(self.n_dofs, -1, dtype=np.int64)
        local[self.free_dofs] = np.arange(self.free_dofs.size)
        r, c = local[np.asarray(rows)], local[np.asarray(cols)]
        free = (r >= 0) & (c >= 0)
        found = self._find(r[free], c[free])
        if found is None:
            return None
        out = np.full(r.shape, -1, dtype=np.int64)
        out[free] = found
        return out

    def pattern_values(self, matrix: sp.spmatrix) -> np.ndarray | None:
        """``matrix`` (nf, nf) as a data array on the tangent's pattern (zeros elsewhere;
        duplicates summed), or None when it has an entry outside the pattern."""
        found = self.pattern_data(matrix)
        if found is None:
            return None
        data = np.zeros(self._nnz)
        data[found[0]] = found[1]
        return data

    def rotated(self, data: np.ndarray, R: np.ndarray) -> np.ndarray | None:
        """The data array of ``Q A Qᵀ``, ``Q = diag(R, …, R)``, for A given by its ``data``
        on this pattern (each 3 × 3 vertex block ``R A_IJ Rᵀ``); None when the free dofs
        do not form whole vertices (the pattern is then not made of 3 × 3 blocks)."""
        if not self.blocked:
            return None
        out = np.empty_like(data)
        _rotate_blocks(self.indptr, np.ascontiguousarray(data, dtype=np.float64),
                       np.ascontiguousarray(R, dtype=np.float64), out)
        return out

    def on_pattern(self, K: sp.spmatrix) -> bool:
        """K is a CSR matrix on this tangent's pattern."""
        return (sp.isspmatrix_csr(K) and K.shape == self._shape
                and K.indices.size == self.indices.size
                and np.array_equal(K.indptr, self.indptr)
                and np.array_equal(K.indices, self.indices))

    def add_into(self, K: sp.csr_matrix, matrix: sp.spmatrix, *,
                 constant: bool = False, scale: float = 1.0) -> sp.csr_matrix:
        """``K + scale · matrix``: in place on K's data when K is on this pattern and holds
        ``matrix``'s entries, else a new sparse sum. ``constant``: ``matrix`` does not
        change between calls (its positions are kept; ``scale`` may)."""
        if self.on_pattern(K):
            if constant:  # kept as a whole data array: one contiguous addition
                kept = self._constant.get(id(matrix))
                if kept is None or kept[0] is not matrix:
                    kept = (matrix, self.pattern_values(matrix))
                    self._constant[id(matrix)] = kept
                if kept[1] is not None:
                    K.data += kept[1] if scale == 1.0 else scale * kept[1]
                    return K
            else:
                found = self.pattern_data(matrix)
                if found is not None:
                    K.data[found[0]] += found[1] if scale == 1.0 else scale * found[1]
                    return K
        return (K + (matrix if scale == 1.0 else scale * matrix)).tocsr()

    def energy(self, u: np.ndarray) -> float:
        """Total strain energy (J) at the full node-major displacement u (3n,) m (every
        element; the numpy densities' ``Ψ(I + H) − Ψ(I)``, compiled)."""
        u = np.ascontiguousarray(u, dtype=np.float64)
        if u.shape != (self.n_dofs,):
            raise LbshapeError(f"displacement must have shape ({self.n_dofs},), got {u.shape}")
        if self._code == 0:  # StVK: in scalars (same operations)
            return float(_stvk_energy_total(self._parameters[0], self._parameters[1], u,
                                            self._full_dofs, self._gradients, self._volumes))
        return float(_energy_total(self._code, self._parameters, u, self._full_dofs,
                                   self._gradients, self._volumes))

    def force(self, u: np.ndarray) -> np.ndarray:
        """The force (nf,) N of :meth:`force_and_tangent` alone (the same sums, in the same
        order: equal to its force bit for bit)."""
        u = np.ascontiguousarray(u, dtype=np.float64)
        if u.shape != (self.n_dofs,):
            raise LbshapeError(f"displacement must have shape ({self.n_dofs},), got {u.shape}")
        f = np.empty(self._shape[0])
        if self._code == 0:  # StVK: the element's stress in scalars (same operations)
            _stvk_force(self._parameters[0], self._parameters[1], u, self._full_dofs,
                        self._element_dofs, self._gradients, self._volumes, f)
        else:
            _assemble_force(self._code, self._parameters, u, self._full_dofs,
                            self._element_dofs, self._gradients, self._volumes, f)
        return f

    def force_and_tangent(self, u: np.ndarray) -> tuple[np.ndarray, sp.csr_matrix]:
        """(force (nf,) N, tangent (nf, nf) N/m CSR) on the free dofs at the full
        node-major displacement u (3n,) m (``+∂E/∂u`` and its derivative)."""
        u = np.ascontiguousarray(u, dtype=np.float64)
        if u.shape != (self.n_dofs,):
            raise LbshapeError(f"displacement must have shape ({self.n_dofs},), got {u.shape}")
        f = np.empty(self._shape[0])
        data = np.empty(self._nnz)
        _assemble(self._code, self._parameters, u, self._full_dofs, self._element_dofs,
                  self._gradients, self._volumes, self._slots, f, data)
        K = sp.csr_matrix((data, self.indices, self.indptr), shape=self._shape)
        return f, K


@njit
def _displacement_gradient(u, dofs, G, H9):
    """H9 (9, 1): the element's displacement gradient H_ij = Σ_a u[dofs[3a + i]] G_aj
    (dofs (12,) its full node-major dofs, G (4, 3) its shape-function gradients)."""
    for i in range(3):
        for j in range(3):
            value = 0.0
            for a in range(4):
                value += u[dofs[3 * a + i]] * G[a, j]
            H9[3 * i + j, 0] = value


@njit
def _add_element_force(dofs, P9, G, V, f):
    """f += the element's force f_ai = V Σ_j P_ij G_aj on its free dofs (dofs (12,), −1 where
    fixed; P9 (9, 1) the first Piola stress, V the volume)."""
    for a in range(4):
        for i in range(3):
            row = dofs[3 * a + i]
            if row < 0:
                continue
            value = 0.0
            for j in range(3):
                value += P9[3 * i + j, 0] * G[a, j]
            f[row] += V * value


@njit
def _assemble_force(code, parameters, u, full_dofs, element_dofs, gradients, volumes, f):
    f[:] = 0.0
    H9 = np.empty((9, 1))
    P9 = np.empty((9, 1))
    A = np.empty((1, 9, 9))
    work = np.empty((6, 3, 3))
    for e in range(full_dofs.shape[0]):
        G = gradients[e]
        V = volumes[e]
        _displacement_gradient(u, full_dofs[e], G, H9)
        _element(code, parameters, H9, P9, A, 0, work, False)
        _add_element_force(element_dofs[e], P9, G, V, f)


@njit
def _gradient_tuple(u, d, G):
    """The element's displacement gradient H (9-tuple, row-major), summed as
    :func:`_displacement_gradient` sums it."""
    h00 = h01 = h02 = h10 = h11 = h12 = h20 = h21 = h22 = 0.0
    for a in range(4):
        u0, u1, u2 = u[d[3 * a]], u[d[3 * a + 1]], u[d[3 * a + 2]]
        ga0, ga1, ga2 = G[a, 0], G[a, 1], G[a, 2]
        h00 += u0 * ga0
        h01 += u0 * ga1
        h02 += u0 * ga2
        h10 += u1 * ga0
        h11 += u1 * ga1
        h12 += u1 * ga2
        h20 += u2 * ga0
        h21 += u2 * ga1
        h22 += u2 * ga2
    return (h00, h01, h02, h10, h11, h12, h20, h21, h22)


@njit
def _stvk_energy_total(mu, lam, u, full_dofs, gradients, volumes):
    """:func:`_energy_total` for StVK, in scalars (the same sums in the same order)."""
    total = 0.0
    for e in range(full_dofs.shape[0]):
        _, psi = stvk_stress(_gradient_tuple(u, full_dofs[e], gradients[e]), mu, lam)
        total += volumes[e] * psi
    return total


@njit
def _stvk_force(mu, lam, u, full_dofs, element_dofs, gradients, volumes, f):
    """:func:`_assemble_force` for StVK (:func:`~lbshape.elastic.block_energy.stvk_stress`):
    the same sums in the same order, the element's quantities in scalars."""
    f[:] = 0.0
    for e in range(full_dofs.shape[0]):
        G = gradients[e]
        P, _ = stvk_stress(_gradient_tuple(u, full_dofs[e], G), mu, lam)
        V = volumes[e]
        dofs = element_dofs[e]
        for a in range(4):
            ga0, ga1, ga2 = G[a, 0], G[a, 1], G[a, 2]
            row = dofs[3 * a]
            if row >= 0:
                f[row] += V * (P[0] * ga0 + P[1] * ga1 + P[2] * ga2)
            row = dofs[3 * a + 1]
            if row >= 0:
                f[row] += V * (P[3] * ga0 + P[4] * ga1 + P[5] * ga2)
            row = dofs[3 * a + 2]
            if row >= 0:
                f[row] += V * (P[6] * ga0 + P[7] * ga1 + P[8] * ga2)


@njit
def _energy_total(code, parameters, u, full_dofs, gradients, volumes):
    H9 = np.empty((9, 1))
    total = 0.0
    for e in range(full_dofs.shape[0]):
        G = gradients[e]
        _displacement_gradient(u, full_dofs[e], G, H9)
        total += volumes[e] * _energy(code, parameters, H9)
    return total


@njit
def _rotate_blocks(indptr, data, R, out):
    """out: each 3 × 3 block B of data (rows 3I..3I+2, aligned column triples) as R B Rᵀ."""
    B = np.empty((3, 3))
    C = np.empty((3, 3))
    for vertex in range((indptr.size - 1) // 3):
        start0 = indptr[3 * vertex]
        count = indptr[3 * vertex + 1] - start0
        for p in range(0, count, 3):
            for a in range(3):
                start = indptr[3 * vertex + a] + p
                for b in range(3):
                    B[a, b] = data[start + b]
            for a in range(3):  # C = R B
                for b in range(3):
                    C[a, b] = R[a, 0] * B[0, b] + R[a, 1] * B[1, b] + R[a, 2] * B[2, b]
            for a in range(3):  # out = C Rᵀ
                start = indptr[3 * vertex + a] + p
                for b in range(3):
                    out[start + b] = C[a, 0] * R[b, 0] + C[a, 1] * R[b, 1] + C[a, 2] * R[b, 2]


@njit
def _assemble(code, parameters, u, full_dofs, element_dofs, gradients, volumes, slots,
              f, data):
    f[:] = 0.0
    data[:] = 0.0
    H9 = np.empty((9, 1))
    P9 = np.empty((9, 1))
    A = np.empty((1, 9, 9))
    work = np.empty((6, 3, 3))
    T = np.empty((9, 12))
    for e in range(full_dofs.shape[0]):
        G = gradients[e]
        V = volumes[e]
        _displacement_gradient(u, full_dofs[e], G, H9)
        _element(code, parameters, H9, P9, A, 0, work, True)
        _add_element_force(element_dofs[e], P9, G, V, f)
        # T[(ij), (bk)] = Σ_l A[ij, kl] G_bl; K[(ai), (bk)] = V Σ_j G_aj T[(ij), (bk)]
        for ij in range(9):
            for b in range(4):
                for k in range(3):
                    value = 0.0
                    for l in range(3):
                        value += A[0, ij, 3 * k + l] * G[b, l]
                    T[ij, 3 * b + k] = value
        for a in range(4):
            for i in range(3):
                r = 3 * a + i
                for c in range(12):
                    slot = slots[e, 12 * r + c]
                    if slot < 0:
                        continue
                    value = 0.0
                    for j in range(3):
                        value += G[a, j] * T[3 * i + j, c]
                    data[slot] += V * value
