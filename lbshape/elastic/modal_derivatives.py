"""Modal derivatives (Barbič & James 2005): the second-order part of the basis.

For linear modes ψ_i, ψ_j the modal derivative Ψ_ij solves

    K Ψ_ij = −H(ψ_i, ψ_j),   H(a, b) = ∂³E/∂u³|₀ [a, b, ·],

with K the stiffness at rest and H the Hessian of the internal force
``f(u) = ∂E/∂u`` at rest (an n-vector for each pair of directions). Both are UFL
derivatives of the **StVK** energy with the given (E, ν, ρ), whatever the simulation
material: as in Barbič & James, the derivatives span the quadratic (StVK)
nonlinearity of the rest geometry. Both material models share K at rest.

H is compiled once as a linear form with two coefficient Functions (a, b) and
re-assembled per pair. Because E is a quartic polynomial of ∇u for StVK, f is cubic
and ``H(ψ, ψ) = (f(εψ) + f(−εψ))/ε²`` holds exactly for every ε.

Solving. One sparse Cholesky factorisation (PETSc KSP ``preonly`` + Cholesky with
MUMPS, options prefix ``md_``) serves every right-hand side.

* **Clamped body:** the system is restricted to the free DOFs; Ψ is zero at the
  fixed vertices.
* **Free body:** K is singular with the 6 rigid motions R (M-orthonormal, built
  analytically by :func:`lbshape.elastic.modes.rigid_body_modes`, so they span the
  null space of K exactly) as its null space. The right-hand side is projected,
  ``h ← (I − M R Rᵀ) h``, which makes ``K x = −h`` consistent; then 6 DOFs chosen by
  QR with column pivoting on Rᵀ (the rows of R that determine a rigid motion best)
  are pinned to zero, which selects one solution of the consistent singular system;
  finally rigid motion is removed, ``x ← x − R Rᵀ M x``, so that every Ψ_ij is
  M-orthogonal to the rigid modes.

Every solution is checked: ``‖K x + h‖ ≤ RESIDUAL_RTOL ‖h‖`` over the free DOFs (all
DOFs of a free body, so the equations of the pinned DOFs are checked too), else
:class:`~lbshape.errors.SolverError`. Serial: the modes must hold their vectors.
"""

from __future__ import annotations

import dataclasses
import logging
import time

import numpy as np
import scipy.linalg
import scipy.sparse as sp

from lbshape.elastic.materials import Material, strain_energy_ufl
from lbshape.elastic.modes import LinearModes, elastic_matrices, rigid_body_modes
from lbshape.errors import LbshapeError, SolverError
from lbshape.fem.dolfinx_bridge import (
    input_order_to_dofs,
    p1_dof_vertices,
    petsc_vec_to_input_order,
    to_dolfinx,
)
from lbshape.fem.eigenproblem import check_residuals
from lbshape.geometry.mesh import TetMesh

log = logging.getLogger(__name__)

#: PETSc options prefix of the derivative solver
OPTIONS_PREFIX = "md_"
#: accepted relative residual ``‖K x + h‖ / ‖h‖`` of each solve
RESIDUAL_RTOL = 1e-8


@dataclasses.dataclass(frozen=True)
class ModalDerivatives:
    """Modal derivatives Ψ_ij of a set of linear modes.

    Attributes:
        vectors: (3n, p) node-major, input vertex order; column q is Ψ for
            ``pairs[q]``. Zero at fixed DOFs; for a free body M-orthogonal to the
            rigid modes. Units: those of ``ψ_i ψ_j`` per metre (the modes are
            M-normalised; only the direction and relative size matter).
        pairs: (p, 2) int64 mode indices (i, j), 0-based into the linear modes.
        residuals: (p,) relative residuals ``‖KΨ + h‖ / ‖h‖`` over the free DOFs (every
            DOF of a free body; 0 where h = 0).
        seconds: wall-clock time.
    """

    vectors: np.ndarray
    pairs: np.ndarray
    residuals: np.ndarray
    seconds: float


