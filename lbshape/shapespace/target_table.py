"""The interpolation target tabulated over the weight simplex (paper eqs. 4, 6, precomputed).

The target ``z*(w) = argmin_z Σ_k w_k E_k(z − z_k)`` depends only on the example
weights w (k,), a point of the simplex. With few examples it is cheaper to solve it
exactly at precompute on a grid of weights and to interpolate at run time:

* k = 1: the example itself, ``z* = z_1``;
* k = 2 (``segment``): ``w = (1 − t, t)``; N + 1 uniform nodes ``t_j = j/N``, the exact
  target and its slope ``dz*/dt`` at each node, and a cubic Hermite spline in t
  between them. The slope comes from the implicit function theorem: differentiating
  ``∇F(z*(t), t) = 0`` gives ``H dz*/dt = −(∇E_1(z* − z_1) − ∇E_0(z* − z_0))`` with
  ``H = ∇²F`` (p, p);
* k = 3 (``triangle``): ``w = (1 − a − b, a, b)``; the triangle cut into N² macro
  triangles, each carrying the cubic Lagrange interpolant of its 10 nodes (a uniform
  barycentric grid of level 3N, exact targets at every node).

Both interpolants are O(h⁴) accurate for a smooth target. The table is accepted only
after checking it against the exact target at held-out weights (interval midpoints
and random points, or macro-triangle centroids and random points): the error is
measured as a share of the examples' **separation** ``max_ij ‖B(z_i − z_j)‖_M`` (the
distance between the examples' own targets), never relative to the target's size,
which passes near zero between examples of opposite sign. When the error exceeds
the tolerance the grid is refined (N doubled) up to a limit, then the table is
refused (:class:`TableRefused`) and the caller falls back to solving the target.

Run time (:meth:`TargetTable.reduced_into`): locate the cell, evaluate 4 or 10 basis
functions and combine as many stored vectors of the reduced dimension r — no Newton,
nothing n-sized, no allocation (a JIT kernel when numba is present).

The example energies behind the table and the path of exact targets the precompute
trains on are built by :mod:`lbshape.shapespace.example_targets`.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from lbshape._jit import njit
from lbshape.errors import LbshapeError
from lbshape.shapespace.interpolation import TargetResult, TargetSolver

log = logging.getLogger(__name__)

#: table kinds by number of examples
KINDS = {1: "point", 2: "segment", 3: "triangle"}
#: default interpolation intervals per edge (k = 2: 16 intervals, 17 nodes)
DEFAULT_INTERVALS = {1: 1, 2: 16, 3: 4}
#: largest intervals per edge tried before refusing
MAX_INTERVALS = {1: 1, 2: 256, 3: 16}
#: default accepted table error, as a share of the example separation
DEFAULT_TOLERANCE = 0.005
#: Newton tolerance of the exact solves behind the table (relative step size)
EXACT_TOLERANCE = 1e-10
_KIND_CODE = {"point": 0, "segment": 1, "triangle": 2}


class TableRefused(LbshapeError):
    """The table's checked error stays above its tolerance at the finest grid allowed."""


@dataclass(frozen=True)
class TableCheck:
    """The table's error against the exact target at held-out weights.

    Attributes:
        intervals: N, intervals per simplex edge of the accepted grid.
        nodes: exact solves at the nodes.
        checks: held-out weights compared.
        max_error: largest ``‖B(z_table − z_exact)‖_M / separation`` (dimensionless).
        median_error: its median.
        tolerance: the accepted maximum.
        separation: ``max_ij ‖B(z_i − z_j)‖_M`` in the norm's units (m·m^{3/2} for LB).
        seconds: wall time of building and checking (s).
    """

    intervals: int
    nodes: int
    checks: int
    max_error: float
    median_error: float
    tolerance: float
    separation: float
    seconds: float


