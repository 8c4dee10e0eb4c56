"""Per-element hyperelastic energy, force and tangent of linear tetrahedra (numpy).

:class:`ElementKernel` evaluates a set of e elements with their own rest shape (the
object's, or an example pose's) on element displacements ``ue`` (e, 4, 3); the
full-space functions assemble all elements of a :class:`~lbshape.geometry.mesh.TetMesh` on a
node-major displacement ``u`` (3n,) in input vertex order. The densities are those
of :mod:`lbshape.elastic.energy_densities` (zero energy at rest), and they match the UFL
energies of :mod:`lbshape.elastic.materials` up to that constant.

Conventions (see ``docs/architecture.md``): ``f_int = +∂E/∂u``; element dofs are
node-major, ``12 = 4 nodes × 3 components`` (dof ``3a + i``); tangents are
``∂f_int/∂u``, symmetric.

For one P1 tetrahedron with rest vertices ``X_a`` and rest volume V:
``F = I + Σ_a u_a ⊗ ∇N_a``, ``E = V Ψ(F)``, ``f_ai = V Σ_j P_ij ∂_j N_a``,
``K_(ai)(bk) = V Σ_jl ∂_j N_a A_ijkl ∂_l N_b``.
"""

from __future__ import annotations

import functools

import numpy as np
import scipy.sparse as sp

from lbshape.elastic.energy_densities import density_model
from lbshape.elastic.materials import Material
from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import DEGENERATE_RTOL, TetMesh


