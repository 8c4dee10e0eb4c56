"""Example interpolation: weights (paper eq. 5) and the nonlinear target (eqs. 4 and 6).

Weights solve ``min_w ½‖Σ_k w_k e_k − c‖²`` over the simplex ``Σw = 1, w ≥ 0``
exactly (support enumeration, k ≤ 12 examples; one implementation,
:class:`SimplexWeights`, for every method; ties go to the minimum-norm minimiser).

The target minimises ``F(z) = Σ_k w_k E_k(z − z_k)``, where ``E_k(y)`` is the elastic
energy of deforming example shape k (its rest shape reconstructed on the object's
mesh) by the displacement ``B y`` for a basis ``B``, evaluated with cubature, and
``z_k`` is example k's own coordinate (so ``E_k(0) = 0``). The routes
(:data:`ROUTES`, the one registry; scenes choose among :data:`ROUTE_CHOICES`) differ
only in the basis and the elements (``lb-exact``: see :mod:`lbshape.pipeline.routes`):

* ``modal`` (the paper's): ``B = U`` (the nonlinear modal basis), z = reduced
  coordinates q, the elastic cubature; examples enter through ``q_k = T c_k``.
* ``lb``: ``B = L`` (LB displacement basis), z = LB coefficients, a cubature
  trained on the LB displacement subspace.
* ``euclidean`` (Zhu et al. 2015 baseline): ``B = L`` with *all* elements of the
  object's mesh and unit weights.

Each ``E_k`` is any object with ``force_and_tangent(y) -> (g (p,), H (p,p))`` and
``energy(y) -> float`` (e.g. :class:`lbshape.elastic.reduced_forces.ReducedForceModel`).
The minimiser is a damped Newton method with a backtracking line search,
warm-started from the previous target.
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import scipy.linalg

from lbshape._jit import njit
from lbshape.errors import LbshapeError, SolverError

log = logging.getLogger(__name__)

#: the target routes (basis and elements of the example energies; set up per run by
#: :mod:`lbshape.pipeline.routes`)
ROUTES: tuple[str, ...] = ("lb-table", "modal", "lb", "lb-exact", "euclidean")
#: the all-element baseline route: the ``euclidean`` method's, never the reduced method's
BASELINE_ROUTE = "euclidean"
#: a scene's ``[reduced] interpolation`` choices: ``"auto"`` or a route of the reduced method
ROUTE_CHOICES: tuple[str, ...] = ("auto",) + tuple(r for r in ROUTES if r != BASELINE_ROUTE)


def resolve_route(choice: str, material_model: str) -> str:
    """The route of a :data:`ROUTE_CHOICES` entry (``auto``: ``lb-table``, the tabulated
    exact target, which falls back by itself to ``lb-exact`` or ``lb``)."""
    if choice not in ROUTE_CHOICES:
        raise LbshapeError(f"interpolation must be one of {', '.join(ROUTE_CHOICES)}, "
                           f"got {choice!r}")
    if choice == "auto":
        return "lb-table"
    return choice


class EnergyModel(Protocol):
    def energy(self, y: np.ndarray) -> float: ...

    def force_and_tangent(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...


#: at most this many examples per region (2^k − 1 supports are enumerated)
MAX_EXAMPLES = 12
#: a support's weights are feasible down to ``-FEASIBILITY_TOLERANCE`` (weights are O(1))
FEASIBILITY_TOLERANCE = 1e-12
#: two feasible supports give the same minimiser when their descriptors ``Eᵀw`` differ by
#: less than this, relative to the size of the examples and of the current descriptor
TIE_TOLERANCE = 1e-9
#: relative cut-off of the singular values of a support's (scaled) KKT matrix
_KKT_RCOND = 1e-12


def _example_matrix(examples) -> np.ndarray:
    """The (k, d) example descriptors as floats, checked (1 <= k <= MAX_EXAMPLES)."""
    E = np.asarray(examples, dtype=float)
    if E.ndim != 2 or not 1 <= E.shape[0] <= MAX_EXAMPLES:
        raise LbshapeError(f"examples must be a (k, d) array with 1 <= k <= {MAX_EXAMPLES}, "
                           f"got shape {E.shape}")
    return E


def simplex_weights(examples: np.ndarray, current: np.ndarray) -> np.ndarray:
    """Exact solution of ``min ½‖Eᵀw − c‖²`` s.t. ``Σw = 1, w ≥ 0`` (paper eq. 5).

    One call of :class:`SimplexWeights` (the one implementation, see there for the
    method and the tie rule): tied examples, e.g. identical ones, share their weight
    evenly. For repeated calls with the same examples build a :class:`SimplexWeights`
    once.

    Args:
        examples: (k, d) example descriptors (flattened), 1 <= k <= 12.
        current: (d,) the current descriptor.

    Returns:
        (k,) weights on the simplex.
    """
    E = _example_matrix(examples)
    c = np.asarray(current, dtype=float).ravel()
    if E.shape[1] != c.size:
        raise LbshapeError(
            f"example descriptors have dimension {E.shape[1]} but the current one has {c.size}"
        )
    return SimplexWeights(E)(c)


class SimplexWeights:
    """Paper eq. 5 for fixed examples, precomputed: the run-time weights in a few µs.

    The problem ``min ½‖Eᵀw − c‖²`` s.t. ``Σw = 1, w ≥ 0`` is convex: its minimisers
    share one descriptor ``Eᵀw``, and the minimiser of least norm ``‖w‖`` on one
    support is the minimum-norm solution of that support's equality-constrained KKT
    system. Everything that depends only on the examples is done once: the Gram
    matrix ``G = E Eᵀ`` (k, k), the map ``b = (E D) q`` (k, r) from reduced
    coordinates to the right-hand side ``b = E c``, and for each of the 2^k − 1
    supports S the affine solution ``w_S = P_S b + a_S``. At run time all supports
    are evaluated; among the feasible ones (``w ≥ −FEASIBILITY_TOLERANCE``) the
    least objective ``½ wᵀGw − bᵀw`` gives the minimiser's descriptor, and among
    the supports at that descriptor (within :data:`TIE_TOLERANCE`) the weights of
    least norm win. That is the one tie rule: the minimum-norm minimiser, so tied
    examples (identical ones, or any affinely dependent set the current shape
    cannot tell apart) share their weight evenly. The call writes into
    preallocated arrays (no allocation with ``out``).

    Args:
        examples: (k, d) example descriptors (flattened), 1 <= k <= 12.
        descriptor_matrix: (d, r) ``D``: the current descriptor is ``D q``; ``None``
            means the caller passes descriptors (r = d).
    """

    def __init__(self, examples: np.ndarray, descriptor_matrix: np.ndarray | None = None):
        E = _example_matrix(np.atleast_2d(np.asarray(examples, dtype=float)))
        k = E.shape[0]
        if descriptor_matrix is None:
            self.ED = np.array(E, order="C")  # (k, d)
        else:
            D = np.asarray(descriptor_matrix, dtype=float)
            if D.ndim != 2 or D.shape[0] != E.shape[1]:
                raise LbshapeError(
                    f"example descriptors have dimension {E.shape[1]}, the descriptor matrix "
                    f"shape {D.shape}")
            self.ED = np.ascontiguousarray(E @ D)  # (k, r)
        self.k = k
        self.G = E @ E.T
        scale = max(float(np.trace(self.G)) / k, 1e-300)
        supports = [np.array(c) for size in range(1, k + 1)
                    for c in itertools.combinations(range(k), size)]
        n = len(supports)
        P = np.zeros((n, k, k))
        a = np.zeros((n, k))
        for index, idx in enumerate(supports):
            size = idx.size
            kkt = np.zeros((size + 1, size + 1))
            kkt[:size, :size] = self.G[np.ix_(idx, idx)] / scale
            kkt[:size, size] = 1.0
            kkt[size, :size] = 1.0
            inverse = np.linalg.pinv(kkt, rcond=_KKT_RCOND)
            P[index, idx[:, None], idx[None, :]] = inverse[:size, :size] / scale
            a[index, idx] = inverse[:size, size]
        self._P = np.ascontiguousarray(P.reshape(n * k, k))
        self._a = a
        self._scale = scale
        # work arrays
        self.b = np.zeros(k)
        self._W = np.zeros((n, k))
        self._values = np.zeros(n)

    def __call__(self, q: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """(k,) weights for reduced coordinates q (r,) (or a descriptor, see Args)."""
        out = np.empty(self.k) if out is None else out
        if self.k == 1:
            out[0] = 1.0
            return out
        np.dot(self.ED, q, out=self.b)
        return self.from_rhs(self.b, out)

    def from_rhs(self, b: np.ndarray, out: np.ndarray) -> np.ndarray:
        """Weights (k,) from the right-hand side ``b = E c`` (k,), written into ``out``."""
        _best_support(self._P, self._a, self.G, b, self._scale, FEASIBILITY_TOLERANCE,
                      TIE_TOLERANCE, self._W, self._values, out)
        return out


@njit
def _best_support(P, a, G, b, scale, feasibility, tie, W, values, out):
    """The minimum-norm minimiser among the supports' affine solutions (see SimplexWeights).

    P (n·k, k), a (n, k), G (k, k), b (k,), scale (the mean of diag G), feasibility and
    tie the tolerances; W (n, k) and values (n,) work; out (k,) the weights.
    """
    n, k = a.shape
    best, best_value = -1, np.inf
    for s in range(n):
        feasible = True
        for i in range(k):
            value = a[s, i]
            for j in range(k):
                value += P[s * k + i, j] * b[j]
            W[s, i] = value
            if value < -feasibility:
                feasible = False
        values[s] = np.inf
        if not feasible:
            continue
        objective = 0.0
        for i in range(k):
            gw = 0.0
            for j in range(k):
                gw += G[i, j] * W[s, j]
            objective += W[s, i] * (0.5 * gw - b[i])
        values[s] = objective
        if objective < best_value:
            best, best_value = s, objective
    # ties: every feasible support whose descriptor is the best one's, least ‖w‖ wins
    b_max = 0.0
    for i in range(k):
        b_max = max(b_max, abs(b[i]))
    root = np.sqrt(scale)
    reach = tie * (root + b_max / root)  # descriptor units: |E| + |c|
    chosen, chosen_norm = best, 0.0
    for i in range(k):
        chosen_norm += W[best, i] * W[best, i]
    for s in range(n):
        if s == best or values[s] == np.inf:
            continue
        distance = 0.0  # ‖Eᵀ(w_s − w_best)‖²
        for i in range(k):
            gd = 0.0
            for j in range(k):
                gd += G[i, j] * (W[s, j] - W[best, j])
            distance += (W[s, i] - W[best, i]) * gd
        if distance > reach * reach:
            continue
        norm = 0.0
        for i in range(k):
            norm += W[s, i] * W[s, i]
        if norm < chosen_norm:
            chosen, chosen_norm = s, norm
    total = 0.0
    for i in range(k):
        out[i] = max(W[chosen, i], 0.0)
        total += out[i]
    for i in range(k):
        out[i] /= total


@dataclass(frozen=True)
class TargetResult:
    """A solved target.

    Attributes:
        z: (p,) target coordinates (reduced coordinates or LB coefficients).
        iterations: Newton iterations used.
        gradient_norm: ‖∇F‖ at the last Hessian evaluation (J per unit of z).
        energy: final F(z) in J.
        converged: False when ``max_iterations`` ended the solve before the step
            tolerance was reached (the first such solve of a solver logs a warning).
    """

    z: np.ndarray
    iterations: int
    gradient_norm: float
    energy: float
    converged: bool = True


class TargetSolver:
    """Minimise ``F(z) = Σ_k w_k E_k(z − z_k)`` by damped Newton (paper eq. 4).

    Args:
        models: one energy model per example (see the module docstring).
        offsets: (k, p) the examples' own coordinates z_k.
        tolerance: stop when the Newton step is below ``tolerance · max_k ‖z_k‖``.
        max_iterations: Newton iterations per call.
        tracking: the caller deliberately takes ``max_iterations`` warm-started steps
            per call (one per time step) and follows the target across calls: stopping
            before the tolerance is then the plan, reported by ``converged`` only, not
            logged as a warning.
    """

    def __init__(
        self,
        models: Sequence[EnergyModel],
        offsets: np.ndarray,
        *,
        tolerance: float = 1e-6,
        max_iterations: int = 20,
        tracking: bool = False,
    ):
        offsets = np.atleast_2d(np.asarray(offsets, dtype=float))
        if len(models) != offsets.shape[0]:
            raise LbshapeError(
                f"{len(models)} example energy models but {offsets.shape[0]} example offsets"
            )
        self.models = list(models)
        self.offsets = offsets
        self.tolerance = float(tolerance)
        self.max_iterations = int(max_iterations)
        self._last: np.ndarray | None = None
        self._warned = bool(tracking)

    @property
    def dimension(self) -> int:
        return int(self.offsets.shape[1])

    def energy(self, z: np.ndarray, weights: np.ndarray) -> float:
        """F(z) in J."""
        terms = zip(weights, self.models, self.offsets, strict=True)
        return float(sum(w * m.energy(z - o) for w, m, o in terms if w > 0.0))

    def gradient_and_hessian(self, z: np.ndarray, weights: np.ndarray):
        """(∇F (p,), ∇²F (p,p)) at z."""
        return self._evaluate(z, weights)[1:]

    def _evaluate(self, z: np.ndarray, weights: np.ndarray):
        """(F, ∇F, ∇²F) at z; models with ``energy_force_and_tangent`` share one pass."""
        p = self.dimension
        f, g, H = 0.0, np.zeros(p), np.zeros((p, p))
        for w, model, offset in zip(weights, self.models, self.offsets, strict=True):
            if w > 0.0:
                y = z - offset
                if hasattr(model, "energy_force_and_tangent"):
                    fk, gk, Hk = model.energy_force_and_tangent(y)
                else:
                    gk, Hk = model.force_and_tangent(y)
                    fk = model.energy(y)
                f += w * fk
                g += w * gk
                H += w * Hk
        return f, g, H

    def _checked_start(self, weights: np.ndarray, start: np.ndarray | None):
        """(weights (k,), z (p,)): the checked weights and the Newton start point — ``start``
        if given, else the last target (warm start), else the weighted examples."""
        weights = np.asarray(weights, dtype=float)
        if weights.shape != (len(self.models),):
            raise LbshapeError(f"expected {len(self.models)} weights, got shape {weights.shape}")
        if start is not None:
            return weights, np.array(start, dtype=float)
        if self._last is not None:
            return weights, self._last.copy()
        return weights, weights @ self.offsets

    def solve(self, weights: np.ndarray, *, start: np.ndarray | None = None) -> TargetResult:
        """The target for the given example weights (k,), warm-started by default.

        Stops when the Newton step is below ``tolerance`` times the size of the
        example coordinates (``max_k ‖z_k‖``), or the gradient vanishes.
        """
        weights, z = self._checked_start(weights, start)
        step_tolerance = self.tolerance * max(float(np.linalg.norm(self.offsets, axis=1).max()),
                                              1e-300)
        f, g, H = self._evaluate(z, weights)
        iterations, converged = 0, not np.linalg.norm(g) > 0.0
        while iterations < self.max_iterations and np.linalg.norm(g) > 0.0:
            iterations += 1
            step = _newton_direction(H, g)
            slope = g @ step
            t = 1.0
            f_new, g_new, H_new = self._evaluate(z + step, weights)
            # round-off slack: at the minimum a Newton step cannot lower F measurably
            slack = 1e-12 * abs(f)
            while not f_new <= f + 1e-4 * t * slope + slack and t > 1e-6:
                t *= 0.5
                f_new, g_new, H_new = self._evaluate(z + t * step, weights)
            if not np.isfinite(f_new):
                raise SolverError(f"target interpolation diverged (energy {f_new})")
            z, f, g, H = z + t * step, f_new, g_new, H_new
            if t * np.linalg.norm(step) <= step_tolerance or not np.linalg.norm(g) > 0.0:
                converged = True
                break
        self._last = z.copy()
        if not converged and not self._warned:
            self._warned = True
            log.warning("target interpolation stopped at max_iterations=%d before its step "
                        "tolerance (|grad| = %.3e); later occurrences are not logged",
                        self.max_iterations, float(np.linalg.norm(g)))
        return TargetResult(z, iterations, float(np.linalg.norm(g)), f, converged)

    def reset(self) -> None:
        """Forget the warm start."""
        self._last = None


def _newton_direction(H: np.ndarray, g: np.ndarray) -> np.ndarray:
    """−(H + μI)⁻¹g with the smallest Levenberg shift μ ∈ {0, 1e-8, 1e-7, …, 1e3}·scale
    that makes the (symmetrised) Hessian positive definite (scale = largest |H_ii|)."""
    H = 0.5 * (H + H.T)
    scale = max(float(np.max(np.abs(np.diag(H)))), 1e-300)
    identity = np.eye(H.shape[0])
    for shift in (0.0, *(scale * 10.0**e for e in range(-8, 4))):
        try:
            factor = scipy.linalg.cho_factor(H + shift * identity, check_finite=False)
        except np.linalg.LinAlgError:
            continue
        return -scipy.linalg.cho_solve(factor, g, check_finite=False)
    raise SolverError("target Hessian could not be made positive definite (non-finite values?)")