class TargetTable:
    """The target z*(w) (p,) interpolated over the weight simplex (see the module docstring).

    Args:
        kind: ``"point"``, ``"segment"`` or ``"triangle"``.
        intervals: N, intervals per edge.
        cells: (n_cells, n_basis, p) per cell the coefficients of the basis functions
            (segment: ``[z_j, h z'_j, z_{j+1}, h z'_{j+1}]``; triangle: the 10 nodal
            values in the order of :func:`_p3_nodes`; point: ``[z_1]``).
        nodes: (n_nodes, p) the exact targets at the nodes (for training and checks).
        node_weights: (n_nodes, k) the weights of the nodes.
        check: the held-out check, when done.
    """

    def __init__(self, kind: str, intervals: int, cells: np.ndarray, nodes: np.ndarray,
                 node_weights: np.ndarray, check: TableCheck | None = None):
        if kind not in _KIND_CODE:
            raise LbshapeError(f"unknown target table kind {kind!r}")
        self.kind = kind
        self.k = {"point": 1, "segment": 2, "triangle": 3}[kind]
        self.intervals = int(intervals)
        self.cells = np.ascontiguousarray(cells, dtype=float)
        self.nodes = np.asarray(nodes, dtype=float)
        self.node_weights = np.asarray(node_weights, dtype=float)
        self.check = check
        self._code = _KIND_CODE[kind]
        self._basis = np.zeros(self.cells.shape[1])
        self._reduced_cells: np.ndarray | None = None

    @property
    def dimension(self) -> int:
        """p, the number of target coordinates."""
        return int(self.cells.shape[2])

    def z(self, weights: np.ndarray) -> np.ndarray:
        """The tabulated target (p,) at weights (k,)."""
        w = self._weights(weights)
        out = np.zeros(self.dimension)
        _evaluate(self._code, self.intervals, w, self.cells, self._basis, out)
        return out

    def set_reduced_map(self, to_reduced: np.ndarray | None) -> None:
        """Precompose the linear map ``q = R z`` (R (r, p)) so that :meth:`reduced_into`
        returns reduced coordinates (r,); ``None``: return z itself."""
        if to_reduced is None:
            self._reduced_cells = self.cells
            return
        R = np.asarray(to_reduced, dtype=float)
        if R.ndim != 2 or R.shape[1] != self.dimension:
            raise LbshapeError(f"to_reduced must have shape (r, {self.dimension}), got {R.shape}")
        self._reduced_cells = np.ascontiguousarray(self.cells @ R.T)

    def mapped(self, to_reduced: np.ndarray | None) -> TargetTable:
        """A table sharing this one's nodes and check whose :meth:`reduced_into` returns
        ``R z*(w)`` (R (r, p); ``None``: z itself); this table is left as it is."""
        table = TargetTable(self.kind, self.intervals, self.cells, self.nodes,
                            self.node_weights, self.check)
        table.set_reduced_map(to_reduced)
        return table

    def reduced_into(self, weights: np.ndarray, out: np.ndarray) -> np.ndarray:
        """Write ``R z*(w)`` (r,) into ``out`` (after :meth:`set_reduced_map`)."""
        if self._reduced_cells is None:
            self.set_reduced_map(None)
        _evaluate(self._code, self.intervals, weights, self._reduced_cells, self._basis, out)
        return out

    def _weights(self, weights) -> np.ndarray:
        w = np.asarray(weights, dtype=float)
        if w.shape != (self.k,):
            raise LbshapeError(f"expected {self.k} weights, got shape {w.shape}")
        if (w < -1e-9).any() or abs(w.sum() - 1.0) > 1e-9:
            raise LbshapeError(f"weights must lie on the simplex, got {w}")
        return w

    # ---------------------------------------------------------------- storage
    def to_arrays(self, prefix: str = "target_table_") -> dict[str, np.ndarray]:
        """Arrays for the artifact cache (restored by :meth:`from_arrays`)."""
        check = self.check
        stats = (np.full(8, np.nan) if check is None else np.array(
            [check.intervals, check.nodes, check.checks, check.max_error, check.median_error,
             check.tolerance, check.separation, check.seconds], dtype=float))
        return {
            f"{prefix}kind": np.array([self._code, self.intervals], dtype=np.int64),
            f"{prefix}cells": self.cells, f"{prefix}nodes": self.nodes,
            f"{prefix}node_weights": self.node_weights, f"{prefix}check": stats,
        }

    @classmethod
    def from_arrays(cls, arrays, prefix: str = "target_table_") -> TargetTable | None:
        """The table stored by :meth:`to_arrays`, or None when ``arrays`` holds none."""
        if f"{prefix}kind" not in arrays:
            return None
        code, intervals = (int(v) for v in np.asarray(arrays[f"{prefix}kind"]))
        kind = {v: k for k, v in _KIND_CODE.items()}[code]
        stats = np.asarray(arrays[f"{prefix}check"], dtype=float)
        check = None if np.isnan(stats[0]) else TableCheck(
            int(stats[0]), int(stats[1]), int(stats[2]), *(float(v) for v in stats[3:]))
        return cls(kind, intervals, np.asarray(arrays[f"{prefix}cells"]),
                   np.asarray(arrays[f"{prefix}nodes"]),
                   np.asarray(arrays[f"{prefix}node_weights"]), check)


