"""Linear elastic vibration modes of a tetrahedral mesh (DOLFINx + SLEPc).

The tangent stiffness at rest ``K = ∂²E/∂u²|₀`` is the second UFL derivative of
:func:`lbshape.elastic.materials.strain_energy_ufl` (vector P1) and the mass is consistent,
``M = ∫ρ u·v``. Both materials linearise to the same isotropic linear elasticity, so
K does not depend on the material model. ``K ψ = ω² M ψ`` is solved with SLEPc
(GHEP, shift-and-invert, Cholesky with CHOLMOD serially and MUMPS over several ranks).

Choices:

* **Fixed vertices.** The eigenproblem is posed on the free DOFs only (PETSc
  submatrices of K and M); eigenvectors are extended by exact zeros at the fixed
  DOFs. There are no spurious eigenvalues to keep away and nothing to purify.
* **Target.** ``σ = -TARGET_FRACTION · (E/ρ) t²/D⁴`` with t the smallest extent and D
  the diagonal of the bounding box: ``(E/ρ) t²/L⁴`` is the order of the lowest
  bending ω² of beams and plates, so σ lies below the spectrum at about a tenth of
  ω₁². ``K - σM`` is symmetric positive definite for every σ < 0 (K ⪰ 0, M ≻ 0):
  a free body's singular K is never factored.
* **Rigid modes.** Pairs with ``|ω²| ≤ RIGID_RTOL · ω²_e`` are rigid, ω²_e being the
  smallest computed ω² above ``RIGID_RTOL · max ω²`` (the first elastic one). A free
  body must have exactly 6 (3 translations, 3 rotations), else
  :class:`~lbshape.errors.SolverError` (several bodies, a broken K); a clamped body
  must have none, else :class:`~lbshape.errors.LbshapeError` (the fixed vertices do
  not stop rigid motion, e.g. one vertex or a line of vertices).
* **Checks.** ``getConverged()`` against the request; relative residuals
  ``‖Kψ − ω²Mψ‖ / (|ω²|‖Mψ‖ + ‖Kψ‖)`` on the free DOFs ≤ ``RESIDUAL_FACTOR · tol``;
  rigid modes ``‖Kr‖ ≤ RIGID_RTOL · ω²_e ‖Mr‖``; no ω² below ``-RIGID_RTOL · ω²_e``.
* **Normalisation.** Rigid and elastic vectors together are made exactly
  M-orthonormal by the symmetric (Löwdin) orthonormalisation, and each elastic
  mode's sign follows the rule of :mod:`lbshape.spectral.spectrum`.

PETSc options with the prefix ``elastic_`` (e.g. ``-elastic_eps_ncv 60``) override
these defaults.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from mpi4py import MPI

from lbshape.elastic.materials import Material, strain_energy_ufl
from lbshape.errors import LbshapeError, SolverError
from lbshape.fem.dolfinx_bridge import dof_to_input_order, p1_dof_vertices, to_dolfinx
from lbshape.fem.eigenproblem import (
    b_orthonormalise,
    check_residuals,
    check_tol_and_target,
    converged_pairs,
    factor_package,
    fix_signs,
    relative_residuals,
    shift_invert_eps,
)
from lbshape.fem.mpi import compute_on_root
from lbshape.fem.petsc_gather import gather_csr, gather_rows
from lbshape.geometry.mesh import TetMesh, free_dof_mask

log = logging.getLogger(__name__)

#: PETSc/SLEPc options prefix of the elastic eigensolver
OPTIONS_PREFIX = "elastic_"
#: the target is ``-TARGET_FRACTION (E/ρ) t²/D⁴``
TARGET_FRACTION = 0.1
#: ``|ω²| ≤ RIGID_RTOL ω²_e`` counts as a rigid mode
RIGID_RTOL = 1e-6
#: accepted relative residual is ``RESIDUAL_FACTOR * tol``
RESIDUAL_FACTOR = 100.0
#: rigid modes of a free body in 3D
FREE_BODY_RIGID_MODES = 6


@dataclasses.dataclass(frozen=True)
class ElasticMatrices:
    """Stiffness and mass of linear elasticity at rest; owner of the PETSc copies.

    Use as a context manager, or call :meth:`destroy`.

    Attributes:
        stiffness: (3n, 3n) scipy CSR ``K`` in N/m, node-major in input vertex order,
            without constraints (``None`` off rank 0).
        mass: (3n, 3n) scipy CSR consistent mass ``M`` in kg (``None`` off rank 0).
        fixed_vertices: (f,) sorted input indices of the fixed vertices (all ranks).
        free_dofs: (3n − 3f,) sorted node-major input indices of the free DOFs.
        stiffness_petsc: ``PETSc.Mat`` K restricted to the free DOFs (DOLFINx dof
            order, distributed over ``comm``), or ``None`` if not requested.
        mass_petsc: ``PETSc.Mat`` M restricted to the free DOFs, or ``None``.
        local_rows: (local rows,) node-major input index of each local row of the
            PETSc matrices.
        n_vertices: global number of vertices n.
        comm: the communicator.
        space: the DOLFINx vector P1 ``FunctionSpace`` the matrices were assembled on
            (its owned dofs, minus the fixed ones, are the local rows).
        owned_free: (3 · owned vertices,) bool, which owned dof rows (DOLFINx order)
            are free: ``local_rows`` are the input indices of those rows.
    """

    stiffness: sp.csr_matrix | None
    mass: sp.csr_matrix | None
    fixed_vertices: np.ndarray
    free_dofs: np.ndarray
    stiffness_petsc: object | None
    mass_petsc: object | None
    local_rows: np.ndarray
    n_vertices: int
    comm: MPI.Comm
    space: object | None = None
    owned_free: np.ndarray | None = None

    def destroy(self) -> None:
        """Destroy the PETSc matrices (idempotent)."""
        for mat in (self.stiffness_petsc, self.mass_petsc):
            if mat is not None:
                mat.destroy()

    def __enter__(self) -> ElasticMatrices:
        return self

    def __exit__(self, *exc) -> None:
        self.destroy()


@dataclasses.dataclass(frozen=True)
class LinearModes:
    """The lowest non-rigid vibration modes ``K ψ = ω² M ψ``.

    In parallel the n-sized fields are on rank 0 only (``None`` elsewhere).

    Attributes:
        omega2: (k,) ascending squared angular frequencies ω² in rad²/s², all > 0.
        frequencies_hz: (k,) ``√ω² / 2π`` in Hz.
        vectors: (3n, k) node-major, input vertex order, M-orthonormal, exact zeros
            at the DOFs of fixed vertices.
        n_rigid: number of rigid modes (6 for a free body, 0 for a clamped one).
        rigid: (3n, n_rigid) M-orthonormal rigid modes, M-orthogonal to ``vectors``.
        fixed_vertices: (f,) sorted input indices of the fixed vertices (all ranks).
        residuals: (k,) relative residuals on the free DOFs (all ranks).
        rigid_omega2: (n_rigid,) the computed ω² of the rigid modes (≈ 0), rad²/s².
        target: the shift-and-invert target σ in rad²/s².
        stiffness: (3n, 3n) scipy CSR K without constraints, N/m.
        mass: (3n, 3n) scipy CSR consistent mass M, kg.
        seconds: wall-clock time of assembly and solve.
    """

    omega2: np.ndarray
    frequencies_hz: np.ndarray
    vectors: np.ndarray | None
    n_rigid: int
    rigid: np.ndarray | None
    fixed_vertices: np.ndarray
    residuals: np.ndarray
    rigid_omega2: np.ndarray
    target: float
    stiffness: sp.csr_matrix | None
    mass: sp.csr_matrix | None
    seconds: float

    @property
    def count(self) -> int:
        """Number k of elastic modes."""
        return int(self.omega2.size)


def elastic_matrices(
    mesh: TetMesh,
    material: Material,
    *,
    fixed_vertices: np.ndarray | None = None,
    comm: MPI.Comm = MPI.COMM_SELF,
    petsc: bool = True,
) -> ElasticMatrices:
    """Assemble K at rest and the consistent mass M with DOLFINx (vector P1).

    Args:
        mesh: a checked tetrahedral mesh with n vertices (rank 0's copy is used).
        material: any :class:`~lbshape.elastic.materials.Material`; K is its linearisation.
        fixed_vertices: (f,) input indices of vertices whose three DOFs are fixed;
            ``None`` or empty for a free body (rank 0's copy is used).
        comm: the communicator; serial by default.
        petsc: also keep the PETSc free-DOF matrices (for SLEPc); ``False`` destroys
            them after conversion.

    Returns:
        :class:`ElasticMatrices`; the caller destroys it.

    Raises:
        LbshapeError: fixed vertex indices out of range, or every vertex fixed.
    """
    import dolfinx.fem
    import dolfinx.fem.petsc
    import ufl
    from petsc4py import PETSc

    n, fixed = compute_on_root(comm, lambda: (mesh.n_vertices,
                                              _check_fixed(fixed_vertices, mesh.n_vertices)))

    msh = to_dolfinx(mesh, comm)
    V = dolfinx.fem.VectorFunctionSpace(msh, ("Lagrange", 1))
    u = dolfinx.fem.Function(V)  # zero: the rest state
    v, du = ufl.TestFunction(V), ufl.TrialFunction(V)
    energy = strain_energy_ufl(material, u)
    k_form = ufl.derivative(ufl.derivative(energy, u, v), u, du)
    m_form = material.density * ufl.inner(du, v) * ufl.dx
    K = dolfinx.fem.petsc.assemble_matrix(dolfinx.fem.form(k_form))
    K.assemble()
    M = dolfinx.fem.petsc.assemble_matrix(dolfinx.fem.form(m_form))
    M.assemble()

    n_owned = V.dofmap.index_map.size_local
    owned_rows = dof_to_input_order(p1_dof_vertices(V)[:n_owned], 3)
    K_csr, M_csr = (gather_csr(A, owned_rows, comm=comm, size=3 * n) for A in (K, M))

    free_mask = free_dof_mask(n, fixed)
    free_dofs = np.flatnonzero(free_mask)
    local_free = free_mask[owned_rows]
    local_rows = owned_rows[local_free]
    K_free = M_free = None
    if petsc:
        if fixed.size:
            start = K.getOwnershipRange()[0]
            index_set = PETSc.IS().createGeneral(
                (start + np.flatnonzero(local_free)).astype(PETSc.IntType), comm=comm)
            try:
                K_free = K.createSubMatrix(index_set, index_set)
                M_free = M.createSubMatrix(index_set, index_set)
            finally:
                index_set.destroy()
        else:
            K_free, M_free = K, M
    if K_free is not K:
        K.destroy()
        M.destroy()
    return ElasticMatrices(
        stiffness=K_csr, mass=M_csr, fixed_vertices=fixed, free_dofs=free_dofs,
        stiffness_petsc=K_free, mass_petsc=M_free, local_rows=local_rows,
        n_vertices=n, comm=comm, space=V, owned_free=local_free,
    )


def _check_fixed(fixed_vertices, n: int) -> np.ndarray:
    """Validated, sorted, unique fixed vertex indices (f,) int64."""
    if fixed_vertices is None:
        return np.empty(0, dtype=np.int64)
    fixed = np.asarray(fixed_vertices)
    if fixed.size == 0:
        return np.empty(0, dtype=np.int64)
    if fixed.ndim != 1 or not np.issubdtype(fixed.dtype, np.integer):
        raise LbshapeError(f"fixed_vertices must be a 1-D integer array, got {fixed.dtype} "
                           f"of shape {fixed.shape}")
    if fixed.min() < 0 or fixed.max() >= n:
        raise LbshapeError(f"fixed vertex index out of range [0, {n}): "
                           f"{int(fixed.min())}..{int(fixed.max())}")
    fixed = np.unique(fixed.astype(np.int64))
    if fixed.size == n:
        raise LbshapeError("every vertex is fixed: nothing can move")
    return fixed


def default_target(mesh: TetMesh, material: Material) -> float:
    """``-TARGET_FRACTION (E/ρ) t²/D⁴`` in rad²/s² (see the module docstring)."""
    extent = np.ptp(np.asarray(mesh.points), axis=0)
    diagonal, thinnest = float(np.linalg.norm(extent)), float(extent.min())
    if not thinnest > 0.0:
        raise LbshapeError("mesh is flat (zero extent along an axis); cannot compute modes")
    return -TARGET_FRACTION * material.young / material.density * thinnest**2 / diagonal**4


def rigid_body_modes(points: np.ndarray, mass: sp.spmatrix) -> np.ndarray:
    """M-orthonormal basis (3n, 6) of the infinitesimal rigid motions of ``points``.

    Translations ``e_c`` and rotations ``e_c × (x − x̄)`` (x̄ the vertex centroid),
    node-major, made M-orthonormal with a Cholesky factor of their Gram matrix.

    Args:
        points: (n, 3) vertex positions in metres.
        mass: (3n, 3n) symmetric positive definite mass matrix.
    """
    points = np.asarray(points, dtype=np.float64)
    n = points.shape[0]
    r = points - points.mean(axis=0)
    fields = np.zeros((n, 3, 6))
    for c in range(3):
        fields[:, c, c] = 1.0
        axis = np.zeros(3)
        axis[c] = 1.0
        fields[:, :, 3 + c] = np.cross(axis, r)
    R = fields.reshape(3 * n, 6)
    gram = R.T @ (mass @ R)
    L = np.linalg.cholesky(0.5 * (gram + gram.T))
    return np.linalg.solve(L, R.T).T


def linear_modes(
    mesh: TetMesh,
    material: Material,
    count: int,
    *,
    fixed_vertices: np.ndarray | None = None,
    comm: MPI.Comm = MPI.COMM_SELF,
    tol: float = 1e-10,
    target: float | None = None,
) -> LinearModes:
    """The ``count`` lowest non-rigid modes of ``mesh`` (see the module docstring).

    Args:
        mesh: a checked, connected tetrahedral mesh with n vertices.
        material: material parameters (E, ν, ρ); the model does not matter at rest.
        count: number k ≥ 1 of elastic (non-rigid) modes.
        fixed_vertices: (f,) input indices of clamped vertices; ``None`` or empty for
            a free body (whose 6 rigid modes are found and returned separately).
        comm: the communicator (``MPI.COMM_WORLD`` to run distributed).
        tol: SLEPc relative tolerance; residuals must be ≤ ``RESIDUAL_FACTOR * tol``.
        target: shift-and-invert target σ < 0 in rad²/s²; default
            :func:`default_target`.

    Returns:
        :class:`LinearModes`; in parallel the n-sized fields are on rank 0 only.

    Raises:
        LbshapeError: bad ``count`` (too large for the mesh), ``tol``, ``target`` or
            fixed vertices, or fixed vertices that leave rigid motions free.
        SolverError: too few converged pairs, large residuals, negative ω², or not
            exactly 6 rigid modes for a free body.
    """
    started = time.perf_counter()
    request = _checked_request(mesh, material, count, fixed_vertices=fixed_vertices, comm=comm,
                               tol=tol, target=target)
    sigma, n, fixed = request.sigma, request.n_vertices, request.fixed
    with elastic_matrices(mesh, material, fixed_vertices=fixed, comm=comm) as mats:
        values, local, tol = _solve_eigenproblem(mats, request.nev, sigma, tol)
        n_rigid, scale = _count_rigid(values)
        _check_rigid_count(n_rigid, request.n_rigid, values, scale)
        vectors = gather_rows(local, mats.local_rows, comm=comm, size=3 * n)
    omega2 = values[n_rigid:request.nev]
    rigid, elastic = compute_on_root(
        comm, lambda: _split_orthonormal(vectors[:, :request.nev], mats.mass, n_rigid),
        share=False) or (None, None)
    residuals, rigid_residual = compute_on_root(
        comm, lambda: _free_dof_residuals(mats, omega2, elastic, rigid))
    _check_residuals(omega2, residuals, rigid_residual, limit=RESIDUAL_FACTOR * tol,
                     scale=scale)
    seconds = time.perf_counter() - started
    log.info("elastic modes: n=%d fixed=%d k=%d rigid=%d target=%.3e f_1=%.6g Hz in %.2f s",
             n, fixed.size, count, n_rigid, sigma, math.sqrt(omega2[0]) / (2 * math.pi),
             seconds)
    return LinearModes(
        omega2=omega2, frequencies_hz=np.sqrt(omega2) / (2.0 * math.pi), vectors=elastic,
        n_rigid=n_rigid, rigid=rigid, fixed_vertices=fixed, residuals=residuals,
        rigid_omega2=values[:n_rigid], target=sigma, stiffness=mats.stiffness, mass=mats.mass,
        seconds=seconds,
    )


class _Request(NamedTuple):
    """A validated :func:`linear_modes` request (the same on every rank).

    sigma: target in rad²/s²; n_vertices: n; fixed: (f,) sorted fixed vertices;
    n_rigid: rigid modes expected (6 free, 0 clamped); nev: pairs to compute.
    """

    sigma: float
    n_vertices: int
    fixed: np.ndarray
    n_rigid: int
    nev: int


def _checked_request(mesh: TetMesh, material: Material, count, *, fixed_vertices, comm,
                     tol: float, target: float | None) -> _Request:
    """Validate the arguments of :func:`linear_modes` (mesh-dependent parts on rank 0)."""
    check_tol_and_target(tol, target)
    sigma, n, fixed = compute_on_root(comm, lambda: (
        default_target(mesh, material) if target is None else float(target),
        mesh.n_vertices, _check_fixed(fixed_vertices, mesh.n_vertices)))
    expected_rigid = 0 if fixed.size else FREE_BODY_RIGID_MODES
    n_free = 3 * (n - fixed.size)
    if isinstance(count, bool) or not isinstance(count, int | np.integer) or count < 1:
        raise LbshapeError(f"the number of modes must be an integer >= 1, got {count!r}")
    if count + expected_rigid >= n_free:
        raise LbshapeError(
            f"{count} modes are too many for a mesh with {n_free} free DOFs: need "
            f"count + {expected_rigid} rigid < {n_free}"
        )
    return _Request(sigma, n, fixed, expected_rigid, int(count) + expected_rigid)


def _split_orthonormal(vectors: np.ndarray, mass: sp.spmatrix,
                       n_rigid: int) -> tuple[np.ndarray, np.ndarray]:
    """(rigid (3n, n_rigid), elastic (3n, k)) from the M-orthonormalised (3n, nev) block;
    elastic signs fixed."""
    vectors = b_orthonormalise(vectors, mass, what="elastic mode vectors")
    return vectors[:, :n_rigid], fix_signs(vectors[:, n_rigid:])


def _free_dof_residuals(mats: ElasticMatrices, omega2: np.ndarray, elastic: np.ndarray,
                        rigid: np.ndarray) -> tuple[np.ndarray, float | None]:
    """Relative residuals (k,) of the elastic pairs on the free DOFs, and the rigid modes'
    ``max ‖Kr‖/‖Mr‖`` in rad²/s² (``None`` without rigid modes)."""
    Kf, Mf = mats.stiffness[mats.free_dofs], mats.mass[mats.free_dofs]
    residuals = relative_residuals(Kf, Mf, omega2, elastic)
    if not rigid.shape[1]:
        return residuals, None
    return residuals, float(np.max(np.linalg.norm(Kf @ rigid, axis=0)
                                   / np.linalg.norm(Mf @ rigid, axis=0)))


def _check_residuals(omega2: np.ndarray, residuals: np.ndarray, rigid_residual: float | None,
                     *, limit: float, scale: float) -> None:
    """Elastic residuals ≤ ``limit``; rigid ``‖Kr‖/‖Mr‖ ≤ RIGID_RTOL · scale``.

    ``scale`` is the first elastic ω² in rad²/s².
    """
    check_residuals(residuals, limit, what="elastic eigenpairs",
                    describe=lambda i: f"mode {i + 1}, omega^2={omega2[i]:.6e}")
    if rigid_residual is not None and rigid_residual > RIGID_RTOL * scale:
        raise SolverError(
            f"rigid modes are not in the null space of K: max |Kr|/|Mr| = {rigid_residual:.3e} "
            f"> {RIGID_RTOL:g} x first elastic omega^2 {scale:.3e}"
        )


def _solve_eigenproblem(mats: ElasticMatrices, nev: int, sigma: float,
                        tol: float) -> tuple[np.ndarray, np.ndarray, float]:
    """The ``nev`` pairs nearest σ: ascending values (nev,), local vectors (l, nev) and
    the tolerance used (``tol`` unless overridden by the options)."""

    eps = shift_invert_eps(mats.stiffness_petsc, mats.mass_petsc, comm=mats.comm,
                           prefix=OPTIONS_PREFIX, nev=nev, sigma=sigma, tol=tol,
                           factor=factor_package(mats.comm))
    try:
        eps.setFromOptions()
        tol = eps.getTolerances()[0]  # as overridden by -elastic_eps_tol, if given
        eps.solve()
        values, local = converged_pairs(eps, nev=nev, what="elastic eigensolver", tol=tol,
                                        sigma=sigma)
    finally:
        eps.destroy()
    # SLEPc may converge more pairs than asked; the nev nearest σ are the smallest
    order = np.argsort(values)[:nev]
    return values[order], local[:, order], tol


def _count_rigid(values: np.ndarray) -> tuple[int, float]:
    """(number of rigid values at the start of ascending ``values``, first elastic ω²)."""
    big = values > RIGID_RTOL * np.max(np.abs(values))
    if not big.any():
        raise SolverError(f"no elastic eigenvalue found among {values.size} computed "
                          f"(largest |omega^2| {np.max(np.abs(values)):.3e})")
    scale = float(values[big][0])
    negative = values < -RIGID_RTOL * scale
    if negative.any():
        raise SolverError(
            f"negative omega^2 {values[negative][0]:.3e} (first elastic {scale:.3e}): "
            "the stiffness matrix is not positive semi-definite"
        )
    rigid = np.abs(values) <= RIGID_RTOL * scale
    n_rigid = int(rigid.sum())
    if not rigid[:n_rigid].all():  # pragma: no cover - values are sorted
        raise SolverError("rigid eigenvalues are not the smallest")
    return n_rigid, scale


def _check_rigid_count(n_rigid: int, expected: int, values: np.ndarray, scale: float) -> None:
    if n_rigid == expected:
        return
    shown = ", ".join(f"{v:.3e}" for v in values[: max(n_rigid, expected) + 1])
    if expected == 0:
        raise LbshapeError(
            f"the fixed vertices do not prevent rigid motion: {n_rigid} zero-frequency modes "
            f"(|omega^2| <= {RIGID_RTOL:g} x {scale:.3e}); fix at least 3 non-collinear "
            f"vertices (smallest omega^2: {shown})"
        )
    raise SolverError(
        f"a free body must have exactly {expected} rigid modes, found {n_rigid} with "
        f"|omega^2| <= {RIGID_RTOL:g} x {scale:.3e} (smallest omega^2: {shown})"
        + ("; several disconnected bodies?" if n_rigid > expected else "")
    )
