"""The one protocol of the three simulation engines.

:class:`~lbshape.dynamics.reduced.ReducedSimulation` (a fixed object, reduced),
:class:`~lbshape.dynamics.free_body.FreeBodySimulation` (a free body, reduced) and
:class:`~lbshape.dynamics.full.FullSpaceSimulator` (full-space FEM, the reference) are
driven the same way: :meth:`Engine.step` advances one step of ``dt``, :meth:`Engine.run`
many (a solver failure ends the record with ``stable=False``), :meth:`Engine.displacement`
gives the world displacement of every vertex (:meth:`Engine.displacements` those of a
run's record), :attr:`Engine.phases` names the timed parts of a step, :attr:`Engine.state` and
:meth:`Engine.reset` take and restore snapshots, and the example force and a user's point
pull (:class:`Drag`) are switched by :meth:`Engine.set_examples` and
:meth:`Engine.set_drag`, which each engine maps to its own forces.
"""

from __future__ import annotations

import contextlib
import gc
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from lbshape.dynamics.record import RunRecord
from lbshape.errors import LbshapeError


@dataclass(frozen=True)
class NewtonSettings:
    """The Newton settings of an engine's time step (one name for every engine).

    Attributes:
        rtol: relative residual tolerance at which a step is accepted (dimensionless).
        max_iterations: Newton updates before a step fails (a
            :class:`~lbshape.errors.SolverError` naming the step and time).
    """

    rtol: float
    max_iterations: int

    def __post_init__(self):
        rtol, iterations = float(self.rtol), self.max_iterations
        if not (np.isfinite(rtol) and rtol > 0):
            raise LbshapeError(f"Newton rtol must be > 0, got {self.rtol}")
        if isinstance(iterations, bool) or int(iterations) != iterations or iterations < 1:
            raise LbshapeError(f"Newton max_iterations must be an integer >= 1, got "
                               f"{iterations}")
        object.__setattr__(self, "rtol", rtol)
        object.__setattr__(self, "max_iterations", int(iterations))


@dataclass(frozen=True)
class EngineState:
    """An opaque snapshot of an engine (copies), for :attr:`Engine.state` and
    :meth:`Engine.reset`: restoring it continues bit for bit as the engine did from it.

    Attributes:
        time: the engine's time (s).
        arrays: the engine's state and step caches by name (copies; scalars as 0-d arrays).
    """

    time: float
    arrays: Mapping[str, np.ndarray] = field(default_factory=dict)


@dataclass(frozen=True)
class Drag:
    """A point pull, engine independent: a spring of ``stiffness`` pulling vertex
    ``vertex`` towards the world point ``target``.

    Attributes:
        vertex: the vertex's index in the object's mesh.
        target: (3,) the world point it is pulled towards (m).
        stiffness: the spring's stiffness k (N/m), > 0.
    """

    vertex: int
    target: np.ndarray
    stiffness: float

    def __post_init__(self):
        target = np.array(self.target, dtype=float).reshape(3)
        if not np.isfinite(target).all():
            raise LbshapeError(f"drag target must be a finite 3-vector, got {self.target!r}")
        stiffness = float(self.stiffness)
        if not (np.isfinite(stiffness) and stiffness > 0):
            raise LbshapeError(f"drag stiffness must be > 0 N/m, got {self.stiffness}")
        if isinstance(self.vertex, bool) or int(self.vertex) != self.vertex or self.vertex < 0:
            raise LbshapeError(f"drag vertex must be an index >= 0, got {self.vertex!r}")
        target.flags.writeable = False
        object.__setattr__(self, "target", target)
        object.__setattr__(self, "stiffness", stiffness)
        object.__setattr__(self, "vertex", int(self.vertex))


#: called after each step of a run with (step index from 0, time in s, the engine's state:
#: reduced coordinates q (r,), or the full engine's displacement (n, 3) in m)
OnStep = Callable[[int, float, np.ndarray], None]


