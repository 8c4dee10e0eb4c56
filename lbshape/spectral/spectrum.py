"""The Laplace-Beltrami (LB) spectrum of a tetrahedral mesh (DOLFINx + SLEPc).

The volumetric LB operator with natural (Neumann) boundary conditions is
discretised with P1 elements: stiffness ``K = ∫ ∇φ·∇ψ`` and *consistent* mass
``M = ∫ φψ``. The generalized problem ``K φ = λ M φ`` is solved with SLEPc (GHEP,
Krylov-Schur, shift-and-invert at a small negative target, sparse Cholesky).

Scale convention: eigenpairs are those of the mesh **as given** — nothing is
rescaled here. Eigenvalues are in 1/m² and scale as ``λ(sΩ) = λ(Ω)/s²``;
M-orthonormal eigenvectors (``φᵀ M φ = 1`` with M in m³) scale as ``s^(-3/2)``.
The shape space normalises volume before comparing shapes; that happens there,
not in this module.

Choices:

* **Target.** ``σ = -0.01 (π/D)²`` with D the diagonal of the bounding box. For a
  convex body the Payne-Weinberger inequality gives ``λ₁ ≥ (π/d)²`` with d the
  diameter ≤ D, so σ lies below the spectrum at a hundredth of the distance to λ₁;
  ``K - σM`` is then symmetric positive definite and its Cholesky factor exists.
  For non-convex bodies λ₁ is smaller but still positive, and any negative σ works.
* **Zero mode.** ``m + 1`` pairs are computed; exactly one eigenvalue must satisfy
  ``|λ| ≤ ZERO_RTOL (π/D)²`` (the constant mode). Several mean several disconnected
  bodies, and an error is raised. The constant mode is dropped.
* **Completeness.** Single-vector Krylov methods may miss further copies of an
  *exactly* repeated eigenvalue (meshes with exact symmetries, e.g. a structured
  cube: 10 of 180 small cases did before this check). With ``verify=True`` (default)
  the number of eigenvalues below a threshold τ just above the (m+1)-th is counted
  from the inertia of ``K − τM = LDLᵀ`` (MUMPS); missed pairs are computed by a
  second solve deflated against the found ones. Cost: one LDLᵀ factorisation
  (about 4 s at 100k vertices); ``verify=False`` skips it.
* **Checks.** ``getConverged() ≥ m + 1`` and, for every returned pair, the relative
  residual ``‖Kφ − λMφ‖ / (|λ| ‖Mφ‖ + ‖Kφ‖) ≤ RESIDUAL_FACTOR · tol``; otherwise
  :class:`~lbshape.errors.SolverError` with the observed numbers.
* **Normalisation.** The returned block is made exactly M-orthonormal by the
  symmetric (Löwdin) orthonormalisation ``Φ (ΦᵀMΦ)^(-1/2)``, the smallest change
  of Φ that does so; it matters inside (near-)degenerate clusters.
* **Sign.** Each eigenvector is made positive at the first vertex (input order)
  where ``|φ| ≥ (1 − SIGN_RTOL) max|φ|``: the vertex of largest magnitude, with
  round-off ties between symmetric vertices broken by vertex index.

* **Factorisation.** Serial: CHOLMOD (SuiteSparse) when PETSc has it, else MUMPS;
  parallel: MUMPS. At 100k vertices (2 x 1 x 1 box, m = 30) the ~108 solves of
  Krylov-Schur dominate: CHOLMOD factor 3.9 s + 60 ms/solve, MUMPS (no METIS in this
  PETSc build) 3.8 s + 100 ms/solve, PETSc's own Cholesky 10x slower. Eigenvector
  purification is off (M is positive definite; it would cost one solve per vector).
  See ``scripts/bench_eigen.py``.

PETSc options with the prefix ``lb_`` (e.g. ``-lb_eps_ncv 80``,
``-lb_st_pc_factor_mat_solver_type mumps``) override these defaults.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time

import numpy as np
import scipy.sparse as sp
from mpi4py import MPI

from lbshape.errors import LbshapeError, SolverError
from lbshape.fem.dolfinx_bridge import p1_dof_vertices, to_dolfinx
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
from lbshape.geometry.mesh import TetMesh

log = logging.getLogger(__name__)

#: seed of the eigensolver's start vector (deterministic eigenvectors)
START_SEED = 1234
#: PETSc/SLEPc options prefix of the LB eigensolver
OPTIONS_PREFIX = "lb_"
#: the target is ``-TARGET_FRACTION (π/D)²``
TARGET_FRACTION = 0.01
#: eigenvalues with ``|λ| ≤ ZERO_RTOL (π/D)²`` count as zero
ZERO_RTOL = 1e-6
#: accepted relative residual is ``RESIDUAL_FACTOR * tol``
RESIDUAL_FACTOR = 100.0
#: rounds of the inertia check and deflated re-solve before giving up
MAX_COMPLETION_ROUNDS = 4
#: computed eigenvalues closer than this (relative) are one cluster for the inertia check
CLUSTER_RTOL = 1e-6
#: relative margin for the sign rule (see the module docstring)


@dataclasses.dataclass(frozen=True)
class LBSpectrum:
    """The m smallest non-zero LB eigenpairs of a mesh (constant mode excluded).

    Attributes:
        eigenvalues: (m,) ascending, in 1/m², all > 0.
        eigenvectors: (n, m) in input vertex order, M-orthonormal
            (``ΦᵀMΦ = I``), sign fixed as in the module docstring. In parallel
            only rank 0 holds it; other ranks hold ``None``.
        stiffness: (n, n) scipy CSR ``K`` in input vertex order (``None`` off rank 0).
        mass: (n, n) scipy CSR consistent mass ``M`` in m³ (``None`` off rank 0).
        residuals: (m,) relative residuals ``‖Kφ−λMφ‖ / (|λ|‖Mφ‖ + ‖Kφ‖)``
            (all ranks).
        zero_eigenvalue: the dropped eigenvalue of the constant mode (≈ 0), in 1/m².
        target: the shift-and-invert target σ used, in 1/m².
        seconds: wall-clock time of assembly and solve.
    """

    eigenvalues: np.ndarray
    eigenvectors: np.ndarray | None
    stiffness: sp.csr_matrix | None
    mass: sp.csr_matrix | None
    residuals: np.ndarray
    zero_eigenvalue: float
    target: float
    seconds: float


class LBMatrices:
    """Owner of the assembled PETSc stiffness ``K`` and mass ``M`` (P1, Neumann).

    Use as a context manager, or call :meth:`destroy`. The matrices are in DOLFINx
    dof order (distributed over ``comm``); :meth:`to_scipy` converts to input
    vertex order.

    Attributes:
        stiffness: ``petsc4py.PETSc.Mat`` K.
        mass: ``petsc4py.PETSc.Mat`` M.
        space: the DOLFINx P1 ``FunctionSpace``.
        owned_vertices: (n_owned,) input vertex index of each owned dof.
        n_vertices: global number of vertices n.
        eigenvalue_scale: ``(π/D)²`` in 1/m², D the bounding-box diagonal.
    """

    def __init__(self, stiffness, mass, space, *, n_vertices: int, eigenvalue_scale: float):
        self.stiffness = stiffness
        self.mass = mass
        self.space = space
        self.n_vertices = int(n_vertices)
        self.eigenvalue_scale = float(eigenvalue_scale)
        imap = space.dofmap.index_map
        self.owned_vertices = p1_dof_vertices(space)[: imap.size_local]

    @property
    def comm(self) -> MPI.Comm:
        return self.space.mesh.comm

    def to_scipy(self) -> tuple[sp.csr_matrix, sp.csr_matrix] | tuple[None, None]:
        """(K, M) as (n, n) scipy CSR in input vertex order, on rank 0 (``None`` elsewhere)."""
        return tuple(gather_csr(A, self.owned_vertices, comm=self.comm, size=self.n_vertices)
                     for A in (self.stiffness, self.mass))

    def gather_columns(self, local: np.ndarray) -> np.ndarray | None:
        """Owned dof rows (n_owned, k) from every rank -> (n, k) input order on rank 0."""
        return gather_rows(local, self.owned_vertices, comm=self.comm, size=self.n_vertices)

    def destroy(self) -> None:
        """Destroy the PETSc matrices (idempotent)."""
        for mat in (self.stiffness, self.mass):
            if mat is not None:
                mat.destroy()
        self.stiffness = self.mass = None

    def __enter__(self) -> LBMatrices:
        return self

    def __exit__(self, *exc) -> None:
        self.destroy()


def eigenvalue_scale(mesh: TetMesh) -> float:
    """``(π/D)²`` in 1/m², D the bounding-box diagonal: ≤ λ₁ for convex bodies."""
    diagonal = float(np.linalg.norm(np.ptp(np.asarray(mesh.points), axis=0)))
    if not diagonal > 0.0:
        raise LbshapeError("mesh has zero extent; cannot compute its LB spectrum")
    return (math.pi / diagonal) ** 2


def lb_matrices(mesh: TetMesh, *, comm: MPI.Comm = MPI.COMM_SELF) -> LBMatrices:
    """Assemble the P1 LB stiffness and consistent mass matrices with DOLFINx.

    Args:
        mesh: a checked tetrahedral mesh (rank 0's copy is distributed).
        comm: the communicator; serial by default.

    Returns:
        :class:`LBMatrices` owning K (1/m² · m³ = m) and M (m³); the caller destroys it.
    """
    import dolfinx.fem
    import dolfinx.fem.petsc
    import ufl

    n, scale = compute_on_root(comm, lambda: (mesh.n_vertices, eigenvalue_scale(mesh)))
    msh = to_dolfinx(mesh, comm)
    V = dolfinx.fem.FunctionSpace(msh, ("Lagrange", 1))
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    K = dolfinx.fem.petsc.assemble_matrix(dolfinx.fem.form(ufl.inner(ufl.grad(u), ufl.grad(v))
                                                           * ufl.dx))
    K.assemble()
    M = dolfinx.fem.petsc.assemble_matrix(dolfinx.fem.form(ufl.inner(u, v) * ufl.dx))
    M.assemble()
    return LBMatrices(K, M, V, n_vertices=n, eigenvalue_scale=scale)


def lb_matrices_csr(mesh: TetMesh) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """Serial helper: (K, M) as (n, n) scipy CSR in input vertex order."""
    with lb_matrices(mesh, comm=MPI.COMM_SELF) as mats:
        return mats.to_scipy()


def lb_spectrum(
    mesh: TetMesh,
    m: int,
    *,
    comm: MPI.Comm = MPI.COMM_SELF,
    tol: float = 1e-10,
    target: float | None = None,
    verify: bool = True,
) -> LBSpectrum:
    """The m smallest non-zero LB eigenpairs of ``mesh`` as given (no rescaling).

    Args:
        mesh: a checked, connected tetrahedral mesh with n vertices.
        m: number of non-constant eigenpairs, an int with ``1 ≤ m`` and ``m + 1 < n``.
        comm: the communicator (``MPI.COMM_WORLD`` to run distributed).
        tol: SLEPc relative tolerance; residuals must be ≤ ``RESIDUAL_FACTOR * tol``.
        target: shift-and-invert target σ < 0 in 1/m²; default ``-0.01 (π/D)²``.
        verify: check with an inertia count that no eigenvalue was missed (see the
            module docstring) and compute missed ones.

    Returns:
        :class:`LBSpectrum`; in parallel the n-sized fields are on rank 0 only.

    Raises:
        LbshapeError: bad ``m``, ``tol`` or ``target``.
        SolverError: too few converged pairs, large residuals, eigenvalues still
            missing after the completion rounds, or not exactly one zero eigenvalue
            (a mesh of several disconnected bodies).
    """
    started = time.perf_counter()
    n = compute_on_root(comm, lambda: mesh.n_vertices)
    _check_request(m, n, tol, target)
    with lb_matrices(mesh, comm=comm) as mats:
        result = lb_spectrum_from_matrices(mats, m, tol=tol, target=target, verify=verify)
    seconds = time.perf_counter() - started
    return dataclasses.replace(result, seconds=seconds)


def _check_request(m, n: int, tol: float, target: float | None) -> None:
    if isinstance(m, bool) or not isinstance(m, int | np.integer) or m < 1:
        raise LbshapeError(f"m must be an integer >= 1, got {m!r}")
    if m + 1 >= n:
        raise LbshapeError(
            f"m={m} is too large for a mesh with {n} vertices: need m + 1 < {n}"
        )
    check_tol_and_target(tol, target)


def lb_spectrum_from_matrices(
    mats: LBMatrices,
    m: int,
    *,
    tol: float = 1e-10,
    target: float | None = None,
    verify: bool = True,
) -> LBSpectrum:
    """Solve ``Kφ = λMφ`` for assembled matrices (see :func:`lb_spectrum`).

    ``seconds`` of the result is the time of this solve alone (no assembly).
    """
    started = time.perf_counter()
    comm = mats.comm
    _check_request(m, mats.n_vertices, tol, target)
    sigma = -TARGET_FRACTION * mats.eigenvalue_scale if target is None else float(target)
    nev = int(m) + 1

    run = _krylov_schur(mats, nev, sigma, tol)
    if verify:
        run = _complete_by_inertia(mats, run, nev, sigma)
    values, local = run.values[:nev], run.local[:, :nev]
    _check_single_zero(values, mats.eigenvalue_scale)
    zero_eigenvalue = float(values[0])
    values, local = values[1:], local[:, 1:]

    K, M = mats.to_scipy()
    vectors = mats.gather_columns(local)
    vectors = compute_on_root(
        comm, lambda: fix_signs(b_orthonormalise(vectors, M, what="LB eigenvectors")), share=False)
    residuals = compute_on_root(comm, lambda: relative_residuals(K, M, values, vectors))
    check_residuals(residuals, RESIDUAL_FACTOR * run.tol, what="LB eigenpairs",
                    describe=lambda i: f"pair {i + 1}, lambda={values[i]:.6e}")
    seconds = time.perf_counter() - started
    log.info("LB spectrum: n=%d m=%d target=%.3e %s lambda_1=%.6e lambda_m=%.6e in %.2f s",
             mats.n_vertices, m, sigma, run.info, values[0], values[-1], seconds)
    return LBSpectrum(
        eigenvalues=values, eigenvectors=vectors, stiffness=K, mass=M,
        residuals=residuals, zero_eigenvalue=zero_eigenvalue, target=sigma, seconds=seconds,
    )


@dataclasses.dataclass(frozen=True)
class _Run:
    """Converged pairs of one or more Krylov-Schur solves, ascending.

    values: (k,); local: (n_owned, k) owned dof rows; tol: the effective tolerance.
    """

    values: np.ndarray
    local: np.ndarray
    tol: float
    info: str

    def merged(self, other: _Run) -> _Run:
        values = np.concatenate([self.values, other.values])
        order = np.argsort(values, kind="stable")
        local = np.hstack([self.local, other.local])[:, order]
        return _Run(values[order], local, self.tol, f"{self.info}; {other.info}")


def _krylov_schur(mats: LBMatrices, nev: int, sigma: float, tol: float,
                  deflation: np.ndarray | None = None) -> _Run:
    """The ``nev`` pairs nearest ``sigma`` (shift-and-invert), M-orthogonal to ``deflation``.

    Args:
        deflation: (n_owned, d) owned rows of known eigenvectors, or ``None``.
    """

    comm = mats.comm
    eps = shift_invert_eps(mats.stiffness, mats.mass, comm=comm, prefix=OPTIONS_PREFIX,
                           nev=nev, sigma=sigma, tol=tol, factor=factor_package(comm))
    basis = []
    try:
        # M is positive definite: purification (one extra solve per vector) is not needed
        eps.setPurify(False)
        eps.setFromOptions()
        # a seeded start vector: eigenvectors inside degenerate eigenspaces then do not
        # depend on how many solves ran before in the process (SLEPc's default random
        # start draws from a global generator)
        start = mats.stiffness.createVecRight()
        low, high = start.getOwnershipRange()
        start.setArray(np.random.default_rng(START_SEED).random(start.getSize())[low:high])
        basis.append(start)
        eps.setInitialSpace([start])
        if deflation is not None:
            deflation_space = []
            for column in deflation.T:
                vec = mats.stiffness.createVecRight()
                vec.setArray(column)
                basis.append(vec)
                deflation_space.append(vec)
            eps.setDeflationSpace(deflation_space)
        tol = eps.getTolerances()[0]  # as overridden by -lb_eps_tol, if given
        eps.solve()
        values, local = converged_pairs(eps, nev=eps.getDimensions()[0], what="LB eigensolver",
                                        tol=tol, sigma=sigma)
        pc = eps.getST().getKSP().getPC()
        info = (f"factor={pc.getFactorSolverType()} nev={eps.getDimensions()[0]} "
                f"ncv={eps.getDimensions()[1]} iterations={eps.getIterationNumber()}")
    finally:
        eps.destroy()
        for vec in basis:
            vec.destroy()
    order = np.argsort(values, kind="stable")
    return _Run(values[order], local[:, order], tol, info)


def _complete_by_inertia(mats: LBMatrices, run: _Run, nev: int, sigma: float) -> _Run:
    """Make sure no eigenvalue below the ``nev``-th computed one was missed.

    Single-vector Krylov methods find further copies of an *exactly* repeated
    eigenvalue (symmetric meshes) only through round-off, and may stop before. The
    number of eigenvalues below a threshold τ is the number of negative pivots of
    ``K − τM = LDLᵀ`` (Sylvester's law of inertia); missing pairs are then computed
    M-orthogonally to the known ones (deflation), where they are simple.
    """
    for _ in range(MAX_COMPLETION_ROUNDS):
        tau = _inertia_threshold(run.values, nev)
        below = count_eigenvalues_below(mats, tau)
        found = int(np.sum(run.values < tau))
        if below == found:
            return run
        if below < found:
            raise SolverError(
                f"LB eigensolver is inconsistent: {found} computed eigenvalues below "
                f"{tau:.6e} but the inertia of K - tau M counts {below}"
            )
        log.info("LB eigensolver missed %d eigenvalue(s) below %.6e (exactly repeated "
                 "eigenvalues of a symmetric mesh); computing them by deflation",
                 below - found, tau)
        run = run.merged(_krylov_schur(mats, below - found, sigma, run.tol, deflation=run.local))
    raise SolverError(
        f"LB eigensolver could not find all eigenvalues below {tau:.6e}: inertia counts "
        f"{below}, found {found} after {MAX_COMPLETION_ROUNDS} rounds"
    )


def _inertia_threshold(values: np.ndarray, nev: int) -> float:
    """τ above the ``nev``-th of the ascending ``values`` and below the next distinct one."""
    last = values[nev - 1]
    gap = CLUSTER_RTOL * abs(last)
    above = values[values > last + gap]
    if above.size:
        return 0.5 * (last + above[0])
    return last + max(1e-3 * abs(last), gap)


def count_eigenvalues_below(mats: LBMatrices, tau: float) -> int:
    """Number of eigenvalues λ < τ of ``Kφ = λMφ`` (inertia of ``K − τM``, MUMPS LDLᵀ).

    Raises:
        SolverError: the factorisation failed (τ is, to round-off, an eigenvalue).
    """
    from petsc4py import PETSc

    A = mats.stiffness.duplicate(copy=True)
    ksp = PETSc.KSP().create(mats.comm)
    try:
        A.axpy(-tau, mats.mass, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
        ksp.setOptionsPrefix(OPTIONS_PREFIX + "inertia_")
        ksp.setOperators(A)
        ksp.setType("preonly")
        pc = ksp.getPC()
        pc.setType("cholesky")
        pc.setFactorSolverType("mumps")
        pc.setFactorSetUpSolverType()
        F = pc.getFactorMatrix()
        F.setMumpsIcntl(13, 1)  # exact inertia: no ScaLAPACK on the root front
        F.setMumpsIcntl(24, 1)  # detect null pivots instead of failing on them
        ksp.setFromOptions()
        try:
            ksp.setUp()
        except PETSc.Error as exc:
            raise SolverError(f"inertia count at tau={tau:.6e} failed ({exc})") from None
        if F.getMumpsInfog(28) != 0:
            raise SolverError(f"tau={tau:.6e} is an LB eigenvalue to round-off (null pivots)")
        return int(F.getMumpsInfog(12))
    finally:
        ksp.destroy()
        A.destroy()


def _check_single_zero(values: np.ndarray, scale: float) -> None:
    """Exactly one of the ascending ``values`` must be (numerically) zero."""
    zero = np.abs(values) <= ZERO_RTOL * scale
    n_zero = int(zero.sum())
    if n_zero != 1 or not zero[0]:
        shown = ", ".join(f"{v:.3e}" for v in values[: min(values.size, 4)])
        hint = (f"; {n_zero} zero eigenvalues mean {n_zero} disconnected bodies"
                if n_zero > 1 else "")
        raise SolverError(
            f"expected exactly one zero LB eigenvalue (|lambda| <= {ZERO_RTOL * scale:.2e}), "
            f"found {n_zero}; smallest: {shown}{hint}"
        )
    if values.size > 1 and values[1] <= 0.0:
        raise SolverError(f"negative LB eigenvalue {values[1]:.3e}: the matrices are invalid")
