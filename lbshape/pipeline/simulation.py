"""The engine-agnostic handle of a running scene: :class:`Simulation`.

A :class:`Simulation` holds a scene, its precompute, the method and the engine that
:mod:`lbshape.pipeline.simulate` sets up for it
(:func:`~lbshape.pipeline.simulate.reduced_simulation` for ``reduced`` and ``euclidean``,
:func:`~lbshape.pipeline.simulate.full_simulation` for ``full``), and drives it through the
engine protocol (:class:`lbshape.dynamics.engine.Engine`): the same calls, the same units
and the same (n, 3) displacement for every method::

    sim = simulation(scene, pre, method="reduced")
    for _ in range(300):
        sim.step()
    u = sim.displacement()          # (n, 3) world displacement, m
    sim.grab(vertex, target)        # a point pull, as ``lbshape live`` does
    record = sim.run(100)           # RunRecord

A run here writes nothing; ``lbshape simulate`` runs the same engine and writes its folder.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from lbshape.dynamics.engine import Drag, Engine, EngineState
from lbshape.dynamics.record import RunRecord
from lbshape.errors import LbshapeError
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.precomputed import Precomputed
from lbshape.pipeline.simulate import (
    METHODS,
    example_stiffness,
    full_simulation,
    reduced_simulation,
)
from lbshape.scene.schema import Scene

__all__ = ["DRAG_RATE", "METHODS", "Simulation", "simulation"]

#: a point pull's default stiffness per kg of the object (N/m per kg = 1/s²), as ``lbshape
#: live``'s drag
DRAG_RATE = 2000.0


class Simulation:
    """A scene running with one method: step it, read it, push it.

    Args:
        scene: the scene (dt, loads, examples, planes).
        pre: its precompute (:func:`lbshape.pipeline.precompute.precompute`).
        method: ``"reduced"`` (the paper's method), ``"euclidean"`` (the baseline: the
            same reduced dynamics, the target over every element) or ``"full"``
            (full-space FEM, the reference).
        engine: an engine to drive instead of the one the method sets up (it must follow
            :class:`lbshape.dynamics.engine.Engine`).

    Attributes:
        scene, pre, method, engine: as given (``engine``: the one built).
        drag_stiffness: a point pull's default stiffness (N/m): :data:`DRAG_RATE` times
            the object's mass (a free body's engine caps it for stability).
        has_examples: whether the scene has an example force to switch.
        examples_on: whether it acts (:meth:`set_examples`).
    """

    def __init__(self, scene: Scene, pre: Precomputed, *, method: str = "reduced",
                 engine: Engine | None = None):
        if method not in METHODS:
            raise LbshapeError(f"method must be one of {', '.join(METHODS)}; got {method!r}")
        self.scene, self.pre, self.method = scene, pre, method
        if engine is None:
            engine = (full_simulation(scene, pre) if method == "full"
                      else reduced_simulation(scene, pre, method=method))
        self.engine = engine
        self.drag_stiffness = DRAG_RATE * float(pre.material.density * pre.mesh.volume())
        self._rest = np.asarray(pre.mesh.points, dtype=float)
        self._drag: Drag | None = None
        self.has_examples = example_stiffness(scene, pre) > 0
        self.examples_on = self.has_examples

    def __repr__(self) -> str:
        return (f"Simulation(scene={self.scene.name!r}, method={self.method!r}, "
                f"n={self.n_vertices}, t={self.time:g} s)")

    # -------------------------------------------------------------- reading
    @property
    def time(self) -> float:
        """Simulated time since the start (s)."""
        return float(self.engine.time)

    @property
    def dt(self) -> float:
        """The time step (s)."""
        return float(self.engine.dt)

    @property
    def n_vertices(self) -> int:
        """n, the object's vertex count."""
        return int(self._rest.shape[0])

    @property
    def rest_points(self) -> np.ndarray:
        """(n, 3) the object's rest positions X (m), in the mesh's vertex order."""
        return self._rest

    def displacement(self) -> np.ndarray:
        """(n, 3) world displacement ``x − X`` of every vertex (m), every method (a free
        body's includes its rigid motion). n-sized: for output, not per step."""
        return np.asarray(self.engine.displacement())

    def points(self) -> np.ndarray:
        """(n, 3) world positions ``X + u`` of every vertex (m)."""
        return self._rest + self.displacement()

    def vertex_position(self, vertex: int) -> np.ndarray:
        """(3,) the world position of one vertex (m), 0 <= vertex < n."""
        return self.points()[self._check_vertex(vertex)]

    # ------------------------------------------------------------- stepping
    def step(self) -> int:
        """Advance one step of :attr:`dt`; returns its Newton iterations.

        Raises:
            SolverError: the step failed (one line naming the step); the state stays at
                the last good step.
        """
        return int(self.engine.step())

    def run(self, steps: int, *, stride: int = 1,
            on_step: Callable[[int, float, np.ndarray], None] | None = None) -> RunRecord:
        """Advance ``steps`` steps from where the simulation is.

        Args:
            steps: steps to take (>= 1).
            stride: keep every ``stride``-th state in the record (and the initial one).
            on_step: called after each step with (step index from 0, time in s, the
                engine's state: reduced coordinates, or the full engine's displacement).

        Returns:
            the :class:`~lbshape.dynamics.record.RunRecord`; a solver failure does not
            raise: the record then has ``stable=False`` and the message. Its sampled
            displacements (f, n, 3) in m: :meth:`displacements`.
        """
        return self.engine.run(steps, stride=stride, on_step=on_step)

    def displacements(self, record: RunRecord) -> np.ndarray:
        """(f, n, 3) the sampled world displacements (m) of a record of this simulation,
        as ``lbshape simulate`` stores them (``states.npz``)."""
        return self.engine.displacements(record)

    @property
    def state(self) -> EngineState:
        """A snapshot of the engine (copies) to come back to with :meth:`reset`."""
        return self.engine.state

    def reset(self, state: EngineState | None = None) -> None:
        """Back to ``state`` (from :attr:`state`), or with ``None`` to rest at t = 0 with a
        drag released; the examples switch is kept."""
        if state is None:
            self.release()
        self.engine.reset(state)

    # --------------------------------------------------------------- inputs
    def set_examples(self, on: bool) -> bool:
        """The scene's example force on or off from the next step on; returns whether it
        acts (False for a scene without examples)."""
        self.examples_on = bool(self.engine.set_examples(bool(on)))
        return self.examples_on

    def grab(self, vertex: int, target=None, stiffness: float | None = None) -> None:
        """Pull ``vertex`` towards ``target`` with a spring, from the next step on (what
        ``lbshape live``'s mouse does); replaces an earlier pull.

        Args:
            vertex: an index of the object's mesh, 0 <= vertex < n.
            target: (3,) world point (m); default: where the vertex is now.
            stiffness: the spring's stiffness in N/m; default :attr:`drag_stiffness`.
        """
        vertex = self._check_vertex(vertex)
        if target is None:
            target = self.points()[vertex]
        stiffness = self.drag_stiffness if stiffness is None else stiffness
        self._drag = Drag(vertex, np.asarray(target, dtype=float), stiffness)
        self.engine.set_drag(self._drag)

    def move(self, target) -> None:
        """Move the pulled vertex's target to ``target`` (3,) world, m (nothing without a
        pull)."""
        if self._drag is None:
            return
        self._drag = Drag(self._drag.vertex, np.asarray(target, dtype=float),
                          self._drag.stiffness)
        self.engine.set_drag(self._drag)

    def release(self) -> None:
        """Let the pulled vertex go (nothing without a pull)."""
        if self._drag is not None:
            self._drag = None
            self.engine.set_drag(None)

    @property
    def drag(self) -> Drag | None:
        """The point pull acting, or ``None``."""
        return self._drag

    def _check_vertex(self, vertex) -> int:
        n = self.n_vertices
        if isinstance(vertex, bool) or not isinstance(vertex, int | np.integer) \
                or not 0 <= int(vertex) < n:
            raise LbshapeError(f"vertex must be an index from 0 to {n - 1}, got {vertex!r}")
        return int(vertex)


def simulation(scene: Scene, pre: Precomputed | None = None, *,
               method: str = "reduced") -> Simulation:
    """A :class:`Simulation` of ``scene`` with ``method`` (``"reduced"``, ``"euclidean"``
    or ``"full"``); ``pre`` ``None``: the scene's precompute, computed or read from the
    cache (:func:`~lbshape.pipeline.precompute.precompute`)."""
    if method not in METHODS:
        raise LbshapeError(f"method must be one of {', '.join(METHODS)}; got {method!r}")
    return Simulation(scene, precompute(scene) if pre is None else pre, method=method)
