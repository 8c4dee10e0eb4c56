"""The example-driven force at run time (paper run-time steps 1–3), m/r/s-sized only.

Per step, from the reduced coordinates q (r,):

1. LB descriptor of the current shape: ``d = D q`` (3m,) with ``D`` precomputed
   (λ-weighted LB coefficients of ``U q``; no n-sized array is touched);
2. example weights ``w`` from :func:`lbshape.shapespace.interpolation.simplex_weights`;
3. target coordinates ``z*`` from the warm-started :class:`TargetSolver` and the
   target in reduced coordinates ``q* = R z*`` (``R`` = identity for the modal
   route, the direct projection ``T`` for routes that solve in LB coefficients);
4. the force is ``f_ex = k_ex (q* − q)`` (paper: linear force), applied as the
   conservative-like term ``+k_ex (q − q*)`` with tangent ``k_ex I`` in the
   stepper.

With several regions (local examples), each region has its own driver and the
forces add up.

Run-time path (:meth:`ExampleDriver.target_into`): the weights come from the
precomputed :class:`~lbshape.shapespace.interpolation.SimplexWeights` and, when the
solver is a tabulated target (:class:`~lbshape.shapespace.target_table.TableSolver`),
``q*`` is one table evaluation written into the caller's array; nothing is allocated.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from lbshape.errors import LbshapeError
from lbshape.shapespace.interpolation import SimplexWeights, TargetSolver


@dataclass(frozen=True)
class TargetInfo:
    """What one call of :meth:`ExampleDriver.target` found.

    Attributes:
        q_target: (r,) target in reduced coordinates.
        weights: (k,) example weights.
        iterations: Newton iterations of the target solve.
        seconds: wall time of weights + target (s).
    """

    q_target: np.ndarray
    weights: np.ndarray
    iterations: int
    seconds: float


class ExampleDriver:
    """Weights and target for one region's examples.

    Args:
        descriptor_matrix: (3m, r) ``D``: LB descriptor of the current shape is ``D q``.
        example_descriptors: (k, 3m) descriptors of the examples (same convention).
        solver: the target solver over k example energies in coordinates z (p,).
        to_reduced: (r, p) ``R`` mapping target coordinates to reduced coordinates;
            ``None`` means z already are reduced coordinates (p = r).
    """

    def __init__(
        self,
        descriptor_matrix: np.ndarray,
        example_descriptors: np.ndarray,
        solver: TargetSolver,
        *,
        to_reduced: np.ndarray | None = None,
    ):
        self.D = np.ascontiguousarray(descriptor_matrix, dtype=float)
        self.examples = np.atleast_2d(np.asarray(example_descriptors, dtype=float))
        if self.examples.shape[1] != self.D.shape[0]:
            raise LbshapeError(
                f"example descriptors have dimension {self.examples.shape[1]}, "
                f"the object's descriptor {self.D.shape[0]}"
            )
        if self.examples.shape[0] != len(solver.models):
            raise LbshapeError("one example energy model per example descriptor is required")
        self.solver = solver
        self.R = None if to_reduced is None else np.ascontiguousarray(to_reduced, dtype=float)
        p = solver.dimension
        expected = (self.D.shape[1], p)
        if self.R is not None and self.R.shape != expected:
            raise LbshapeError(f"to_reduced must have shape {expected}, got {self.R.shape}")
        if self.R is None and p != self.D.shape[1]:
            raise LbshapeError(f"target dimension {p} differs from r={self.D.shape[1]}")
        self._weights = SimplexWeights(self.examples, self.D)
        #: (k,) the weights of the last :meth:`target_into` call
        self.w = np.zeros(self.examples.shape[0])
        #: Newton iterations of the last :meth:`target_into` call
        self.iterations = 0
        self._table = getattr(solver, "table", None)

    @property
    def k(self) -> int:
        """Number of examples."""
        return int(self.examples.shape[0])

    def weights(self, q: np.ndarray) -> np.ndarray:
        """(k,) example weights for the current reduced coordinates q (r,)."""
        return self._weights(np.asarray(q, dtype=float), np.empty(self.k))

    def weights_into(self, q: np.ndarray) -> np.ndarray:
        """Weights for q (r,) written into :attr:`w` (returned)."""
        return self._weights(q, self.w)

    def target_from_weights_into(self, out: np.ndarray) -> None:
        """``q*`` (r,) for the weights in :attr:`w`, written into ``out``."""
        if self._table is not None:
            self._table.reduced_into(self.w, out)
            self.iterations = 0
            return
        result = self.solver.solve(self.w)
        self.iterations = result.iterations
        if self.R is None:
            out[:] = result.z
        else:
            np.dot(self.R, result.z, out=out)

    def target_into(self, q: np.ndarray, out: np.ndarray) -> None:
        """Weights (into :attr:`w`) and ``q*`` (r,) into ``out`` for reduced coordinates q (r,)."""
        self._weights(q, self.w)
        self.target_from_weights_into(out)

    def target(self, q: np.ndarray) -> TargetInfo:
        """Weights, target and timing for the current reduced coordinates q (r,)."""
        started = time.perf_counter()
        q_target = np.zeros(self.D.shape[1])
        self.target_into(np.asarray(q, dtype=float), q_target)
        return TargetInfo(q_target, self.w.copy(), self.iterations,
                          time.perf_counter() - started)