class ElementKernel:
    """Energy, internal forces and tangents of e tetrahedra with a given rest shape.

    Args:
        points: (n, 3) rest vertex positions in metres (any shape, e.g. an example pose).
        tets: (e, 4) vertex indices of the elements to evaluate (a subset is fine).
        material: the hyperelastic material.

    Attributes:
        material: the material.
        n_elements: e.
        Dm_inv: (e, 3, 3) inverse rest edge matrices ``[X1−X0, X2−X0, X3−X0]⁻¹`` (1/m).
        volumes: (e,) rest volumes in m³ (positive, whatever the rest orientation).
        gradients: (e, 4, 3) shape-function gradients ``∇N_a`` in 1/m.
        gradient_operator: (e, 9, 12) B with ``F.ravel() = I.ravel() + B @ ue.ravel()``
            (row-major F, node-major ue): ``B[e, 3i + j, 3a + k] = δ_ik ∂_j N_a``.
            Lets reduced models map coordinates to F in one product.
        density: the :class:`~lbshape.elastic.energy_densities.DensityModel` of the material
            (its ``*_t`` methods take the element-last ``H = F − I``).

    Raises:
        LbshapeError: wrong shapes, indices out of range, non-finite points or a
            degenerate (zero-volume) rest element.
    """

    def __init__(self, points: np.ndarray, tets: np.ndarray, material: Material):
        points = np.asarray(points, dtype=np.float64)
        tets = np.asarray(tets)
        if points.ndim != 2 or points.shape[1] != 3:
            raise LbshapeError(f"rest points must have shape (n, 3), got {points.shape}")
        if tets.ndim != 2 or tets.shape[1] != 4 or tets.shape[0] == 0:
            raise LbshapeError(f"elements must have shape (e, 4) with e >= 1, got {tets.shape}")
        if not np.issubdtype(tets.dtype, np.integer):
            raise LbshapeError(f"element indices must be integers, got dtype {tets.dtype}")
        if tets.min() < 0 or tets.max() >= points.shape[0]:
            raise LbshapeError(f"element vertex index out of range [0, {points.shape[0]})")
        if not np.isfinite(points).all():
            raise LbshapeError("rest points contain NaN or infinite coordinates")
        if not isinstance(material, Material):
            raise LbshapeError(f"material must be a lbshape Material, got {type(material)}")
        X = points[tets]
        Dm = np.ascontiguousarray((X[:, 1:] - X[:, :1]).transpose(0, 2, 1))
        det = np.linalg.det(Dm)
        edges = np.linalg.norm(X[:, [1, 2, 3, 2, 3, 3]] - X[:, [0, 0, 0, 1, 1, 2]], axis=2)
        degenerate = np.abs(det) <= 6.0 * DEGENERATE_RTOL * edges.mean(axis=1) ** 3
        if degenerate.any():
            first = int(np.flatnonzero(degenerate)[0])
            raise LbshapeError(
                f"{int(degenerate.sum())} degenerate (zero-volume) rest elements "
                f"(first: element {first}, vertices {tets[first].tolist()})"
            )
        e = tets.shape[0]
        self.material = material
        self.n_elements = e
        self.Dm_inv = np.linalg.inv(Dm)
        self.volumes = np.abs(det) / 6.0
        G = np.empty((e, 4, 3))
        G[:, 1:] = self.Dm_inv
        G[:, 0] = -self.Dm_inv.sum(axis=1)
        self.gradients = G
        self.density = density_model(material)
        self._shape = (e, 4, 3)
        # forces: f[e, a, i] = Σ_j (V G)[e, a, j] P[e, i, j]
        self._vg = self.volumes[:, None, None] * G

    @functools.cached_property
    def gradient_operator(self) -> np.ndarray:
        """(e, 9, 12) B with ``F.ravel() = I.ravel() + B @ ue.ravel()``, built on first use
        (the reduced models and the cubature's passes never ask for it)."""
        B = np.zeros((self.n_elements, 3, 3, 4, 3))
        for i in range(3):  # B[e, (i, j), (a, k)] = δ_ik ∂_j N_a
            B[:, i, :, :, i] = self.gradients.transpose(0, 2, 1)
        return B.reshape(self.n_elements, 9, 12)

    @functools.cached_property
    def _vbt(self) -> np.ndarray:
        """(e, 12, 9) ``V Bᵀ`` of the tangents ``K = V Bᵀ A B``."""
        return np.ascontiguousarray(
            self.volumes[:, None, None] * self.gradient_operator.transpose(0, 2, 1))

    # -- kinematics --------------------------------------------------------------------
    def _check(self, ue: np.ndarray) -> np.ndarray:
        ue = np.asarray(ue, dtype=np.float64)
        if ue.shape != self._shape:
            raise LbshapeError(
                f"element displacements must have shape {self._shape}, got {np.shape(ue)}"
            )
        return ue

    def _displacement_gradient_t(self, ue: np.ndarray) -> np.ndarray:
        """Element-last displacement gradients Ht = F − I, (3, 3, e)."""
        e = self.n_elements
        grad_u = np.matmul(self.gradient_operator, self._check(ue).reshape(e, 12, 1))
        return np.ascontiguousarray(grad_u.reshape(e, 9).T).reshape(3, 3, e)

    def deformation_gradient(self, ue: np.ndarray) -> np.ndarray:
        """F = I + Σ_a u_a ⊗ ∇N_a, (e, 3, 3), of element displacements ue (e, 4, 3) m."""
        F = np.matmul(self._check(ue).transpose(0, 2, 1), self.gradients)
        F.reshape(-1, 9)[:, ::4] += 1.0
        return F

    def jacobians(self, ue: np.ndarray) -> np.ndarray:
        """det F (e,) of element displacements ue (e, 4, 3); ≤ 0 means inverted."""
        Ft = self._displacement_gradient_t(ue)
        Ft.reshape(9, -1)[::4] += 1.0
        return (
            Ft[0, 0] * (Ft[1, 1] * Ft[2, 2] - Ft[1, 2] * Ft[2, 1])
            - Ft[0, 1] * (Ft[1, 0] * Ft[2, 2] - Ft[1, 2] * Ft[2, 0])
            + Ft[0, 2] * (Ft[1, 0] * Ft[2, 1] - Ft[1, 1] * Ft[2, 0])
        )

    def min_jacobian(self, ue: np.ndarray) -> float:
        """The smallest det F over the elements; ≤ 0 means some element is inverted."""
        return float(self.jacobians(ue).min())

    # -- energy, forces, tangents --------------------------------------------------------
    def energy(self, ue: np.ndarray) -> np.ndarray:
        """Element strain energies (e,) in J of element displacements ue (e, 4, 3) m."""
        return self.volumes * self.density.energy_t(self._displacement_gradient_t(ue))

    def _forces_from_stress(self, Pt: np.ndarray) -> np.ndarray:
        return np.matmul(self._vg, Pt.transpose(2, 1, 0))

    def forces(self, ue: np.ndarray) -> np.ndarray:
        """Internal forces ``+∂E/∂ue`` (e, 4, 3) in N of ue (e, 4, 3) m."""
        return self._forces_from_stress(self.density.stress_t(self._displacement_gradient_t(ue)))

    def _tangents_from_derivative(self, At: np.ndarray) -> np.ndarray:
        e = self.n_elements
        A = np.ascontiguousarray(At.reshape(81, e).T).reshape(e, 9, 9)
        return np.matmul(np.matmul(self._vbt, A), self.gradient_operator)

    def tangents(self, ue: np.ndarray) -> np.ndarray:
        """Tangent stiffnesses ∂f/∂ue (e, 12, 12) in N/m, node-major dofs ``3a + i``."""
        return self.forces_and_tangents(ue)[1]

    def forces_and_tangents(self, ue: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(forces (e, 4, 3) N, tangents (e, 12, 12) N/m) of ue (e, 4, 3) m."""
        Pt, At = self.density.stress_and_derivative_t(self._displacement_gradient_t(ue))
        return self._forces_from_stress(Pt), self._tangents_from_derivative(At)


# -- full space -----------------------------------------------------------------------------
class FullSpaceElasticity:
    """Elastic energy, internal force and tangent stiffness of a whole mesh.

    The element data and the sparsity pattern (with the map from element-matrix
    entries to CSR slots) are built once; each call is vectorised over all elements.

    Args:
        mesh: the mesh; its points are the rest shape.
        material: the hyperelastic material.

    Attributes:
        kernel: the :class:`ElementKernel` of all elements.
        n_dofs: 3n.
    """

    def __init__(self, mesh: TetMesh, material: Material):
        self.mesh = mesh
        self.kernel = ElementKernel(mesh.points, mesh.tets, material)
        n = mesh.n_vertices
        self.n_dofs = 3 * n
        tets = np.asarray(mesh.tets, dtype=np.int64)
        self._tets = tets
        dofs = (3 * tets[:, :, None] + np.arange(3)).reshape(-1, 12)  # (e, 12)
        self._dofs = dofs
        rows = np.broadcast_to(dofs[:, :, None], (len(dofs), 12, 12)).ravel()
        cols = np.broadcast_to(dofs[:, None, :], (len(dofs), 12, 12)).ravel()
        # CSR pattern: unique (row, col) pairs in row-major order
        keys = rows * self.n_dofs + cols
        unique, self._slot = np.unique(keys, return_inverse=True)
        self._slot = self._slot.ravel()
        self._nnz = unique.size
        self._indices = (unique % self.n_dofs).astype(np.int32)
        counts = np.bincount(unique // self.n_dofs, minlength=self.n_dofs)
        self._indptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)

    def _element_displacements(self, u: np.ndarray) -> np.ndarray:
        u = np.asarray(u, dtype=np.float64)
        if u.shape != (self.n_dofs,):
            raise LbshapeError(
                f"displacement must be node-major with shape ({self.n_dofs},), got {u.shape}"
            )
        return u.reshape(-1, 3)[self._tets]

    def energy(self, u: np.ndarray) -> float:
        """Total strain energy in J of the displacement u (3n,) in metres."""
        return float(self.kernel.energy(self._element_displacements(u)).sum())

    def force(self, u: np.ndarray) -> np.ndarray:
        """Internal force ``+∂E/∂u`` (3n,) in N, node-major, input vertex order."""
        fe = self.kernel.forces(self._element_displacements(u))
        return np.bincount(self._dofs.ravel(), weights=fe.ravel(), minlength=self.n_dofs)

    def tangent(self, u: np.ndarray) -> sp.csr_matrix:
        """Tangent stiffness ∂f/∂u (3n, 3n) in N/m, CSR, symmetric."""
        Ke = self.kernel.tangents(self._element_displacements(u))
        return self._assemble(Ke)

    def force_and_tangent(self, u: np.ndarray) -> tuple[np.ndarray, sp.csr_matrix]:
        """(force (3n,) N, tangent (3n, 3n) N/m CSR), sharing the element work."""
        fe, Ke = self.kernel.forces_and_tangents(self._element_displacements(u))
        f = np.bincount(self._dofs.ravel(), weights=fe.ravel(), minlength=self.n_dofs)
        return f, self._assemble(Ke)

    def _assemble(self, Ke: np.ndarray) -> sp.csr_matrix:
        data = np.bincount(self._slot, weights=Ke.ravel(), minlength=self._nnz)
        return sp.csr_matrix(
            (data, self._indices.copy(), self._indptr.copy()), shape=(self.n_dofs, self.n_dofs)
        )


def strain_energy(mesh: TetMesh, material: Material, u: np.ndarray) -> float:
    """Total strain energy in J of u (3n,) m; see :class:`FullSpaceElasticity`."""
    return FullSpaceElasticity(mesh, material).energy(u)


def internal_force(mesh: TetMesh, material: Material, u: np.ndarray) -> np.ndarray:
    """Internal force ``+∂E/∂u`` (3n,) in N of u (3n,) m; see :class:`FullSpaceElasticity`."""
    return FullSpaceElasticity(mesh, material).force(u)


def tangent_stiffness(mesh: TetMesh, material: Material, u: np.ndarray) -> sp.csr_matrix:
    """Tangent stiffness (3n, 3n) N/m CSR at u (3n,) m; see :class:`FullSpaceElasticity`."""
    return FullSpaceElasticity(mesh, material).tangent(u)


def mass_matrix(mesh: TetMesh, density: float, *, lumped: bool = False) -> sp.csr_matrix:
    """P1 mass matrix (3n, 3n) in kg, node-major, input vertex order.

    Consistent: ``M_ab = ρV/20 (1 + δ_ab)`` per element, times I₃ per block. Lumped:
    the row sums, ``ρV/4`` per element and vertex, on the diagonal. Both give the
    total mass ``ρ · volume`` per component.

    Args:
        mesh: the mesh.
        density: ρ in kg/m³, > 0.
        lumped: return the diagonal (row-sum) lumped matrix.
    """
    if isinstance(density, bool) or not isinstance(density, int | float | np.floating):
        raise LbshapeError(f"density must be a number in kg/m^3, got {density!r}")
    if not density > 0 or not np.isfinite(density):
        raise LbshapeError(f"density must be > 0 kg/m^3, got {density}")
    n = mesh.n_vertices
    tets = np.asarray(mesh.tets, dtype=np.int64)
    vol = np.abs(mesh.signed_volumes())
    if lumped:
        m = np.bincount(tets.ravel(), weights=np.repeat(density * vol / 4.0, 4), minlength=n)
        return sp.diags(np.repeat(m, 3), format="csr")
    local = (np.ones((4, 4)) + np.eye(4)) / 20.0
    rows = (3 * tets[:, :, None, None] + np.arange(3)[None, None, None, :]).repeat(4, axis=2)
    cols = (3 * tets[:, None, :, None] + np.arange(3)[None, None, None, :]).repeat(4, axis=1)
    data = (density * vol)[:, None, None, None] * local[None, :, :, None]
    data = np.broadcast_to(data, rows.shape)
    M = sp.coo_matrix((data.ravel(), (rows.ravel(), cols.ravel())), shape=(3 * n, 3 * n))
    return M.tocsr()