# ---------------------------------------------------------------------- building
def separation(offsets: np.ndarray, metric: np.ndarray | None = None) -> float:
    """``max_ij ‖z_i − z_j‖`` over the examples' coordinates (k, p); 0 for one example.

    ``metric`` (p, p): the Gram matrix ``Bᵀ M B`` of the norm (identity when None,
    e.g. for the M-orthonormal LB basis).
    """
    z = np.atleast_2d(np.asarray(offsets, dtype=float))
    best = 0.0
    for i in range(z.shape[0]):
        for j in range(i + 1, z.shape[0]):
            best = max(best, _norm(z[i] - z[j], metric))
    return best


def build_target_table(
    solver: TargetSolver,
    *,
    intervals: int | None = None,
    tolerance: float = DEFAULT_TOLERANCE,
    metric: np.ndarray | None = None,
    max_intervals: int | None = None,
    checks: int = 40,
    rng: np.random.Generator | None = None,
) -> TargetTable:
    """Tabulate the exact target of ``solver`` and check it (see the module docstring).

    Args:
        solver: the exact target solver over k <= 3 example energies (its models need
            ``force_and_tangent``); its tolerance is tightened for the table's solves.
        intervals: N to start with (default :data:`DEFAULT_INTERVALS`).
        tolerance: largest accepted error at the held-out weights, a share of the
            examples' separation.
        metric: (p, p) Gram matrix of the norm (identity when None).
        max_intervals: finest N before refusing (default :data:`MAX_INTERVALS`).
        checks: random held-out weights (besides midpoints or centroids).
        rng: generator of the random held-out weights (seeded default).

    Returns:
        The accepted :class:`TargetTable` with its :class:`TableCheck`.

    Raises:
        LbshapeError: more than 3 examples.
        TableRefused: the error stays above ``tolerance`` at ``max_intervals``.
    """
    import time

    k = solver.offsets.shape[0]
    if k not in KINDS:
        raise LbshapeError(f"a target table covers 1 to 3 examples, got {k}")
    kind = KINDS[k]
    n = DEFAULT_INTERVALS[k] if intervals is None else int(intervals)
    finest = MAX_INTERVALS[k] if max_intervals is None else int(max_intervals)
    rng = np.random.default_rng(20170402) if rng is None else rng
    exact = TargetSolver(solver.models, solver.offsets, tolerance=EXACT_TOLERANCE,
                         max_iterations=100)
    spread = separation(solver.offsets, metric)
    started = time.perf_counter()
    held_out = _held_out_weights(k, checks, rng)
    while True:
        table = _tabulate(kind, n, exact)
        errors = _check(table, exact, held_out + _cell_centres(kind, n), spread, metric)
        worst = float(errors.max()) if errors.size else 0.0
        log.info("target table (%s, N=%d, %d nodes): error max %.3g %% / median %.3g %% of "
                 "the separation at %d held-out weights", kind, n, table.nodes.shape[0],
                 100 * worst, 100 * float(np.median(errors)) if errors.size else 0.0,
                 errors.size)
        if worst <= tolerance or kind == "point":
            break
        if 2 * n > finest:
            raise TableRefused(
                f"target table error {100 * worst:.3g} % of the example separation exceeds "
                f"{100 * tolerance:g} % at the finest grid (N = {n})")
        n *= 2
    table.check = TableCheck(
        intervals=n, nodes=int(table.nodes.shape[0]), checks=int(errors.size),
        max_error=worst, median_error=float(np.median(errors)) if errors.size else 0.0,
        tolerance=float(tolerance), separation=spread, seconds=time.perf_counter() - started)
    return table


