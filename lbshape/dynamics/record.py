"""The record of a simulation run: one type for the reduced and the full-space engine.

Both engines step the same way (weights + target, then one implicit step) and keep
the same things: the sampled states, the wall time of each step and of its
interpolation part, the Newton iterations, and whether the run ended on a solver
failure. :class:`RunRecorder` collects them step by step; :class:`RunRecord` is the
frozen result.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class RunRecord:
    """What a run produced (also when it stopped early).

    Attributes:
        times: (f,) sample times in s: the initial state, then every ``stride``-th step.
        states: (f, p) the engine's state at those times: reduced coordinates q
            (p = r) for the reduced engine, the node-major displacement u in m
            (p = 3n, zero on fixed vertices) for the full-space engine.
        t_interp_ms: (k,) per-step wall time of weights + target in ms.
        t_total_ms: (k,) per-step wall time of the whole step in ms.
        newton_iterations: (k,) Newton iterations per step.
        stable: False if the run stopped on a solver failure.
        message: the failure message ('' if stable).
        max_displacement: largest vertex displacement norm over every step in m, for
            engines that see full-space displacements at each step (full space);
            ``None`` otherwise.
    """

    times: np.ndarray
    states: np.ndarray
    t_interp_ms: np.ndarray
    t_total_ms: np.ndarray
    newton_iterations: np.ndarray
    stable: bool = True
    message: str = ""
    max_displacement: float | None = None

    @property
    def steps(self) -> int:
        """Number of completed steps k."""
        return int(self.t_total_ms.size)

    def mean_ms(self, *, warmup: int = 0) -> tuple[float, float]:
        """Per-step means ``(t_interp, t_total)`` in ms after ``warmup`` steps.

        With fewer than ``warmup + 1`` steps, the mean over all steps (0 without any).
        """
        def mean(values: np.ndarray) -> float:
            data = values[warmup:] if values.size > warmup else values
            return float(data.mean()) if data.size else 0.0

        return mean(self.t_interp_ms), mean(self.t_total_ms)

    def displacements(self, basis: np.ndarray | None = None) -> np.ndarray:
        """(f, n, 3) sampled displacements in m.

        Args:
            basis: (3n, p) node-major basis that maps the states to displacements
                (``U`` for reduced coordinates), or ``None`` when the states already
                are displacements (full space).
        """
        states = self.states if basis is None else self.states @ np.asarray(basis).T
        return states.reshape(len(self.times), -1, 3)


class RunRecorder:
    """Collects a run step by step; :meth:`record` freezes it into a :class:`RunRecord`.

    Args:
        stride: keep the initial state and every ``stride``-th state, ≥ 1.
    """

    def __init__(self, *, stride: int = 1):
        self.stride = int(stride)
        self._times: list[float] = []
        self._states: list[np.ndarray] = []
        self._interp: list[float] = []
        self._total: list[float] = []
        self._iterations: list[int] = []

    def start(self, t: float, state: np.ndarray) -> None:
        """The initial state (p,) at time ``t`` (s)."""
        self._times.append(float(t))
        self._states.append(np.array(state, dtype=float))

    def step(self, t: float, state: np.ndarray, *, interp_seconds: float, total_seconds: float,
             iterations: int) -> None:
        """A completed step: its end time (s), state (p,), wall times (s), Newton iterations."""
        self._interp.append(1e3 * interp_seconds)
        self._total.append(1e3 * total_seconds)
        self._iterations.append(int(iterations))
        if len(self._total) % self.stride == 0:
            self._times.append(float(t))
            self._states.append(np.array(state, dtype=float))

    def record(self, *, stable: bool = True, message: str = "",
               max_displacement: float | None = None) -> RunRecord:
        """The frozen record of what was collected so far."""
        return RunRecord(
            times=np.asarray(self._times, dtype=float),
            states=np.asarray(self._states, dtype=float),
            t_interp_ms=np.asarray(self._interp, dtype=float),
            t_total_ms=np.asarray(self._total, dtype=float),
            newton_iterations=np.asarray(self._iterations, dtype=np.int64),
            stable=bool(stable),
            message=message,
            max_displacement=None if max_displacement is None else float(max_displacement),
        )
