"""An interactive run of a scene's reduced simulation (``lbshape live``), apart from its
window (:mod:`lbshape.live.window` draws it).

:class:`LiveSession` holds the engine of :func:`~lbshape.pipeline.simulate.reduced_simulation`
(a fixed object's :class:`~lbshape.dynamics.reduced.ReducedSimulation` or a free body's
:class:`~lbshape.dynamics.free_body.FreeBodySimulation`, contact planes included) and
advances it by as many steps of the scene's dt as the wall time given
(:meth:`LiveSession.advance`, paced to the clock, the debt capped so a slow frame does
not spiral). What a user does goes through its methods, whether it comes from the mouse,
a key or a scripted event: :meth:`~LiveSession.grab` / :meth:`~LiveSession.move` /
:meth:`~LiveSession.release` a drag spring on a vertex
(:class:`~lbshape.dynamics.engine.Drag`, which the engine reduces through the vertex's
three rows of U),
:meth:`~LiveSession.set_examples` on and off, :meth:`~LiveSession.pause`,
:meth:`~LiveSession.step_once`, :meth:`~LiveSession.reset` to rest. The world positions
of all vertices (n-sized) are formed only for drawing (:meth:`~LiveSession.points`).
"""

from __future__ import annotations

import contextlib
import math
import time

import numpy as np

from lbshape.dynamics.engine import Drag
from lbshape.errors import LbshapeError, SolverError
from lbshape.pipeline.precomputed import Precomputed
from lbshape.pipeline.simulate import WARMUP_STEPS, reduced_simulation
from lbshape.pipeline.simulation import DRAG_RATE
from lbshape.scene.schema import Scene

#: at most this much simulated time (s) is owed per frame: a slower frame lets the
#: simulation fall behind the clock instead of spiralling
MAX_FRAME_DEBT = 0.1


