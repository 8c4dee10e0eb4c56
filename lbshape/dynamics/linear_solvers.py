"""Newton-update solvers of the full-space stepper: one sparse factorisation reused
across Newton iterations and time steps.

The full-space reference (:mod:`lbshape.dynamics.full`) solves ``(J + W S Wᵀ) δ = R``
at every Newton iteration, J the sparse Newton matrix ``c_a M + c_v D + K(x)`` and
``W S Wᵀ`` an optional low-rank part (:class:`~lbshape.dynamics.integrators.ImplicitStepper`).
With small steps J changes little from one iteration and one step to the next (the
inertial term ``c_a M`` dominates), so a factorisation of an earlier J is an excellent
preconditioner of the current one:

* :class:`ReusedFactorSolver` solves each system by right-preconditioned GMRES with the
  last factorisation (and the Woodbury identity for ``W S Wᵀ``) to a relative residual of
  :data:`LINEAR_RTOL`, or, given the Newton tolerance τ of the step
  (:attr:`ReusedFactorSolver.newton_tolerance`, set by the stepper), to the residual
  ``NEWTON_FRACTION · τ`` where that is larger (an inexact Newton: an update's linear
  residual stays a tenth of what the Newton test accepts, so the iteration converges as
  the exact one does), or to ``NEWTON_FRACTION · c ‖R‖`` where that is larger still, c
  the contraction of the Newton iteration's last update, at most the caller's
  :attr:`ReusedFactorSolver.contraction_cap` (a free body's: an update whose tangent
  leaves ``c ‖R‖`` behind gains nothing from a finer solve), and factorises the current J
  afresh when GMRES needs more than ``max_inner`` iterations (the next call refactorises
  first when it needed more than ``refactor_after``). The Newton iteration around it is
  unchanged: the same residual test.
* factorisations: sparse Cholesky (CHOLMOD through PETSc, :class:`CholmodFactor`) when
  J is symmetric, numeric refactorisation reusing the symbolic one while the pattern
  stays; where Cholesky fails (an indefinite matrix: buckling) or J is not symmetric
  (friction) SciPy's SuperLU (:class:`SuperLUFactor`), as
  :mod:`lbshape.elastic.static_equilibrium` does.

:func:`lu_each_iteration` is the former path (a SuperLU factorisation per Newton
iteration), kept for comparison runs (``scripts/bench_full_reference.py``).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from lbshape.errors import LbshapeError, SolverError

#: relative residual ``‖R − A δ‖ / ‖R‖`` of a Newton update solved with a reused factor
LINEAR_RTOL = 1e-11
#: the fraction of the Newton tolerance an update's linear residual may reach
NEWTON_FRACTION = 0.1
#: the largest Newton contraction a free body's solves follow
#: (:attr:`ReusedFactorSolver.contraction_cap`; a stalling iteration, whose updates
#: contract ‖R‖ little, needs its updates solved finely). Held objects follow none: there
#: the looser updates led Newton to other solutions (a soft hanging bar on a plane settled
#: 7.7 mm through it instead of 4.6 mm; a bar under a 1e4 g load no longer failed)
CONTRACTION_CAP = 1e-3
#: linear solver names of :func:`make_linear_solver`
LINEAR_SOLVERS = ("reuse", "lu-each-iteration")
#: CHOLMOD's simplicial factorisation up to this many rows: on the built-in scenes' Newton
#: matrices (216-2,157 rows) its numeric factorisation took 0.4-0.7× the supernodal one's
#: and its solves 0.7-0.9×, single-threaded; on compact meshes of 4,000+ rows it took 2-9×
#: (``docs/decisions.md``)
SIMPLICIAL_MAX_DOFS = 3000
#: the options prefix of the simplicial factors
_SIMPLICIAL_PREFIX = "lbshape_simplicial_"


class SuperLUFactor:
    """SciPy's SuperLU factorisation of a sparse square matrix (any, non-singular).

    Raises:
        RuntimeError: the matrix is singular (SuperLU's error).
    """

    kind = "superlu"

    def __init__(self, A: sp.spmatrix):
        self._lu = spla.splu(sp.csc_matrix(A))

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        return self._lu.solve(rhs)


class CholmodFactor:
    """Sparse Cholesky factorisation (CHOLMOD through PETSc) of a symmetric positive
    definite CSR matrix; :meth:`refactor` reuses the symbolic factorisation (ordering,
    elimination tree) for a matrix of the same pattern. Up to :data:`SIMPLICIAL_MAX_DOFS`
    rows CHOLMOD's simplicial factorisation, above them its own choice (supernodal there).

    Raises:
        SolverError: not positive definite (or singular).
    """

    kind = "cholmod"

    def __init__(self, A: sp.csr_matrix):
        from petsc4py import PETSc

        A = sp.csr_matrix(A)
        A.sort_indices()
        self.shape = A.shape
        self._indptr = A.indptr.astype(PETSc.IntType)
        self._indices = A.indices.astype(PETSc.IntType)
        self._mat = PETSc.Mat().createAIJ(size=A.shape, csr=(self._indptr, self._indices,
                                                             A.data), comm=PETSc.COMM_SELF)
        self._ksp = PETSc.KSP().create(PETSc.COMM_SELF)
        if A.shape[0] <= SIMPLICIAL_MAX_DOFS:
            PETSc.Options().setValue(_SIMPLICIAL_PREFIX + "mat_cholmod_factor", "simplicial")
            self._ksp.setOptionsPrefix(_SIMPLICIAL_PREFIX)
        self._ksp.setType("preonly")
        pc = self._ksp.getPC()
        pc.setType("cholesky")
        pc.setFactorSolverType("cholmod")
        self._ksp.setFromOptions()
        self._b = PETSc.Vec().createSeq(A.shape[0], comm=PETSc.COMM_SELF)
        self._x = PETSc.Vec().createSeq(A.shape[0], comm=PETSc.COMM_SELF)
        self._factorise()

    def same_pattern(self, A: sp.csr_matrix) -> bool:
        return (A.shape == self.shape and A.indptr.size == self._indptr.size
                and A.indices.size == self._indices.size
                and np.array_equal(A.indptr, self._indptr)
                and np.array_equal(A.indices, self._indices))

    def refactor(self, A: sp.csr_matrix) -> None:
        """Factorise A (same pattern, sorted indices) reusing the symbolic factorisation."""
        self._mat.setValuesCSR(self._indptr, self._indices, A.data)
        self._mat.assemble()
        self._factorise()

    def _factorise(self) -> None:
        from petsc4py import PETSc

        self._ksp.setOperators(self._mat)
        try:
            self._ksp.setUp()
            self._factor = self._ksp.getPC().getFactorMatrix()
        except PETSc.Error as exc:
            raise SolverError(f"Cholesky factorisation failed (PETSc error "
                              f"{getattr(exc, 'ierr', '?')})") from None

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        rhs = np.asarray(rhs, dtype=float)
        if rhs.ndim == 2:
            return np.column_stack([self.solve(rhs[:, j]) for j in range(rhs.shape[1])]) \
                if rhs.shape[1] else np.zeros((rhs.shape[0], 0))
        self._b.getArray()[:] = rhs
        self._factor.solve(self._b, self._x)
        return self._x.getArray().copy()

    def destroy(self) -> None:
        for item in (self._ksp, self._mat, self._b, self._x):
            item.destroy()


def factorise(A: sp.csr_matrix, *, symmetric: bool, previous=None):
    """A factorisation of A: Cholesky (reusing ``previous``'s symbolic one when the pattern
    is the same) when ``symmetric`` and positive definite, else SuperLU."""
    if symmetric:
        try:
            if isinstance(previous, CholmodFactor) and previous.same_pattern(A):
                previous.refactor(A)
                return previous
            return CholmodFactor(A)
        except SolverError:  # indefinite (buckling): LU
            pass
    return SuperLUFactor(A)


def lu_each_iteration(base: sp.spmatrix, K: sp.spmatrix, R: np.ndarray,
                      correction=None) -> np.ndarray:
    """The former Newton update: a SuperLU factorisation of ``J = base + K`` for this one
    solve, with the low-rank part by the Woodbury identity (:class:`ReusedFactorSolver`)."""
    return woodbury_solve(spla.splu(sp.csc_matrix(base + K)).solve, R, correction)


def woodbury_solve(solve, R: np.ndarray, correction=None) -> np.ndarray:
    """``(J + W S Wᵀ)⁻¹ R`` (n,) from ``solve`` (J⁻¹ applied to (n,) or (n, k) arrays) and
    ``correction = (W (n, k), S (k, k))`` or None, by the Woodbury identity in the form
    that needs no S⁻¹: ``J⁻¹ − Z (I + S Wᵀ Z)⁻¹ S Wᵀ J⁻¹``, ``Z = J⁻¹ W``."""
    delta = solve(R)
    if correction is not None and correction[0].size:
        W, S = np.asarray(correction[0], dtype=float), np.asarray(correction[1])
        Z = solve(W)
        small = np.eye(W.shape[1]) + S @ (W.T @ Z)
        delta = delta - Z @ np.linalg.solve(small, S @ (W.T @ delta))
    return delta


class ReusedFactorSolver:
    """Solve Newton systems ``(J + W S Wᵀ) δ = R`` with one factorisation reused across
    calls (see the module docstring).

    Args:
        symmetric: J is symmetric; ``False`` (friction): its symmetric part is factorised
            as the preconditioner (SuperLU of J where GMRES does not converge with it).
        rtol: relative residual of each solve (or the round-off level of ``J δ``,
            ``64 ε (‖J‖∞ ‖δ‖ + ‖R‖)``, where that is larger).
        max_inner: GMRES iterations with a reused factor before J is factorised afresh.
        refactor_after: when a solve needed more GMRES iterations than this, the next
            call factorises its J first.

    Attributes:
        newton_tolerance: the Newton residual tolerance τ (force units) of the current
            step, set by the stepper; 0 (default): every solve to ``rtol``.
        newton_contraction: ``‖R_new‖ / ‖R‖`` of the stepper's last accepted Newton update
            (set by the stepper; 0: none yet): a solve may stop at a linear residual of
            ``NEWTON_FRACTION`` times that contraction, at most ``contraction_cap``, of ‖R‖.
        contraction_cap: the largest contraction a solve's goal follows (set by the caller;
            0, the default: every solve to the goals above alone). A free body uses
            :data:`CONTRACTION_CAP`.
        frame: (3, 3) the rotation of a free body's current rigid frame, or None (set by
            the caller each step; the dofs are then whole vertices, node-major). A factor
            of ``J₀`` taken in frame R₀ preconditions ``Q J₀ Qᵀ``, ``Q = diag(R R₀ᵀ, …)``:
            the stiffness of a rotated body is the rotated stiffness, and the mass and the
            co-rotated damping commute with Q, so the factor follows the body's rotation.
        factorisations: factorisations done so far.
        solves: systems solved.
        inner_iterations: GMRES iterations (preconditioner applications) so far.
    """

    def __init__(self, *, symmetric: bool = True, rtol: float = LINEAR_RTOL,
                 max_inner: int = 30, refactor_after: int = 12):
        self.symmetric = bool(symmetric)
        self.rtol = float(rtol)
        self.max_inner = int(max_inner)
        self.refactor_after = int(refactor_after)
        self._factor = None
        self._stale = True
        self._pattern = None
        self._last_matrix = None  # (base, K, J) of the last newton_matrix
        self._woodbury = None  # (W, S, J₀⁻¹W, (I + S Wᵀ J₀⁻¹ W)⁻¹ S) of the factor
        self._norm = 0.0  # ‖J‖∞ of the factorised matrix (the round-off level)
        self.frame: np.ndarray | None = None
        self.newton_tolerance = 0.0
        self.newton_contraction = 0.0
        self.contraction_cap = 0.0
        self._factor_frame: np.ndarray | None = None  # the frame the factor was taken in
        self.factorisations = 0
        self.solves = 0
        self.inner_iterations = 0

    def reset(self) -> None:
        """Forget the factorisation (the next call factorises)."""
        self._stale = True

    def _factorise(self, J: sp.csr_matrix) -> None:
        # a non-symmetric J (friction): Cholesky of its symmetric part as the
        # preconditioner (GMRES solves J itself); LU of J where that fails
        matrix = J if self.symmetric else _symmetric_part(J)
        self._factor = factorise(matrix, symmetric=True, previous=self._factor)
        self._factor_frame = None if self.frame is None else np.array(self.frame)
        self.factorisations += 1
        self._stale = False
        self._woodbury = None
        self._norm = _inf_norm(J)

    def newton_matrix(self, base: sp.spmatrix, K: sp.spmatrix) -> sp.csr_matrix:
        """``J = base + K`` (CSR, sorted): on K's own pattern when it holds base's (one
        vector addition; K from :class:`~lbshape.elastic.assembly.CompiledElasticity`
        keeps its pattern arrays), else by a sparse addition. The last J is kept for the
        same ``base`` and ``K`` objects (a modified Newton's kept tangent, never changed
        in place once evaluated)."""
        last = self._last_matrix
        if last is not None and last[0] is base and last[1] is K:
            return last[2]
        J = self._newton_matrix(base, K)
        self._last_matrix = (base, K, J)
        return J

    def _newton_matrix(self, base: sp.spmatrix, K: sp.spmatrix) -> sp.csr_matrix:
        if sp.isspmatrix_csr(K) and K.has_sorted_indices:
            kept = self._pattern
            if kept is None or kept[0] is not base or not (
                    np.array_equal(kept[1], K.indptr) and np.array_equal(kept[2], K.indices)):
                kept = (base, K.indptr.copy(), K.indices.copy(), _embed(base, K))
                self._pattern = kept
            embedded = kept[3]
            if embedded is not None:
                return sp.csr_matrix((embedded + K.data, K.indices, K.indptr), shape=K.shape)
        J = sp.csr_matrix(base + K)
        J.sort_indices()
        return J

    def __call__(self, base: sp.spmatrix, K: sp.spmatrix, R: np.ndarray,
                 correction=None) -> np.ndarray:
        J = self.newton_matrix(base, K)
        self.solves += 1
        fresh = self._stale or self._factor is None
        if fresh:
            self._factorise(J)
        delta, iterations, converged = self._gmres(J, R, correction)
        if not converged and not fresh:
            self._factorise(J)
            delta, iterations, converged = self._gmres(J, R, correction)
        if not converged and self._factor.kind != SuperLUFactor.kind:
            # a Cholesky factor of an indefinite matrix (PETSc does not always report it)
            # or of a non-symmetric J's symmetric part: LU of J
            self._factor = SuperLUFactor(J)
            self._factor_frame = None if self.frame is None else np.array(self.frame)
            self._woodbury = None
            self._norm = _inf_norm(J)
            self.factorisations += 1
            delta, iterations, converged = self._gmres(J, R, correction)
        if iterations > self.refactor_after:
            self._stale = True
        return delta

    def _in_frame(self, precondition, size: int):
        """The preconditioner turned into the current frame, ``Q P⁻¹ Qᵀ`` (see
        :attr:`frame`), or ``precondition`` itself when there is no turn."""
        turn = _turn_of(self.frame, self._factor_frame, size)
        if turn is None:
            return precondition

        def turned(v):
            return (precondition((v.reshape(-1, 3) @ turn).ravel()).reshape(-1, 3)
                    @ turn.T).ravel()
        return turned

    def _gmres(self, J, R, correction):
        """Right-preconditioned GMRES from ``δ₀ = P⁻¹ R``; ``(δ, iterations, converged)``
        (with a fresh factor a non-converged δ is the best there is, as a direct solve)."""
        solve = self._factor.solve
        if correction is not None and correction[0].size:
            W, S = np.asarray(correction[0], dtype=float), np.asarray(correction[1])
            # the preconditioner: the factored matrix plus the low-rank part it was
            # factorised with (Woodbury); GMRES absorbs the change of W S Wᵀ since then
            kept = self._woodbury
            if kept is None or kept[0].shape != W.shape or kept[1].shape != S.shape:
                Z = solve(W)
                kept = (W, S, Z, np.linalg.inv(np.eye(W.shape[1]) + S @ (W.T @ Z)) @ S)
                self._woodbury = kept
            W0, Z0, small0 = kept[0], kept[2], kept[3]

            def precondition(v):
                y = solve(v)
                return y - Z0 @ (small0 @ (W0.T @ y))

            def operator(v):
                return J @ v + W @ (S @ (W.T @ v))
        else:
            precondition = solve

            def operator(v):
                return J @ v
        precondition = self._in_frame(precondition, R.size)
        norm_r = math.sqrt(float(R @ R))
        x = precondition(R)
        self.inner_iterations += 1
        if norm_r == 0.0:
            return x, 1, True
        # the tolerance, or the round-off level of evaluating J x where that is larger
        # (an ill-conditioned J: no solve, direct or not, gets its residual lower)
        noise = 64.0 * np.finfo(float).eps * (self._norm * math.sqrt(float(x @ x)) + norm_r)
        target = max(self.rtol * norm_r, NEWTON_FRACTION * self.newton_tolerance, noise,
                     NEWTON_FRACTION * min(self.newton_contraction, self.contraction_cap)
                     * norm_r)
        r = R - operator(x)
        beta = math.sqrt(float(r @ r))
        if beta <= target:
            return x, 1, True
        m = self.max_inner
        V = np.empty((m + 1, R.size))
        Zs = np.empty((m, R.size))
        H = np.zeros((m + 1, m))
        cs, sn = np.zeros(m), np.zeros(m)
        g = np.zeros(m + 1)
        g[0] = beta
        V[0] = r / beta
        k = 0
        for k in range(m):
            Zs[k] = precondition(V[k])
            self.inner_iterations += 1
            w = operator(Zs[k])
            for i in range(k + 1):  # modified Gram-Schmidt
                H[i, k] = float(w @ V[i])
                w -= H[i, k] * V[i]
            H[k + 1, k] = math.sqrt(float(w @ w))
            if H[k + 1, k] > 0:
                V[k + 1] = w / H[k + 1, k]
            for i in range(k):  # earlier rotations
                a, b = H[i, k], H[i + 1, k]
                H[i, k], H[i + 1, k] = cs[i] * a + sn[i] * b, -sn[i] * a + cs[i] * b
            a, b = H[k, k], H[k + 1, k]
            rho = math.hypot(a, b)
            cs[k], sn[k] = (a / rho, b / rho) if rho > 0 else (1.0, 0.0)
            H[k, k], H[k + 1, k] = rho, 0.0
            g[k + 1] = -sn[k] * g[k]
            g[k] = cs[k] * g[k]
            if abs(g[k + 1]) <= target or H[k, k] == 0.0:
                break
        steps = k + 1
        y = np.linalg.solve(np.triu(H[:steps, :steps]) + np.diag(H[:steps, :steps].diagonal()
                                                                  == 0.0), g[:steps])
        x = x + y @ Zs[:steps]
        r = R - operator(x)
        converged = math.sqrt(float(r @ r)) <= 10.0 * target
        return x, steps + 1, converged


def _turn_of(frame, factor_frame, size: int) -> np.ndarray | None:
    """``R R₀ᵀ`` from the current frame R and the factor's R₀ (None: no frames, not whole
    vertices, or no rotation)."""
    if frame is None or factor_frame is None or size % 3:
        return None
    turn = np.asarray(frame) @ np.asarray(factor_frame).T
    return None if np.array_equal(turn, np.eye(3)) else turn


def _inf_norm(J: sp.spmatrix) -> float:
    """Largest absolute row sum of J."""
    return float(abs(J).sum(axis=1).max()) if J.shape[0] else 0.0


def _symmetric_part(J: sp.csr_matrix) -> sp.csr_matrix:
    """``(J + Jᵀ)/2`` (CSR, sorted)."""
    sym = sp.csr_matrix(0.5 * (J + J.T))
    sym.sort_indices()
    return sym


def _embed(base: sp.spmatrix, K: sp.csr_matrix) -> np.ndarray | None:
    """base's entries as a data array on K's (sorted CSR) pattern, or None when base has
    an entry outside it."""
    n = K.shape[0]
    coo = sp.coo_matrix(base)
    coo.sum_duplicates()
    rows = np.repeat(np.arange(n, dtype=np.int64), np.diff(K.indptr))
    keys = rows * n + K.indices
    wanted = coo.row.astype(np.int64) * n + coo.col
    position = np.searchsorted(keys, wanted)
    position[position >= keys.size] = 0
    if not np.array_equal(keys[position], wanted):
        return None
    data = np.zeros(keys.size)
    data[position] = coo.data
    return data


def make_linear_solver(name: str, *, symmetric: bool = True):
    """The Newton-update solver named ``name`` (:data:`LINEAR_SOLVERS`): a callable
    ``(base, K, R, correction) -> δ`` solving ``(base + K + W S Wᵀ) δ = R``."""
    if name == "reuse":
        return ReusedFactorSolver(symmetric=symmetric)
    if name == "lu-each-iteration":
        return lu_each_iteration
    raise LbshapeError(f"linear solver must be one of {LINEAR_SOLVERS}, got {name!r}")