def target_slope(solver: TargetSolver, z: np.ndarray, weights: np.ndarray,
                 direction: np.ndarray) -> np.ndarray:
    """``dz*/ds`` (p,) along a weight direction d (k,) (Σd = 0), by the implicit function theorem.

    At the target, ``Σ_k w_k ∇E_k(z* − z_k) = 0``; moving the weights by ``s d`` gives
    ``H dz*/ds = −Σ_k d_k ∇E_k(z* − z_k)`` with ``H = Σ_k w_k ∇²E_k`` (p, p).
    """
    p = solver.dimension
    H = np.zeros((p, p))
    rhs = np.zeros(p)
    for w, d, model, offset in zip(weights, direction, solver.models, solver.offsets,
                                   strict=True):
        g, h = model.force_and_tangent(z - offset)
        H += w * h
        rhs -= d * g
    return np.linalg.solve(0.5 * (H + H.T), rhs)


def _tabulate(kind: str, n: int, exact: TargetSolver) -> TargetTable:
    offsets = exact.offsets
    p = offsets.shape[1]
    if kind == "point":
        return TargetTable(kind, 1, offsets[None, :1].copy(), offsets[:1].copy(), np.ones((1, 1)))
    if kind == "segment":
        t = np.linspace(0.0, 1.0, n + 1)
        weights = np.stack([1.0 - t, t], axis=1)
        values, slopes = np.zeros((n + 1, p)), np.zeros((n + 1, p))
        z = offsets[0].copy()
        for j, w in enumerate(weights):
            z = _solve(exact, w, z)
            values[j] = z
            slopes[j] = target_slope(exact, z, w, np.array([-1.0, 1.0]))
        h = 1.0 / n
        cells = np.stack([values[:-1], h * slopes[:-1], values[1:], h * slopes[1:]], axis=1)
        return TargetTable(kind, n, cells, values, weights)
    level = 3 * n
    index = {}
    grid = [(i, j) for j in range(level + 1) for i in range(level + 1 - j)]
    weights = np.array([[1.0 - (i + j) / level, i / level, j / level] for i, j in grid])
    values = np.zeros((len(grid), p))
    z = offsets[0].copy()
    for row, ((i, j), w) in enumerate(zip(grid, weights, strict=True)):
        if i == 0 and j > 0:  # new row: warm start from the node below
            z = values[index[(0, j - 1)]]
        z = _solve(exact, np.clip(w, 0.0, None) / np.clip(w, 0.0, None).sum(), z)
        values[row] = z
        index[(i, j)] = row
    local = _p3_nodes()
    cells = []
    for J in range(n):
        for I in range(n - J):
            cells.append([values[index[(3 * I + a, 3 * J + b)]] for a, b in local])
            if I + J <= n - 2:  # the upper triangle, mirrored about its (1, 1) corner
                cells.append([values[index[(3 * I + 3 - a, 3 * J + 3 - b)]] for a, b in local])
    # cells are looked up by (I, J, upper); store them in that dense order
    dense = np.zeros((n * n * 2, 10, p))
    position = 0
    for J in range(n):
        for I in range(n - J):
            dense[2 * (J * n + I)] = cells[position]
            position += 1
            if I + J <= n - 2:
                dense[2 * (J * n + I) + 1] = cells[position]
                position += 1
    return TargetTable(kind, n, dense, values, weights)


def _solve(exact: TargetSolver, w: np.ndarray, start: np.ndarray) -> np.ndarray:
    result = exact.solve(w, start=start)
    if not result.converged:
        raise LbshapeError(f"the exact target did not converge at weights {w} "
                           f"(|grad| {result.gradient_norm:.3e}): no table")
    return result.z


def _held_out_weights(k: int, count: int, rng: np.random.Generator) -> list[np.ndarray]:
    if k == 1:
        return [np.ones(1)]
    return list(rng.dirichlet(np.ones(k), size=count))


def _cell_centres(kind: str, n: int) -> list[np.ndarray]:
    """Interval midpoints or macro-triangle centroids (where interpolation is worst)."""
    if kind == "segment":
        t = (np.arange(n) + 0.5) / n
        return list(np.stack([1.0 - t, t], axis=1))
    if kind == "triangle":
        out = []
        for J in range(n):
            for I in range(n - J):
                out.append(((I + 1 / 3) / n, (J + 1 / 3) / n))
                if I + J <= n - 2:
                    out.append(((I + 2 / 3) / n, (J + 2 / 3) / n))
        return [np.array([1.0 - a - b, a, b]) for a, b in out]
    return []


