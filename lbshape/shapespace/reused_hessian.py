"""The example target by a modified Newton method: Hessians reused, gradients fresh.

:class:`ReusedHessianTargetSolver` minimises the same ``F(z) = Σ_k w_k E_k(z − z_k)`` as
:class:`~lbshape.shapespace.interpolation.TargetSolver`, for models that also evaluate
``energy_and_force(y) -> (E, g)`` without the Hessian (a fraction of the cost of a full
pass: the Hessian is an ``m × 3s × 6m`` product over the elements). Each model's Hessian
``H_k`` is kept from its last full evaluation; the step is ``−(Σ_k w_k H_k)⁻¹ ∇F(z)``
with the current weights and the current gradient, with the same backtracking line
search. The Hessians are evaluated again at the current point when a step needed a line
search, shrank by less than :data:`REFRESH_RATIO` against the previous one, or when the
gradient passes the observed rate ρ still needs (``log(stop/step) / log ρ``, counted
:data:`FUTURE_SOLVES` times: the next solve starts here) cost more than a full pass and
:data:`NEWTON_AFTER_REFRESH` gradient passes (by the cost model of
:data:`FULL_PASS_SCALE`; no timings, so that a run is reproducible).

Converged to the same point: the iteration stops when the step falls below
``refinement × tolerance × max_k ‖z_k‖`` (``refinement`` = 0.1 by default: a linearly
convergent iteration's remaining error is about the last step times ρ/(1 − ρ), ρ ≤
:data:`REFRESH_RATIO`, a tenth of the base solver's tolerance; the full reference's
trajectories stay within 1e-8 of the base solver's, ``docs/decisions.md``); it falls
back to the full Newton method of the base class when it has not converged after
``max_passes`` gradient passes.

The time stepping calls it once per step from the previous target with new weights: the
first step from there is the Euler–Newton predictor, the next ones correct it with cheap
gradient passes, and the Hessians are refreshed only when the target moved far enough
to slow the iteration down.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import scipy.linalg

from lbshape.errors import SolverError
from lbshape.shapespace.interpolation import EnergyModel, TargetResult, TargetSolver

#: refresh the Hessians at least when a step is more than this fraction of the previous one
REFRESH_RATIO = 0.5
#: a full pass costs about ``1 + p² / FULL_PASS_SCALE`` gradient passes (p = 3m coordinates:
#: the Hessian's ``m × 3s × 6m`` product; measured on the compiled block energy, 17× at
#: p = 30 and 5× at p = 18). A model of the costs, not a timing: runs are reproducible.
FULL_PASS_SCALE = 56.0
#: a refresh also serves the next solve (warm-started here): its saving counts this often
FUTURE_SOLVES = 2.0
#: Newton iterations expected after a refresh
NEWTON_AFTER_REFRESH = 2


class ReusedHessianTargetSolver(TargetSolver):
    """:class:`~lbshape.shapespace.interpolation.TargetSolver` by modified Newton (see the
    module docstring).

    Args:
        models: one energy model per example, with ``energy_and_force`` and
            ``energy_force_and_tangent``.
        offsets: (k, p) the examples' own coordinates z_k.
        tolerance: the base solver's step tolerance (relative to ``max_k ‖z_k‖``).
        refinement: the modified iteration stops at ``refinement × tolerance``.
        max_passes: gradient passes before the full Newton method takes over.

    Attributes:
        full_passes: full (Hessian) evaluations of a model so far.
        gradient_passes: gradient-only evaluations of a model so far.
    """

    def __init__(self, models: Sequence[EnergyModel], offsets: np.ndarray, *,
                 tolerance: float = 1e-6, refinement: float = 0.1, max_passes: int = 40):
        super().__init__(models, offsets, tolerance=tolerance)
        self.refinement = float(refinement)
        self.max_passes = int(max_passes)
        self._hessians: dict[int, np.ndarray] = {}
        self._point: tuple[np.ndarray, dict[int, tuple[float, np.ndarray]]] | None = None
        self.full_passes = 0
        self.gradient_passes = 0

    def reset(self) -> None:
        super().reset()
        self._hessians, self._point = {}, None

    def kept_arrays(self) -> dict[str, np.ndarray]:
        """What the next solve starts from besides the warm start (the Hessians and the
        values at the last point), as named arrays for an engine's snapshot."""
        out = {f"hessian{i}": H for i, H in self._hessians.items()}
        if self._point is not None:
            out["point"] = self._point[0]
            for i, (f, g) in self._point[1].items():
                out[f"energy{i}"], out[f"gradient{i}"] = np.array(f), g
        return out

    def restore_kept(self, arrays: dict[str, np.ndarray]) -> None:
        """Back to :meth:`kept_arrays` (copies), so that a restored run repeats bit for bit."""
        self._hessians = {int(k[len("hessian"):]): np.array(v) for k, v in arrays.items()
                          if k.startswith("hessian")}
        point = arrays.get("point")
        self._point = None if point is None else (np.array(point), {
            int(k[len("energy"):]): (float(v), np.array(arrays["gradient" + k[len("energy"):]]))
            for k, v in arrays.items() if k.startswith("energy")})

    def _active(self, weights: np.ndarray):
        return [(i, w) for i, w in enumerate(weights) if w > 0.0]

    def _values(self, z: np.ndarray, weights: np.ndarray, *, full: bool = False):
        """(F, ∇F) at z from the models' values there (cached at the last point; a full
        pass also stores the Hessians)."""
        cached = self._point if self._point is not None and np.array_equal(
            self._point[0], z) else (z.copy(), {})
        values = cached[1]
        for i, _ in self._active(weights):
            if i in values and not (full and i not in self._hessians):
                continue
            y = z - self.offsets[i]
            if full or i not in self._hessians:
                fk, gk, Hk = self.models[i].energy_force_and_tangent(y)
                self._hessians[i] = Hk
                self.full_passes += 1
            else:
                fk, gk = self.models[i].energy_and_force(y)
                self.gradient_passes += 1
            values[i] = (fk, gk)
        self._point = cached
        f = sum(w * values[i][0] for i, w in self._active(weights))
        g = sum(w * values[i][1] for i, w in self._active(weights))
        return float(f), np.asarray(g, dtype=float)

    def _refresh(self, z: np.ndarray, weights: np.ndarray):
        """Full passes at z: the Hessians there; returns (F, ∇F)."""
        for i, _ in self._active(weights):
            self._hessians.pop(i, None)
        self._point = None
        return self._values(z, weights)

    def _factor(self, weights: np.ndarray):
        H = sum(w * self._hessians[i] for i, w in self._active(weights))
        return _positive_factor(H)

    def solve(self, weights: np.ndarray, *, start: np.ndarray | None = None) -> TargetResult:
        weights, z = self._checked_start(weights, start)
        if self._point is None or not np.array_equal(self._point[0], z):
            self._hessians, self._point = {}, None  # not where the last solve ended
        scale = max(float(np.linalg.norm(self.offsets, axis=1).max()), 1e-300)
        fine = self.refinement * self.tolerance * scale
        f, g = self._values(z, weights)
        factor, previous, passes = None, None, 0
        while np.linalg.norm(g) > 0.0:
            if passes >= self.max_passes:  # the full Newton method from here
                return super().solve(weights, start=z)
            factor = self._factor(weights) if factor is None else factor
            step = -scipy.linalg.cho_solve(factor, g, check_finite=False)
            slope, t, slack = g @ step, 1.0, 1e-12 * abs(f)
            f_new, g_new = self._values(z + step, weights)
            passes += 1
            while not f_new <= f + 1e-4 * t * slope + slack and t > 1e-6:
                t *= 0.5
                f_new, g_new = self._values(z + t * step, weights)
                passes += 1
            if not np.isfinite(f_new):
                raise SolverError(f"target interpolation diverged (energy {f_new})")
            z, f, g = z + t * step, f_new, g_new
            size = t * np.linalg.norm(step)
            if size <= fine:
                break
            if t < 1.0 or (previous is not None and self._slow(size / previous, fine / size)):
                f, g = self._refresh(z, weights)
                factor = None
            previous = size
        self._last = z.copy()
        return TargetResult(z, passes, float(np.linalg.norm(g)), f, True)


    def _slow(self, rate: float, reduction: float) -> bool:
        """Refresh the Hessians: the rate is above :data:`REFRESH_RATIO`, or the gradient
        passes it still needs to shrink the step by ``reduction`` (< 1) cost more than a
        refresh (module docstring)."""
        if rate >= REFRESH_RATIO:
            return True
        if rate <= 0.0:
            return False
        full = 1.0 + self.dimension ** 2 / FULL_PASS_SCALE  # in gradient passes
        remaining = math.log(reduction) / math.log(rate)
        return FUTURE_SOLVES * remaining > full + NEWTON_AFTER_REFRESH


def _positive_factor(H: np.ndarray):
    """The Cholesky factor of the (symmetrised) H with the smallest Levenberg shift that
    makes it positive definite (as :func:`~lbshape.shapespace.interpolation._newton_direction`)."""
    H = 0.5 * (H + H.T)
    scale = max(float(np.max(np.abs(np.diag(H)))), 1e-300)
    identity = np.eye(H.shape[0])
    for shift in (0.0, *(scale * 10.0**e for e in range(-8, 4))):
        try:
            return scipy.linalg.cho_factor(H + shift * identity, check_finite=False)
        except np.linalg.LinAlgError:
            continue
    raise SolverError("target Hessian could not be made positive definite (non-finite values?)")