class ForceHessian:
    """``H(a, b) = ∂³E/∂u³|₀ [a, b, ·]`` of the StVK energy on a mesh (serial).

    The UFL form is compiled once; each call re-assembles it for new directions.

    Args:
        mesh: the tetrahedral mesh (n vertices).
        material: (E, ν) are used with the StVK model, whatever ``material.model``.
    """

    def __init__(self, mesh: TetMesh, material: Material):
        import dolfinx.fem
        import ufl
        from mpi4py import MPI

        self.n_vertices = mesh.n_vertices
        self.material = stvk_material(material)
        msh = to_dolfinx(mesh, MPI.COMM_SELF)
        V = dolfinx.fem.VectorFunctionSpace(msh, ("Lagrange", 1))
        u = dolfinx.fem.Function(V)  # zero: the rest state
        self._a, self._b = dolfinx.fem.Function(V), dolfinx.fem.Function(V)
        v = ufl.TestFunction(V)
        force = ufl.derivative(strain_energy_ufl(self.material, u), u, v)
        hessian = ufl.derivative(ufl.derivative(force, u, self._a), u, self._b)
        self._form = dolfinx.fem.form(hessian)
        self._dof_vertices = p1_dof_vertices(V)

    def __call__(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """H(a, b) (3n,) in N/m² for node-major input-order displacements a, b (3n,) in m."""
        import dolfinx.fem

        for function, values in ((self._a, a), (self._b, b)):
            values = np.asarray(values, dtype=np.float64)
            if values.shape != (3 * self.n_vertices,):
                raise LbshapeError(f"direction must have shape ({3 * self.n_vertices},), "
                                   f"got {values.shape}")
            function.x.array[:] = input_order_to_dofs(values, self._dof_vertices, 3)
        assembled = dolfinx.fem.assemble_vector(self._form)
        return petsc_vec_to_input_order(np.array(assembled.array), self._dof_vertices, 3)


def stvk_material(material: Material) -> Material:
    """The StVK material with the same (E, ν, ρ)."""
    return dataclasses.replace(material, model="stvk")


def all_pairs(k: int) -> np.ndarray:
    """(k(k+1)/2, 2) int64 pairs (i, j), i ≤ j < k, row by row."""
    i, j = np.triu_indices(int(k))
    return np.column_stack([i, j]).astype(np.int64)


def modal_derivatives(
    mesh: TetMesh,
    material: Material,
    modes: LinearModes,
    *,
    pairs: np.ndarray | None = None,
) -> ModalDerivatives:
    """Modal derivatives of ``modes`` (serial; see the module docstring).

    Args:
        mesh: the mesh the modes were computed on (n vertices).
        material: (E, ν, ρ) of the modes; the StVK energy is used for K and H.
        modes: linear modes (k of them) with their fixed vertices.
        pairs: (p, 2) 0-based mode index pairs; default every i ≤ j < k.

    Returns:
        :class:`ModalDerivatives`.

    Raises:
        LbshapeError: modes from another mesh, or bad pairs.
        SolverError: the factorisation failed or a residual is too large.
    """
    started = time.perf_counter()
    n = mesh.n_vertices
    if modes.vectors is None or modes.vectors.shape[0] != 3 * n:
        shape = None if modes.vectors is None else modes.vectors.shape
        raise LbshapeError(f"the modes do not belong to this mesh: vectors {shape}, "
                           f"mesh has {n} vertices")
    pairs = _check_pairs(pairs, modes.count)
    stvk = stvk_material(material)
    fixed = np.asarray(modes.fixed_vertices, dtype=np.int64)
    with elastic_matrices(mesh, stvk, fixed_vertices=fixed, petsc=False) as mats:
        K, M, free_dofs = mats.stiffness, mats.mass, mats.free_dofs
    rigid = None if fixed.size else rigid_body_modes(mesh.points, M)
    solve_dofs = free_dofs if rigid is None else _unpinned_dofs(rigid)
    hessian = ForceHessian(mesh, stvk)

    p = pairs.shape[0]
    vectors, rhs = np.zeros((3 * n, p)), np.zeros((3 * n, p))
    Ks = K[solve_dofs][:, solve_dofs].tocsr()
    with _CholeskySolver(Ks) as solver:
        for q, (i, j) in enumerate(pairs):
            h = hessian(modes.vectors[:, i], modes.vectors[:, j])
            if rigid is not None:
                h -= M @ (rigid @ (rigid.T @ h))
            rhs[:, q] = -h
            if np.any(h[solve_dofs]):
                vectors[solve_dofs, q] = solver.solve(rhs[solve_dofs, q])
    if rigid is not None:
        vectors -= rigid @ (rigid.T @ (M @ vectors))
    # residuals on every equation that must hold (all DOFs of a free body)
    norms = np.linalg.norm(rhs[free_dofs], axis=0)
    misfit = np.linalg.norm((K @ vectors - rhs)[free_dofs], axis=0)
    residuals = np.divide(misfit, norms, out=np.zeros(p), where=norms > 0)
    check_residuals(residuals, RESIDUAL_RTOL, what="modal derivative solves",
                    describe=lambda q: f"pair {tuple(pairs[q])}")
    seconds = time.perf_counter() - started
    log.info("modal derivatives: n=%d pairs=%d free=%s max residual %.1e in %.2f s",
             n, pairs.shape[0], rigid is not None, residuals.max(initial=0.0), seconds)
    return ModalDerivatives(vectors=vectors, pairs=pairs, residuals=residuals, seconds=seconds)


def _check_pairs(pairs, k: int) -> np.ndarray:
    if pairs is None:
        return all_pairs(k)
    array = np.asarray(pairs)
    if array.size == 0:
        raise LbshapeError("pairs is empty: give at least one (i, j) pair")
    if array.ndim != 2 or array.shape[1] != 2 or not np.issubdtype(array.dtype, np.integer):
        raise LbshapeError(f"pairs must be an integer array of shape (p, 2), got {array.dtype} "
                           f"{array.shape}")
    if array.min() < 0 or array.max() >= k:
        raise LbshapeError(f"pair index out of range [0, {k}): {int(array.min())}.."
                           f"{int(array.max())}")
    return array.astype(np.int64)


def _unpinned_dofs(rigid: np.ndarray) -> np.ndarray:
    """All DOFs but the 6 that best determine a rigid motion (rows of R by pivoted QR)."""
    _, r, pivots = scipy.linalg.qr(rigid.T, mode="economic", pivoting=True)
    k = rigid.shape[1]
    pinned = pivots[:k]
    conditioning = abs(r[k - 1, k - 1] / r[0, 0])  # diagonal of the (k, 3n) factor
    if conditioning < 1e-8:  # pragma: no cover - needs a degenerate (collinear) body
        raise SolverError(f"cannot pin the rigid motions of this body (|r66/r11| = "
                          f"{conditioning:.1e})")
    keep = np.ones(rigid.shape[0], dtype=bool)
    keep[pinned] = False
    return np.flatnonzero(keep)


class _CholeskySolver:
    """One MUMPS Cholesky factorisation of a symmetric positive definite CSR matrix."""

    def __init__(self, A: sp.csr_matrix):
        from petsc4py import PETSc

        self._mat = PETSc.Mat().createAIJ(
            size=A.shape, comm=PETSc.COMM_SELF,
            csr=(A.indptr.astype(PETSc.IntType), A.indices.astype(PETSc.IntType), A.data))
        self._mat.assemble()
        self._ksp = PETSc.KSP().create(PETSc.COMM_SELF)
        self._ksp.setOptionsPrefix(OPTIONS_PREFIX)
        self._ksp.setOperators(self._mat)
        self._ksp.setType("preonly")
        pc = self._ksp.getPC()
        pc.setType("cholesky")
        pc.setFactorSolverType("mumps")
        self._ksp.setFromOptions()
        self._b, self._x = self._mat.createVecs()
        try:
            self._ksp.setUp()
        except PETSc.Error as exc:
            self.destroy()
            raise SolverError(f"Cholesky factorisation of the stiffness failed ({exc})") from None

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        self._b.setArray(rhs)
        self._ksp.solve(self._b, self._x)
        reason = self._ksp.getConvergedReason()
        if reason <= 0:
            raise SolverError(f"modal derivative solve failed (KSP reason {reason})")
        return self._x.getArray(readonly=True).copy()

    def destroy(self) -> None:
        for obj in ("_ksp", "_mat", "_b", "_x"):
            item = getattr(self, obj, None)
            if item is not None:
                item.destroy()
                setattr(self, obj, None)

    def __enter__(self) -> _CholeskySolver:
        return self

    def __exit__(self, *exc) -> None:
        self.destroy()
