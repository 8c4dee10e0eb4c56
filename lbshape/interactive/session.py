"""An interactive run of a scene's reduced simulation (``lbshape live``), apart from its
window (:mod:`lbshape.interactive.window` draws it).

:class:`LiveSession` is the pacing of a :class:`~lbshape.pipeline.simulation.Simulation`
(the scene's ``reduced`` method: a fixed object's or a free body's reduced engine,
contact planes included) to the wall clock: :meth:`LiveSession.advance` takes as many
steps of the scene's dt as the wall time given owes. A slow frame (a renderer that
cannot keep up) is made up by more steps in the next one — frames are dropped, never
simulated time; only when the steps themselves cannot keep up (more than
:data:`STEP_BUDGET` of wall time stepping in one call) does the simulation fall behind
the clock, owing at most :data:`MAX_DEBT` (:attr:`LiveSession.behind`). Everything a
user does — the drag (:meth:`~LiveSession.grab` / :meth:`~LiveSession.move` /
:meth:`~LiveSession.release`), the examples switch, the reset, the world points drawn —
is the :class:`~lbshape.pipeline.simulation.Simulation`'s; the session adds the pause,
one step at a time and the step timing.
"""

from __future__ import annotations

import contextlib
import math
import time

import numpy as np

from lbshape.dynamics.engine import Drag
from lbshape.errors import LbshapeError, SolverError
from lbshape.pipeline.precomputed import Precomputed
from lbshape.pipeline.simulate import WARMUP_STEPS
from lbshape.pipeline.simulation import Simulation
from lbshape.scene.schema import Scene

#: at most this much wall time (s) is spent stepping in one :meth:`LiveSession.advance`:
#: steps costing more than the time they simulate let the simulation fall behind the
#: clock instead of spiralling
STEP_BUDGET = 0.1
#: the simulated time (s) still owed after a call that ran out of :data:`STEP_BUDGET`
#: (the rest is dropped: the simulation is then behind the clock)
MAX_DEBT = 0.1