def _check(table: TargetTable, exact: TargetSolver, weights, spread: float,
           metric: np.ndarray | None) -> np.ndarray:
    if not spread > 0:
        return np.zeros(0)
    errors = []
    for w in weights:
        tabulated = table.z(w)
        z = _solve(exact, w, tabulated)
        errors.append(_norm(tabulated - z, metric) / spread)
    return np.asarray(errors)


def _norm(v: np.ndarray, metric: np.ndarray | None) -> float:
    return float(np.sqrt(v @ v if metric is None else v @ metric @ v))


def _p3_nodes() -> list[tuple[int, int]]:
    """The 10 local nodes (a, b), a + b <= 3, of a cubic triangle, in the table's order."""
    return [(a, b) for b in range(4) for a in range(4 - b)]


_P3 = np.array(_p3_nodes(), dtype=np.int64)


@njit
def _evaluate(code, n, w, cells, basis, out):
    """out (d,) = Σ_i basis_i(w) cells[cell(w), i] for the table kind ``code``."""
    d = out.shape[0]
    if code == 0:
        for c in range(d):
            out[c] = cells[0, 0, c]
        return
    if code == 1:
        t = min(max(w[1], 0.0), 1.0) * n
        j = min(int(t), n - 1)
        s = t - j
        s2 = s * s
        s3 = s2 * s
        basis[0] = 2.0 * s3 - 3.0 * s2 + 1.0
        basis[1] = s3 - 2.0 * s2 + s
        basis[2] = -2.0 * s3 + 3.0 * s2
        basis[3] = s3 - s2
        cell = j
    else:
        a = max(w[1], 0.0) * n
        b = max(w[2], 0.0) * n
        total = a + b
        if total > n:  # round-off outside the triangle: scale back onto it
            a *= n / total
            b *= n / total
        i = min(int(a), n - 1)
        j = min(int(b), n - 1)
        if i + j > n - 1:
            i = n - 1 - j
        alpha = a - i
        beta = b - j
        upper = alpha + beta > 1.0 and i + j <= n - 2
        if upper:
            alpha = 1.0 - alpha
            beta = 1.0 - beta
        cell = 2 * (j * n + i) + (1 if upper else 0)
        # cubic Lagrange basis on the local barycentric grid of level 3
        l1 = 3.0 * alpha
        l2 = 3.0 * beta
        l0 = 3.0 - l1 - l2
        for m in range(10):
            na = _P3[m, 0]
            nb = _P3[m, 1]
            n0 = 3 - na - nb
            value = 1.0
            for step in range(na):
                value *= (l1 - step) / (step + 1)
            for step in range(nb):
                value *= (l2 - step) / (step + 1)
            for step in range(n0):
                value *= (l0 - step) / (step + 1)
            basis[m] = value
    for c in range(d):
        out[c] = 0.0
    for m in range(basis.shape[0]):
        coefficient = basis[m]
        for c in range(d):
            out[c] += coefficient * cells[cell, m, c]


class TableSolver:
    """A :class:`TargetTable` behind the :class:`TargetSolver` interface.

    ``solve(w)`` returns the tabulated target (0 Newton iterations); the run-time
    driver uses :attr:`table` directly (:meth:`TargetTable.reduced_into`).

    Args:
        table: the table.
        models: the exact energy models (k) the table was built from, or placeholders
            (only their number is used here).
        offsets: (k, p) the examples' coordinates z_k.
    """

    def __init__(self, table: TargetTable, models: Sequence, offsets: np.ndarray):
        self.table = table
        self.models = list(models)
        self.offsets = np.atleast_2d(np.asarray(offsets, dtype=float))
        if self.offsets.shape != (table.k, table.dimension):
            raise LbshapeError(f"offsets must have shape ({table.k}, {table.dimension}), "
                               f"got {self.offsets.shape}")

    @property
    def dimension(self) -> int:
        return self.table.dimension

    def solve(self, weights: np.ndarray, *, start: np.ndarray | None = None):
        """The tabulated target as a :class:`~lbshape.shapespace.interpolation.TargetResult`."""
        return TargetResult(self.table.z(weights), 0, float("nan"), float("nan"), True)

    def reset(self) -> None:
        """Nothing to forget (no warm start)."""