@runtime_checkable
class Engine(Protocol):
    """What every simulation engine offers (see the module docstring).

    Attributes:
        dt: the time step (s).
        newton: the step's :class:`NewtonSettings`.
        phases: the names of the parts of a step an engine times (the columns of its
            ``phase_seconds`` after a :meth:`run`); empty for an engine that times none.
    """

    dt: float
    newton: NewtonSettings
    phases: tuple[str, ...]

    @property
    def time(self) -> float:
        """Time since the start (s)."""
        ...

    def step(self) -> int:
        """Advance one step of ``dt``; return its Newton iterations.

        Raises:
            SolverError: the step failed; the message names the step and its time, and
                the state stays at the last good step.
        """
        ...

    def run(self, steps: int, *, stride: int = 1, on_step: OnStep | None = None) -> RunRecord:
        """Advance ``steps`` steps keeping every ``stride``-th state (and the initial one);
        never raises on a solver failure: the record then has ``stable=False`` and the
        message."""
        ...

    def displacement(self) -> np.ndarray:
        """(n, 3) world displacement ``x − X`` of every vertex (m); n-sized: for output."""
        ...

    def displacements(self, record: RunRecord) -> np.ndarray:
        """(f, n, 3) the world displacements (m) at the sampled times of a record of this
        engine (its :meth:`run`), whatever its states are."""
        ...

    @property
    def state(self) -> EngineState:
        """A snapshot (copies) of the state and the step's caches."""
        ...

    def reset(self, state: EngineState | None = None) -> None:
        """Back to ``state`` (from :attr:`state`), or with ``None`` to the initial state
        at t = 0; the switched forces (examples, drag) stay as they are."""
        ...

    def set_examples(self, on: bool) -> bool:
        """The configured example force on or off from the next step on; returns whether
        it acts (False without examples)."""
        ...

    def set_drag(self, drag: Drag | None) -> None:
        """A point pull from the next step on, or ``None`` to release it."""
        ...


def snapshot(time: float, arrays: Mapping[str, np.ndarray],
             scalars: Mapping[str, float | int]) -> EngineState:
    """An :class:`EngineState` of copies of ``arrays`` and the ``scalars`` (0-d arrays)."""
    copies = {name: np.array(value, copy=True) for name, value in arrays.items()}
    for name, value in scalars.items():
        copies[name] = np.array(value)
    return EngineState(float(time), copies)


def restore_arrays(state: EngineState, arrays: Mapping[str, np.ndarray]) -> dict:
    """Copy ``state``'s arrays into the live ``arrays`` (in place, same names); returns the
    remaining entries (the scalars, as Python numbers).

    Raises:
        LbshapeError: the state is not one of this engine (names or shapes differ).
    """
    saved = dict(state.arrays)
    for name, live in arrays.items():
        value = saved.pop(name, None)
        if value is None or np.shape(value) != live.shape:
            raise LbshapeError(f"the state does not fit this engine (array {name!r})")
        live[...] = value
    return {name: value.item() if value.ndim == 0 else value for name, value in saved.items()}


def check_run(steps: int, stride: int) -> tuple[int, int]:
    """``(steps, stride)`` as integers ≥ 1 (the arguments of :meth:`Engine.run`)."""
    steps, stride = int(steps), int(stride)
    if steps < 1 or stride < 1:
        raise LbshapeError(f"steps and stride must be >= 1, got {steps} and {stride}")
    return steps, stride


@contextlib.contextmanager
def collector_paused() -> Iterator[None]:
    """Python's cyclic garbage collector paused for a reduced run's steps, its state
    restored after. A reduced step makes no reference cycles, but what it allocates
    counts towards the collector's thresholds, and a full collection of the process's
    objects can land among the steps: one of 160,000 objects (a ``lbshape simulate``
    process) took 60-70 ms inside bar-s-cuboid's run, 0.045 ms on each of its steps and
    a 60 ms stall in a real-time loop."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def forget_warm_starts(owner) -> None:
    """Forget the target solvers' warm starts of an example driver or force (so a reset
    run solves its targets as the first run did): ``owner.solver`` and the solvers of
    ``owner.drivers``; anything else is stateless."""
    if owner is None:
        return
    solver = getattr(owner, "solver", None)
    if solver is not None and hasattr(solver, "reset"):
        solver.reset()
    for driver in getattr(owner, "drivers", ()):
        forget_warm_starts(driver)
    for solver in getattr(owner, "solvers", ()):
        solver.reset()


def basis_rows(basis: np.ndarray | None, vertex: int, what: str) -> np.ndarray:
    """(3, r) the rows ``U[3i:3i+3]`` of vertex i of the basis (3n, r)."""
    if basis is None:
        raise LbshapeError(f"{what} needs the basis U (give the engine basis=...)")
    n = basis.shape[0] // 3
    if not 0 <= vertex < n:
        raise LbshapeError(f"vertex must be an index from 0 to {n - 1}, got {vertex}")
    return basis[3 * vertex:3 * vertex + 3]