class LiveSession:
    """A scene's reduced simulation stepped on demand, with a user's drag and switches.

    Args:
        scene: the scene (its dt, loads, planes, examples).
        pre: its precompute.
        drag_stiffness: the drag spring's stiffness in N/m (default :data:`DRAG_RATE`
            times the object's mass). A free body's drag is explicit in the state: its
            engine caps it at :func:`~lbshape.dynamics.drag.explicit_stiffness_limit`.

    Attributes:
        sim: the engine.
        examples_on: whether the example force acts.
        paused: :meth:`advance` does nothing while True.
        steps: steps taken since the start (resets included).
        step_seconds: the wall time of those steps after the first
            :data:`~lbshape.pipeline.simulate.WARMUP_STEPS` (compilation) (s).
        drags: how many drags were started.
    """

    def __init__(self, scene: Scene, pre: Precomputed, *, drag_stiffness: float | None = None):
        self.scene, self.pre = scene, pre
        self.dt = float(scene.simulation.dt)
        self.mass = float(pre.material.density * pre.mesh.volume())
        stiffness = DRAG_RATE * self.mass if drag_stiffness is None else float(drag_stiffness)
        if not (math.isfinite(stiffness) and stiffness > 0):
            raise LbshapeError(f"drag stiffness must be > 0 N/m, got {drag_stiffness}")
        self.drag_stiffness = stiffness
        self.free = scene.is_free
        self._points = np.asarray(pre.mesh.points, dtype=float)
        self._basis = np.asarray(pre.U, dtype=float)
        self._body = self._points - pre.frame.center if self.free else self._points
        self.steps, self.step_seconds, self.drags = 0, 0.0, 0
        self.paused = False
        self._debt = 0.0
        self._clock = time.perf_counter
        self._warm_up()
        self.sim = reduced_simulation(scene, pre)
        self._driver, self._k_ex = self.sim.driver, self.sim.k_ex
        self.examples_on = self._driver is not None
        self.drag: Drag | None = None

    def _warm_up(self) -> None:
        """A few steps of a throwaway engine, so the compiled kernels are loaded before the
        clock starts (a stop there is left for the live engine to meet)."""
        sim = reduced_simulation(self.scene, self.pre)
        with contextlib.suppress(SolverError):
            for _ in range(WARMUP_STEPS):
                sim.step()

    # -------------------------------------------------------------- state
    @property
    def time(self) -> float:
        """Simulated time since the last reset (s)."""
        return float(self.sim.time)

    @property
    def has_examples(self) -> bool:
        """Whether the scene has an example force to switch."""
        return self._driver is not None

    @property
    def q(self) -> np.ndarray:
        """(r,) the reduced coordinates (a free body's body-frame deformation)."""
        return self.sim.q if self.free else self.sim.x

    def _pose(self) -> tuple[np.ndarray | None, np.ndarray | None]:
        """A free body's (centre of mass, rotation); (None, None) for a fixed object."""
        if not self.free:
            return None, None
        rigid = self.sim.rigid
        return rigid.center, rigid.rotation

    def center(self) -> np.ndarray | None:
        """(3,) a free body's centre of mass (m, world); ``None`` for a fixed object."""
        return self._pose()[0]

    def points(self) -> np.ndarray:
        """(n, 3) world positions of every vertex (m): ``X + U q``, a free body's
        ``c + R (X̄ + U q)`` (n-sized: for drawing only)."""
        local = self._body + (self._basis @ self.q).reshape(-1, 3)
        center, rotation = self._pose()
        return local if center is None else local @ rotation.T + center

    def vertex_position(self, vertex: int) -> np.ndarray:
        """(3,) one vertex's world position (m), from its three rows of U."""
        vertex = self._check_vertex(vertex)
        rows = self._basis[3 * vertex:3 * vertex + 3]
        local = self._body[vertex] + rows @ self.q
        center, rotation = self._pose()
        return local if center is None else center + rotation @ local

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
        self.sim.step()
        if self.steps >= WARMUP_STEPS:
            self.step_seconds += self._clock() - started
        self.steps += 1

    def advance(self, seconds: float) -> int:
        """Owe the simulation ``seconds`` of wall time (at most :data:`MAX_FRAME_DEBT` in
        all) and take the whole steps of dt it covers; nothing while paused. Returns the
        steps taken."""
        if self.paused:
            return 0
        self._debt = min(self._debt + max(float(seconds), 0.0), MAX_FRAME_DEBT)
        count = int(self._debt / self.dt + 1e-9)
        for _ in range(count):
            self.step_once()
        self._debt -= count * self.dt
        return count

    def pause(self, paused: bool | None = None) -> bool:
        """Pause (``True``), resume (``False``) or toggle (``None``); returns the new state.
        Time owed before a pause is dropped."""
        self.paused = (not self.paused) if paused is None else bool(paused)
        self._debt = 0.0
        return self.paused

    def reset(self) -> None:
        """Back to rest at t = 0; the examples switch is kept, a drag released."""
        self.drag = None
        self.sim.set_drag(None)
        self.sim.reset()
        self._debt = 0.0
        self.set_examples(self.examples_on)

    # --------------------------------------------------------------- inputs
    def set_examples(self, on: bool | None = None) -> bool:
        """Example force on (``True``), off (``False``) or toggled (``None``); returns
        whether it acts (always False for a scene without examples)."""
        on = (not self.examples_on) if on is None else bool(on)
        self.examples_on = self.sim.set_examples(on and self.has_examples)
        return self.examples_on

    def grab(self, vertex: int, target: np.ndarray | None = None) -> None:
        """Start pulling ``vertex`` towards ``target`` (3,) world, m (default: where it
        is), replacing any earlier drag."""
        vertex = self._check_vertex(vertex)
        if target is None:
            target = self.vertex_position(vertex)
        self.drag = Drag(vertex, target, self.drag_stiffness)
        self.sim.set_drag(self.drag)
        self.drags += 1

    def move(self, target: np.ndarray) -> None:
        """Pull the grabbed vertex towards ``target`` (3,) world, m (nothing without a drag)."""
        if self.drag is None:
            return
        self.drag = Drag(self.drag.vertex, target, self.drag.stiffness)
        self.sim.set_drag(self.drag)

    def release(self) -> None:
        """Let the grabbed vertex go."""
        if self.drag is not None:
            self.drag = None
            self.sim.set_drag(None)

    def _check_vertex(self, vertex) -> int:
        n = self._points.shape[0]
        if isinstance(vertex, bool) or not isinstance(vertex, int | np.integer) \
                or not 0 <= int(vertex) < n:
            raise LbshapeError(f"vertex must be an index from 0 to {n - 1}, got {vertex!r}")
        return int(vertex)