class LiveSession:
    """A scene's reduced simulation paced to the clock, with a user's drag and switches.

    Args:
        scene: the scene (its dt, loads, planes, examples).
        pre: its precompute.
        drag_stiffness: the drag spring's stiffness in N/m (default the
            :class:`~lbshape.pipeline.simulation.Simulation`'s: 2000 N/m per kg of the
            object). A free body's drag is explicit in the state: its engine caps it at
            :func:`~lbshape.dynamics.drag.explicit_stiffness_limit`.

    Attributes:
        simulation: the :class:`~lbshape.pipeline.simulation.Simulation` stepped.
        paused: :meth:`advance` does nothing while True.
        steps: steps taken since the start (resets included).
        step_seconds: the wall time of those steps after the first
            :data:`~lbshape.pipeline.simulate.WARMUP_STEPS` (compilation) (s).
        drags: how many drags were started.
        last_steps: the steps the last :meth:`advance` took.
        behind: whether the last :meth:`advance` ran out of :data:`STEP_BUDGET` and
            dropped simulated time (the simulation is behind the clock).
        dropped: simulated time dropped so far that way (s).
    """

    def __init__(self, scene: Scene, pre: Precomputed, *, drag_stiffness: float | None = None):
        self.scene, self.pre = scene, pre
        self._warm_up()
        self.simulation = Simulation(scene, pre, method="reduced")
        if drag_stiffness is not None:
            stiffness = float(drag_stiffness)
            if not (math.isfinite(stiffness) and stiffness > 0):
                raise LbshapeError(f"drag stiffness must be > 0 N/m, got {drag_stiffness}")
            self.simulation.drag_stiffness = stiffness
        self.dt = self.simulation.dt
        self.steps, self.step_seconds, self.drags = 0, 0.0, 0
        self.last_steps, self.behind, self.dropped = 0, False, 0.0
        self.paused = False
        self._debt = 0.0
        self._clock = time.perf_counter

    def _warm_up(self) -> None:
        """A few steps of a throwaway simulation, so the compiled kernels are loaded before
        the clock starts (a stop there is left for the live one to meet)."""
        warm = Simulation(self.scene, self.pre, method="reduced")
        with contextlib.suppress(SolverError):
            for _ in range(WARMUP_STEPS):
                warm.step()

    # -------------------------------------------------------------- state
    @property
    def time(self) -> float:
        """Simulated time since the last reset (s)."""
        return self.simulation.time

    @property
    def drag_stiffness(self) -> float:
        """The drag spring's stiffness (N/m)."""
        return self.simulation.drag_stiffness

    @property
    def has_examples(self) -> bool:
        """Whether the scene has an example force to switch."""
        return self.simulation.has_examples

    @property
    def examples_on(self) -> bool:
        """Whether the example force acts."""
        return self.simulation.examples_on

    @property
    def drag(self) -> Drag | None:
        """The drag acting, or ``None``."""
        return self.simulation.drag

    def points(self) -> np.ndarray:
        """(n, 3) world positions of every vertex (m) (n-sized: for drawing only)."""
        return self.simulation.points()

    def vertex_position(self, vertex: int) -> np.ndarray:
        """(3,) one vertex's world position (m)."""
        return self.simulation.vertex_position(vertex)

    def center(self, points: np.ndarray | None = None) -> np.ndarray | None:
        """(3,) a free body's centre (the mean of its world ``points``, default
        :meth:`points`), which the window's camera follows; ``None`` for a fixed object."""
        if not self.scene.is_free:
            return None
        return (self.points() if points is None else points).mean(axis=0)

    def mean_step_ms(self) -> float:
        """Mean wall time of a step after the warm-up (ms); 0 before the first."""
        timed = self.steps - WARMUP_STEPS
        return 1e3 * self.step_seconds / timed if timed > 0 else 0.0

    # ------------------------------------------------------------- stepping
    def step_once(self) -> None:
        """One step of dt (also while paused).

        Raises:
            SolverError: the engine's one-line message naming the step.
        """
        started = self._clock()
        self.simulation.step()
        if self.steps >= WARMUP_STEPS:
            self.step_seconds += self._clock() - started
        self.steps += 1

    def advance(self, seconds: float) -> int:
        """Owe the simulation ``seconds`` more of wall time and take the whole steps of dt
        it is owed, however many (a slow frame is made up, not dropped), within
        :data:`STEP_BUDGET` of wall time; out of it, at most :data:`MAX_DEBT` stays owed
        and :attr:`behind` is set. Nothing while paused. Returns the steps taken."""
        self.last_steps, self.behind = 0, False
        if self.paused:
            return 0
        self._debt += max(float(seconds), 0.0)
        started = self._clock()
        count = 0
        while self._debt >= self.dt * (1.0 - 1e-9):
            self.step_once()
            self._debt -= self.dt
            count += 1
            if self._clock() - started > STEP_BUDGET and self._debt >= self.dt:
                self.behind = True
                break
        if self.behind and self._debt > MAX_DEBT:
            self.dropped += self._debt - MAX_DEBT
            self._debt = MAX_DEBT
        self.last_steps = count
        return count

    def pause(self, paused: bool | None = None) -> bool:
        """Pause (``True``), resume (``False``) or toggle (``None``); returns the new state.
        Time owed before a pause is dropped."""
        self.paused = (not self.paused) if paused is None else bool(paused)
        self._debt = 0.0
        return self.paused

    def reset(self) -> None:
        """Back to rest at t = 0; the examples switch is kept, a drag released."""
        self.simulation.reset()
        self._debt = 0.0

    # --------------------------------------------------------------- inputs
    def set_examples(self, on: bool | None = None) -> bool:
        """Example force on (``True``), off (``False``) or toggled (``None``); returns
        whether it acts (always False for a scene without examples)."""
        on = (not self.examples_on) if on is None else bool(on)
        return self.simulation.set_examples(on and self.has_examples)

    def grab(self, vertex: int, target: np.ndarray | None = None) -> None:
        """Start pulling ``vertex`` towards ``target`` (3,) world, m (default: where it
        is), replacing any earlier drag."""
        self.simulation.grab(vertex, target)
        self.drags += 1

    def move(self, target: np.ndarray) -> None:
        """Pull the grabbed vertex towards ``target`` (3,) world, m (nothing without a drag)."""
        self.simulation.move(target)

    def release(self) -> None:
        """Let the grabbed vertex go."""
        self.simulation.release()
