"""Modal derivatives (Barbič & James 2005): the second-order part of the basis.

For linear modes ψ_i, ψ_j the modal derivative Ψ_ij solves

    K Ψ_ij = −H(ψ_i, ψ_j),   H(a, b) = ∂³E/∂u³|₀ [a, b, ·],

with K the stiffness at rest and H the Hessian of the internal force
``f(u) = ∂E/∂u`` at rest (an n-vector for each pair of directions). Both are UFL
derivatives of the **StVK** energy with the given (E, ν, ρ), whatever the simulation
material: as in Barbič & James, the derivatives span the quadratic (StVK)
nonlinearity of the rest geometry. Both material models share K at rest.

H of every pair is evaluated in one compiled pass over the elements
(:func:`force_hessians`, rank 0; its rows are sent to the ranks); :class:`ForceHessian`,
the UFL form of the same H, is its independent check. Because E is a quartic polynomial
of ∇u for StVK, f is cubic and ``H(ψ, ψ) = (f(εψ) + f(−εψ))/ε²`` holds exactly for every ε.

Solving. One sparse Cholesky factorisation (PETSc KSP ``preonly`` + Cholesky: CHOLMOD
serially, MUMPS over several ranks; options prefix ``md_``) serves every right-hand side.
It also solves the basis's **static responses** ``K x = f`` (keyword ``static_loads``,
clamped bodies only; :mod:`lbshape.pipeline.responses`) in the same block solve: K at
rest is the same for both material models, and a second factorisation of K would
cost as much as this one (measured in ``docs/decisions.md``).

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
:class:`~lbshape.errors.SolverError`.

**Distributed** (``comm`` with several ranks, e.g. under ``mpirun``): the mesh is
distributed by DOLFINx, K and M are assembled in parallel (:func:`lbshape.elastic.modes.
elastic_matrices`), the H(ψ_i, ψ_j) of rank 0 are sent to the ranks, each receiving the
rows of its dofs, the projections and residuals use PETSc products and sums over the
ranks, and MUMPS factors K once over all ranks; the derivatives are gathered to
rank 0 (:mod:`lbshape.fem.petsc_gather`). One rank runs the same code.
"""

from __future__ import annotations

import dataclasses
import logging
import time

import numpy as np
import scipy.linalg
from mpi4py import MPI

from lbshape._jit import njit
from lbshape.elastic.materials import Material, strain_energy_ufl
from lbshape.elastic.modes import LinearModes, elastic_matrices, rigid_body_modes
from lbshape.errors import LbshapeError, SolverError
from lbshape.fem.cholesky import CholeskySolver
from lbshape.fem.dolfinx_bridge import dof_to_input_order, p1_dof_vertices, to_dolfinx
from lbshape.fem.eigenproblem import check_residuals
from lbshape.fem.mpi import compute_on_root, sum_over_ranks
from lbshape.fem.petsc_gather import gather_rows, scatter_rows
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
        static_responses: (3n, c) solutions x of ``K x = f`` for the ``static_loads``
            f (m for f in N), zero at fixed DOFs; (3n, 0) without loads.
    """

    vectors: np.ndarray
    pairs: np.ndarray
    residuals: np.ndarray
    seconds: float
    static_responses: np.ndarray | None = None


class ForceHessian:
    """``H(a, b) = ∂³E/∂u³|₀ [a, b, ·]`` of the StVK energy on a mesh.

    The UFL form is compiled once; each call re-assembles it for new directions.

    Args:
        mesh: the tetrahedral mesh (n vertices); used only without ``space``.
        material: (E, ν) are used with the StVK model, whatever ``material.model``.
        space: a DOLFINx vector P1 ``FunctionSpace`` (serial or distributed) to
            assemble on; default a serial space on ``mesh``.
    """

    def __init__(self, mesh: TetMesh | None, material: Material, *, space=None):
        import dolfinx.fem
        import ufl
        from mpi4py import MPI

        self.material = stvk_material(material)
        if space is None:
            space = dolfinx.fem.VectorFunctionSpace(to_dolfinx(mesh, MPI.COMM_SELF),
                                                    ("Lagrange", 1))
        self.space = space
        u = dolfinx.fem.Function(space)  # zero: the rest state
        self._a, self._b = dolfinx.fem.Function(space), dolfinx.fem.Function(space)
        v = ufl.TestFunction(space)
        force = ufl.derivative(strain_energy_ufl(self.material, u), u, v)
        hessian = ufl.derivative(ufl.derivative(force, u, self._a), u, self._b)
        self._form = dolfinx.fem.form(hessian)
        self._dof_vertices = p1_dof_vertices(space)
        self.n_vertices = space.dofmap.index_map.size_global
        #: (3 · local vertices,) input index of every local dof (owned, then ghosts)
        self.local_dofs = dof_to_input_order(self._dof_vertices, 3)
        self.n_owned = 3 * space.dofmap.index_map.size_local
        self._vector = None

    def assemble(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """H(a, b) on the owned dofs (3 · owned vertices,) in DOLFINx order, in N/m², for
        directions given at every local dof (:attr:`local_dofs` order, ghosts included)."""
        import dolfinx.fem.petsc
        from petsc4py import PETSc

        self._a.x.array[:] = a
        self._b.x.array[:] = b
        if self._vector is None:  # one ghosted vector, re-used by every call
            self._vector = dolfinx.fem.petsc.create_vector(self._form)
        with self._vector.localForm() as local:
            local.set(0.0)
        dolfinx.fem.petsc.assemble_vector(self._vector, self._form)
        self._vector.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        return self._vector.getArray(readonly=True)[: self.n_owned].copy()

    def destroy(self) -> None:
        """Destroy the assembly vector (idempotent; also done at garbage collection)."""
        if self._vector is not None:
            self._vector.destroy()
            self._vector = None

    def __call__(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """H(a, b) (3n,) in N/m² for node-major input-order displacements a, b (3n,) in m
        (a serial space)."""
        values = []
        for direction in (a, b):
            direction = np.asarray(direction, dtype=np.float64)
            if direction.shape != (3 * self.n_vertices,):
                raise LbshapeError(f"direction must have shape ({3 * self.n_vertices},), "
                                   f"got {direction.shape}")
            values.append(direction[self.local_dofs])
        out = np.empty(3 * self.n_vertices)
        out[self.local_dofs[: self.n_owned]] = self.assemble(*values)
        return out


def stvk_material(material: Material) -> Material:
    """The StVK material with the same (E, ν, ρ)."""
    return dataclasses.replace(material, model="stvk")


def force_hessians(mesh: TetMesh, material: Material, vectors: np.ndarray,
                   pairs: np.ndarray) -> np.ndarray:
    """``H(ψ_i, ψ_j)`` (3n, p) in N/m² of the StVK energy for every pair ``(i, j)`` of the
    columns of ``vectors`` (3n, k), node-major, input order: one compiled pass over the
    elements for all pairs (the same quantity as :class:`ForceHessian`, to round-off).

    With ``G = ∇a``, ``S(G) = μ(G + Gᵀ) + λ tr(G) I`` (the stress of the strain ``sym G``),
    the second derivative of ``P = F S`` at rest is
    ``G_a S(G_b) + G_b S(G_a) + μ(G_aᵀG_b + G_bᵀG_a) + λ (G_a : G_b) I``, and each element
    adds ``V P ∇N_v`` at its vertex v (P1: constant gradients, exact).
    """
    stvk = stvk_material(material)
    vectors = np.ascontiguousarray(vectors, dtype=np.float64)
    out = np.zeros((vectors.shape[0], pairs.shape[0]))
    _hessian_kernel(np.ascontiguousarray(mesh.points, dtype=np.float64),
                    np.ascontiguousarray(mesh.tets, dtype=np.int64), vectors,
                    np.ascontiguousarray(pairs, dtype=np.int64), stvk.mu, stvk.lam, out)
    return out


@njit
def _hessian_kernel(points, tets, vectors, pairs, mu, lam, out):  # pragma: no cover - jit
    k, p = vectors.shape[1], pairs.shape[0]
    edges, inv, grads = np.empty((3, 3)), np.empty((3, 3)), np.empty((4, 3))
    G, S, P = np.empty((k, 3, 3)), np.empty((k, 3, 3)), np.empty((3, 3))
    for e in range(tets.shape[0]):
        for c in range(3):
            for a in range(3):
                edges[c, a] = points[tets[e, a + 1], c] - points[tets[e, 0], c]
        det = (edges[0, 0] * (edges[1, 1] * edges[2, 2] - edges[1, 2] * edges[2, 1])
               - edges[0, 1] * (edges[1, 0] * edges[2, 2] - edges[1, 2] * edges[2, 0])
               + edges[0, 2] * (edges[1, 0] * edges[2, 1] - edges[1, 1] * edges[2, 0]))
        for a in range(3):  # inv = edges⁻¹ by cofactors; row a is ∇N_(a+1)
            for j in range(3):
                r0, r1 = (j + 1) % 3, (j + 2) % 3
                c0, c1 = (a + 1) % 3, (a + 2) % 3
                inv[a, j] = (edges[r0, c0] * edges[r1, c1] - edges[r0, c1] * edges[r1, c0]) / det
        volume = abs(det) / 6.0
        for j in range(3):
            grads[0, j] = -(inv[0, j] + inv[1, j] + inv[2, j])
            for a in range(3):
                grads[a + 1, j] = inv[a, j]
        for m in range(k):
            for c in range(3):
                for j in range(3):
                    value = 0.0
                    for a in range(4):
                        value += vectors[3 * tets[e, a] + c, m] * grads[a, j]
                    G[m, c, j] = value
            trace = G[m, 0, 0] + G[m, 1, 1] + G[m, 2, 2]
            for c in range(3):
                for j in range(3):
                    S[m, c, j] = mu * (G[m, c, j] + G[m, j, c])
                S[m, c, c] += lam * trace
        for q in range(p):
            i, b = pairs[q, 0], pairs[q, 1]
            inner = 0.0
            for c in range(3):
                for j in range(3):
                    inner += G[i, c, j] * G[b, c, j]
            for c in range(3):
                for j in range(3):
                    value = 0.0
                    for m in range(3):
                        value += (G[i, c, m] * S[b, m, j] + G[b, c, m] * S[i, m, j]
                                  + mu * (G[i, m, c] * G[b, m, j] + G[b, m, c] * G[i, m, j]))
                    P[c, j] = value
                P[c, c] += lam * inner
            for a in range(4):
                row = 3 * tets[e, a]
                for c in range(3):
                    value = 0.0
                    for j in range(3):
                        value += P[c, j] * grads[a, j]
                    out[row + c, q] += volume * value


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
    static_loads: np.ndarray | None = None,
    comm: MPI.Comm = MPI.COMM_SELF,
) -> ModalDerivatives:
    """Modal derivatives of ``modes`` (see the module docstring).

    Args:
        mesh: the mesh the modes were computed on (n vertices; rank 0's copy is used).
        material: (E, ν, ρ) of the modes; the StVK energy is used for K and H.
        modes: linear modes (k of them) with their fixed vertices; their vectors are
            read on rank 0 only (where :func:`~lbshape.elastic.modes.linear_modes`
            leaves them).
        pairs: (p, 2) 0-based mode index pairs; default every i ≤ j < k.
        static_loads: (3n, c) force patterns f in N (read on rank 0) whose static
            responses ``K x = f`` are solved with the same factorisation; clamped
            bodies only (K of a free body is singular).
        comm: the communicator (``MPI.COMM_WORLD`` to run distributed).

    Returns:
        :class:`ModalDerivatives`; in parallel ``vectors`` is on rank 0 only (``None``
        elsewhere), ``residuals`` on every rank.

    Raises:
        LbshapeError: modes from another mesh, bad pairs, or static loads of the
            wrong shape or on a free body.
        SolverError: the factorisation failed or a residual is too large.
    """
    started = time.perf_counter()
    n, c = compute_on_root(comm, lambda: (_checked_size(mesh, modes),
                                          _load_count(static_loads, 3 * mesh.n_vertices)))
    pairs = _check_pairs(pairs, modes.count)
    stvk = stvk_material(material)
    fixed = np.asarray(modes.fixed_vertices, dtype=np.int64)
    if c and not fixed.size:
        raise LbshapeError("static responses need a clamped body (K of a free body is "
                           "singular)")
    p = pairs.shape[0]
    with elastic_matrices(mesh, stvk, fixed_vertices=fixed, comm=comm) as mats:
        rows = mats.local_rows  # input DOF of each local row of K, M (free DOFs)
        rigid, solve_rows = _rigid_null_space(mesh, mats, free=not fixed.size, comm=comm)
        system = _DistributedSystem(mats, rigid, solve_rows)
        rhs = np.zeros((rows.size, p + c))
        if c:
            rhs[:, p:] = scatter_rows(static_loads, rows, comm=comm)
        with system:
            _hessian_right_hand_sides(rhs, mesh, stvk, modes.vectors, pairs, system, rigid,
                                      comm)
            vectors, misfit = _solve_block(system, rhs, rigid, comm)
        residuals = _checked_residuals(misfit, rhs, pairs, comm)
        vectors = gather_rows(vectors, rows, comm=comm, size=3 * n)
    seconds = time.perf_counter() - started
    log.info("modal derivatives: n=%d pairs=%d static loads=%d free=%s ranks=%d max "
             "residual %.1e in %.2f s", n, p, c, rigid is not None, comm.size,
             residuals.max(initial=0.0), seconds)
    responses = None if vectors is None else vectors[:, p:]
    return ModalDerivatives(vectors=None if vectors is None else vectors[:, :p], pairs=pairs,
                            residuals=residuals[:p], seconds=seconds,
                            static_responses=responses)


def _rigid_null_space(mesh: TetMesh, mats, *, free: bool, comm: MPI.Comm
                      ) -> tuple[np.ndarray | None, np.ndarray | None]:
    """A free body's rigid modes R on the local rows (l, 6) and the local rows solved for
    (all but the 6 pinned DOFs, :func:`_pinned_dofs`); (None, None) for a clamped body."""
    if not free:
        return None, None
    rows = mats.local_rows
    full = compute_on_root(comm, lambda: rigid_body_modes(mesh.points, mats.mass),
                           share=False)
    pinned = compute_on_root(comm, lambda: _pinned_dofs(full))
    rigid = scatter_rows(full, rows, comm=comm)  # (l, 6) local rows of R
    return rigid, np.flatnonzero(~np.isin(rows, pinned))


def _hessian_right_hand_sides(rhs: np.ndarray, mesh: TetMesh, stvk: Material,
                              vectors: np.ndarray | None, pairs: np.ndarray,
                              system: _DistributedSystem, rigid: np.ndarray | None,
                              comm: MPI.Comm) -> None:
    """Column q of ``rhs`` (local rows) ← ``−H(ψ_i, ψ_j)`` for ``pairs[q] = (i, j)``
    (:func:`force_hessians` on rank 0, its rows sent to the ranks), a free body's
    projected onto the consistent range (``h ← (I − M R Rᵀ) h``)."""
    hessians = compute_on_root(comm, lambda: force_hessians(mesh, stvk, vectors, pairs),
                               share=False)
    local = scatter_rows(hessians, system.rows, comm=comm)
    for q in range(pairs.shape[0]):
        h = local[:, q]
        if rigid is not None:
            h -= system.mass_times(rigid @ sum_over_ranks(comm, rigid.T @ h))
        rhs[:, q] = -h


def _solve_block(system: _DistributedSystem, rhs: np.ndarray, rigid: np.ndarray | None,
                 comm: MPI.Comm) -> tuple[np.ndarray, np.ndarray]:
    """(X, K X − rhs) on the local rows: every non-zero right-hand side in one block
    solve, a free body's solutions made M-orthogonal to its rigid modes; the misfit is
    over every equation that must hold (all DOFs of a free body)."""
    vectors = np.zeros_like(rhs)
    nonzero = np.flatnonzero(sum_over_ranks(comm, np.any(rhs, axis=0).astype(np.int64)))
    if nonzero.size:  # all right-hand sides in one block solve
        vectors[:, nonzero] = system.solve(rhs[:, nonzero])
    if rigid is not None:
        masses = np.column_stack([system.mass_times(x) for x in vectors.T])
        vectors -= rigid @ sum_over_ranks(comm, rigid.T @ masses)
    misfit = np.column_stack([system.stiffness_times(x) for x in vectors.T]) - rhs
    return vectors, misfit


def _checked_residuals(misfit: np.ndarray, rhs: np.ndarray, pairs: np.ndarray,
                       comm: MPI.Comm) -> np.ndarray:
    """(p + c,) relative residuals ``‖K x − rhs‖ / ‖rhs‖`` over the ranks (0 for a zero
    right-hand side), checked against :data:`RESIDUAL_RTOL`."""
    p = pairs.shape[0]
    misfit_norms = np.sqrt(sum_over_ranks(comm, np.sum(misfit**2, axis=0)))
    norms = np.sqrt(sum_over_ranks(comm, np.sum(rhs**2, axis=0)))
    residuals = np.divide(misfit_norms, norms, out=np.zeros(rhs.shape[1]), where=norms > 0)
    check_residuals(residuals, RESIDUAL_RTOL, what="modal derivative solves",
                    describe=lambda q: f"pair {tuple(pairs[q])}" if q < p
                    else f"static load {q - p}")
    return residuals


def _checked_size(mesh: TetMesh, modes: LinearModes) -> int:
    """n, after checking that the modes' vectors belong to ``mesh`` (rank 0)."""
    n = mesh.n_vertices
    if modes.vectors is None or modes.vectors.shape[0] != 3 * n:
        shape = None if modes.vectors is None else modes.vectors.shape
        raise LbshapeError(f"the modes do not belong to this mesh: vectors {shape}, "
                           f"mesh has {n} vertices")
    return n


def _load_count(loads: np.ndarray | None, size: int) -> int:
    """c, after checking that ``loads`` is a finite (size, c) array (rank 0)."""
    if loads is None:
        return 0
    array = np.asarray(loads)
    if array.ndim != 2 or array.shape[0] != size or not np.isfinite(array).all():
        raise LbshapeError(f"static_loads must be a finite ({size}, c) array, got "
                           f"{array.dtype} {array.shape}")
    return int(array.shape[1])


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


def _pinned_dofs(rigid: np.ndarray) -> np.ndarray:
    """The 6 DOFs (input indices) that best determine a rigid motion (rows of R by
    pivoted QR)."""
    _, r, pivots = scipy.linalg.qr(rigid.T, mode="economic", pivoting=True)
    k = rigid.shape[1]
    conditioning = abs(r[k - 1, k - 1] / r[0, 0])  # diagonal of the (k, 3n) factor
    if conditioning < 1e-8:  # pragma: no cover - needs a degenerate (collinear) body
        raise SolverError(f"cannot pin the rigid motions of this body (|r66/r11| = "
                          f"{conditioning:.1e})")
    return np.sort(pivots[:k]).astype(np.int64)


def _unpinned_dofs(rigid: np.ndarray) -> np.ndarray:
    """All DOFs but the 6 of :func:`_pinned_dofs`."""
    keep = np.ones(rigid.shape[0], dtype=bool)
    keep[_pinned_dofs(rigid)] = False
    return np.flatnonzero(keep)


class _DistributedSystem:
    """K and M on the free DOFs (distributed PETSc matrices of an
    :class:`~lbshape.elastic.modes.ElasticMatrices`) and one MUMPS Cholesky
    factorisation of K restricted to the local rows ``solve_rows`` (all rows of a
    clamped body; all but the pinned ones of a free body). Vectors are local-row
    arrays (l,) in the order of ``mats.local_rows``."""

    def __init__(self, mats, rigid: np.ndarray | None, solve_rows: np.ndarray | None):
        from petsc4py import PETSc

        self._K, self._M = mats.stiffness_petsc, mats.mass_petsc
        self.rows = mats.local_rows  # input DOF of each local row
        self._x, self._y = self._K.createVecs()
        self._sub = None
        self._solve_rows = solve_rows
        if solve_rows is not None:
            start = self._K.getOwnershipRange()[0]
            index_set = PETSc.IS().createGeneral((start + solve_rows).astype(PETSc.IntType),
                                                 comm=mats.comm)
            try:
                self._sub = self._K.createSubMatrix(index_set, index_set)
            finally:
                index_set.destroy()
        self._solver = CholeskySolver(self._sub if self._sub is not None else self._K,
                                      prefix=OPTIONS_PREFIX, what="the stiffness")

    def _apply(self, A, x: np.ndarray) -> np.ndarray:
        self._x.setArray(x)
        A.mult(self._x, self._y)
        return self._y.getArray(readonly=True).copy()

    def stiffness_times(self, x: np.ndarray) -> np.ndarray:
        return self._apply(self._K, x)

    def mass_times(self, x: np.ndarray) -> np.ndarray:
        return self._apply(self._M, x)

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """X (l, c) with K X = rhs (l, c) on the solve rows, zero on the pinned rows."""
        if self._solve_rows is None:
            return self._solver.solve(rhs)
        x = np.zeros_like(rhs)
        x[self._solve_rows] = self._solver.solve(rhs[self._solve_rows])
        return x

    def __enter__(self) -> _DistributedSystem:
        return self

    def __exit__(self, *exc) -> None:
        self._solver.destroy()
        for item in (self._sub, self._x, self._y):
            if item is not None:
                item.destroy()
