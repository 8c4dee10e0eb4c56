"""A free body whose impact columns act only around its impacts (:class:`ImpactSwitchedBody`).

A basis ending with impact columns (:mod:`lbshape.pipeline.impact_columns`) holds the
local crush of an impact, but it costs its extra coordinates on every step, also while
the body flies or rests (the Figure 4 bar without its example: 1.76 ms a step at rest
with 26 columns against 0.95 without, ``docs/decisions.md``). The columns are the trailing
k of the basis ``[U₀ V]`` and its leading r₀ columns are the plain basis, so two
:class:`~lbshape.dynamics.free_body.FreeBodySimulation` engines, one on U₀ (plain) and
one on ``[U₀ V]`` (columns), can hand one state to each other. Per hull feature
(``reduced.impact_columns_per = "feature"``) V is t sets of k, one engine on ``[U₀ V_j]``
a set (:class:`ColumnSet`), and a hit switches on the set of the feature it hits
(:meth:`ImpactSwitchedBody.choose_set`; per pair of neighbouring features,
``"feature-pair"``, the set of the pair nearest the hit, so that a hit on the border of
two features takes the same set from either side); a hit with another feature while on
a set (a step that starts clear of every plane) is taken again on that feature's set:

- **On at a contact's onset.** The plain engine steps while the body flies. A step that
  starts clear of every plane and ends touching one, with the body's kinetic energy at
  least :data:`ONSET_KINETIC_SHARE` of the design impact's, is taken back (the plain
  engine's state before it, kept in a copy of its 18 + 4 r₀ floats) and taken again by
  the columns' engine, which starts with the columns at their static answer to the
  deformation and the example spring, ``(K_zz + k_ex I) z = k_ex z* − K_zq q`` (the
  columns couple to q linearly: :class:`~lbshape.elastic.column_forces.ColumnForceModel`;
  z* the columns' part of the last example target), and ``ż = A q̇``, ``z̈ = A q̈`` with
  ``A = −(K_zz + k_ex I)⁻¹ K_zq``. The design impact is the body at the speed it
  reaches its planes at (the speed the columns' throws are made for): ``½ m v²``.
- **Off once the body rests.** The columns' engine hands the state back when the body
  has touched a plane at the end of every step for :data:`REST_HOLD` s and its kinetic
  energy (rigid, the rotation's on the rest inertia, and deformation) is below
  :data:`REST_KINETIC_SHARE` of the design impact's: the plain engine takes q, q̇, q̈
  as the leading coordinates (the columns' share of a resting body's crush is dropped
  with them).

Either hand-over keeps the rigid state (c, p, R, L), the time, the step count and the
energy monitor's work and initial energy; the receiving engine computes its elastic
force and energy at the state and evaluates its contact afresh. The engine protocol
(:mod:`lbshape.dynamics.engine`) sees one body on the columns' basis: :attr:`q` is
(r,), the plain engine's with ``z = 0``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from lbshape.dynamics.engine import Drag, EngineState
from lbshape.dynamics.free_body import PHASES, FreeBodySimulation, run_free_body
from lbshape.dynamics.free_body_record import FreeBodyRecord
from lbshape.dynamics.rigid_frame import RigidState
from lbshape.errors import LbshapeError
from lbshape.geometry.hull_directions import hull_points

#: a contact's onset hands the body to the columns' engine when its kinetic energy is
#: at least this share of the design impact's ``½ m v²`` (v the speed the body reaches its
#: planes at, :func:`~lbshape.pipeline.impact_columns.throw_speed`): a fifth of v. A
#: slower touch (a resting body's small hops) stays on the plain basis
ONSET_KINETIC_SHARE = 0.04
#: the columns' engine hands the body back after it has touched a plane at the end of
#: every step for this long (s) ...
REST_HOLD = 0.05
#: ... with its kinetic energy below this share of the design impact's (a tenth of its
#: speed): on the built-in free bodies' runs the same errors against full as 1e-3, and the
#: car with examples, rocking under its pull, back on its plain basis at 1.5 s instead of
#: 1.8 s (``docs/decisions.md``)
REST_KINETIC_SHARE = 1e-2

#: the state the engines hand over besides the body's arrays
_CARRIED = ("time", "steps_taken", "work", "energy0", "total_sweeps", "sweeps", "substeps",
            "k_ex")


class LeadingDriver:
    """The columns' example driver (weights from q (r,), target q* (r,)) as the plain
    engine reads it: weights from the leading coordinates q₀ (r₀,) with the columns at
    zero, the target's leading r₀ entries.

    Args:
        driver: the driver of the whole basis (``weights_into``,
            ``target_from_weights_into``).
        r: the whole basis's coordinates; ``leading``: r₀.
    """

    def __init__(self, driver, r: int, leading: int, slots: np.ndarray | None = None):
        self.driver, self.leading = driver, int(leading)
        #: the whole basis's columns this engine runs on, in its order (its leading r₀)
        self.slots = np.arange(self.leading) if slots is None else np.asarray(slots)
        self.drivers = (driver,)  # its warm starts are the driver's
        self._q, self._target = np.zeros(r), np.zeros(r)

    @property
    def w(self) -> np.ndarray:
        """(k,) the weights of the last call."""
        return self.driver.w

    def weights_into(self, q: np.ndarray) -> np.ndarray:
        """The weights for the engine's q (its :attr:`slots`) into :attr:`w` (returned)."""
        self._q[self.slots] = q
        return self.driver.weights_into(self._q)

    def target_from_weights_into(self, out: np.ndarray) -> None:
        """The :attr:`slots` entries of ``q*`` for the weights in :attr:`w` into ``out``."""
        self.driver.target_from_weights_into(self._target)
        out[:] = self._target[self.slots]

    def target_entries(self, slots: np.ndarray) -> np.ndarray:
        """(k,) the last target's entries of the whole basis's columns ``slots`` (0 before
        the first)."""
        return self._target[slots]


class ColumnSet(NamedTuple):
    """One set of impact columns and the engine on the plain basis with them."""

    engine: FreeBodySimulation  #: on ``[U₀ V_S]`` (r₀ + k columns)
    slots: np.ndarray  #: (k,) the set's columns V_S in the whole basis
    #: (3,) the rest-frame normals of the planes its features' throws hit, summed (one
    #: feature: its normal); None: the only set
    direction: np.ndarray | None = None


class ImpactSwitchedBody:
    """One free body on a plain engine and one or more column sets, the columns on around
    its impacts (see the module docstring).

    Args:
        plain: the engine on the leading r₀ columns U₀.
        sets: the :class:`ColumnSet` s: one on the whole basis ``[U₀ V]``, or one per hull
            feature or pair of features (each with its direction), same scene.
        coupling: (r, r) ``Uᵀ K₀ U`` of the whole basis (1/s²).
        impact_speed: v, the speed the body reaches its planes at (m/s, > 0).
        basis: (3n, r) the whole basis, and ``frame`` its frame tensors, where the sets
            are several (one set: its engine's).

    Attributes:
        columns_on: a set's engine is the one stepping (:attr:`columns`).
        onsets, rests: hand-overs to a set's engine (taken-back steps) and back.
        column_steps: steps the sets' engines took.
    """

    phases: tuple[str, ...] = PHASES  #: the parts of a step timed in ``phase_seconds``

    def __init__(self, plain: FreeBodySimulation, sets, coupling: np.ndarray,
                 impact_speed: float, *, basis: np.ndarray | None = None, frame=None):
        sets = list(sets)
        coupling = np.asarray(coupling, dtype=float)
        r0, r = plain.r, coupling.shape[0]
        if not sets or plain.contact is None or any(
                s.engine.contact is None or s.engine.r != r0 + len(s.slots) or not len(s.slots)
                for s in sets) or (len(sets) > 1 and any(s.direction is None for s in sets)):
            raise LbshapeError(f"an impact switch needs engines with contact, each set's on "
                               f"the plain engine's {r0} columns and its own, and a "
                               "direction for each of several sets")
        self.plain, self.sets, self._set = plain, sets, 0
        self.r, self.leading = r, r0
        #: per set: (k, k) K_zz and (k, r₀) K_zq, the columns' rest stiffness and coupling
        self._blocks = [(coupling[np.ix_(s.slots, s.slots)].copy(),
                         coupling[s.slots, :r0].copy()) for s in sets]
        #: (t, 3) the sets' directions (one set: none to choose from)
        self._directions = (None if len(sets) == 1
                            else np.array([s.direction for s in sets], dtype=float))
        self._whole = len(sets) == 1 and np.array_equal(sets[0].slots, np.arange(r0, r))
        self._basis = sets[0].engine.basis if basis is None else basis
        self._frame = sets[0].engine.frame if frame is None else frame
        if not (math.isfinite(impact_speed) and impact_speed > 0):
            raise LbshapeError(f"the impact speed must be > 0 m/s, got {impact_speed}")
        #: ½ m v² of the design impact (J)
        self.impact_energy = 0.5 * plain.frame.mass * float(impact_speed) ** 2
        self._held_steps = max(1, math.ceil(REST_HOLD / plain.dt * (1 - 1e-12)))
        self._q, self._qd = np.zeros(r), np.zeros(r)
        self._saved = np.zeros(max(e.engine._now.data.size for e in sets))
        self._mass = float(plain.frame.mass)
        self._inverse_inertia = np.linalg.inv(plain.frame.inertia0)
        self._spin, self._omega = np.zeros(3), np.zeros(3)
        # the hull's points about the centre (body frame): which plane a hit touches
        self._hull = hull_points(plain.rest_points) - plain.frame.center
        self.phase_seconds = np.zeros((0, len(PHASES)))
        self._initial = self._start()

    def _start(self) -> EngineState:
        """The state at t = 0 (the plain engine's, the switch's counters at zero)."""
        state = self.plain._now
        touching = self.plain.contact.evaluate(state.c, state.R, state.q, rigid=False).active
        self.columns_on, self.onsets, self.rests, self.column_steps = False, 0, 0, 0
        self._touching, self._held, self._set = bool(touching > 0), 0, 0
        return self.state

    # ------------------------------------------------------------- protocol
    @property
    def columns(self) -> FreeBodySimulation:
        """The engine of the set chosen last (the only one: always)."""
        return self.sets[self._set].engine

    @property
    def active(self) -> FreeBodySimulation:
        """The engine that steps now."""
        return self.columns if self.columns_on else self.plain

    @property
    def per_feature(self) -> bool:
        """Several sets, one per hull feature, chosen at each hit."""
        return self._directions is not None

    @property
    def engines(self) -> list[FreeBodySimulation]:
        """The plain engine and every set's."""
        return [self.plain] + [s.engine for s in self.sets]

    @property
    def dt(self) -> float:
        return self.plain.dt

    @property
    def newton(self):
        return self.plain.newton

    @newton.setter
    def newton(self, settings) -> None:
        for engine in self.engines:
            engine.newton = settings

    @property
    def time(self) -> float:
        return self.active.time

    @property
    def steps_taken(self) -> int:
        return self.active.steps_taken

    @property
    def q(self) -> np.ndarray:
        """(r,) the deformation on the whole basis (the plain engine's: columns at 0)."""
        return self._lifted(self.active.q, self._q)

    @property
    def qd(self) -> np.ndarray:
        """(r,) its rate."""
        return self._lifted(self.active.qd, self._qd)

    def _lifted(self, value: np.ndarray, out: np.ndarray) -> np.ndarray:
        if self.columns_on and self._whole:
            return value
        out[:] = 0.0
        out[:self.leading] = value[:self.leading]
        if self.columns_on:
            out[self.sets[self._set].slots] = value[self.leading:]
        return out

    @property
    def rigid(self) -> RigidState:
        return self.active.rigid

    @property
    def basis(self) -> np.ndarray:
        """(3n, r) the whole basis."""
        return self._basis

    @property
    def frame(self):
        """The whole basis's frame tensors."""
        return self._frame

    def omega(self) -> np.ndarray:
        return self.active.omega()

    def energy(self) -> float:
        return self.active.energy()

    def __getattr__(self, name: str):
        """The scene's parts every engine shares (``loads``, ``rest_points`` …) from the
        current set's engine, the whole basis's example driver, the step's read-outs
        (``sweeps``, ``substeps``, ``contact``, ``elastic`` …) from the one that steps."""
        if name == "driver":
            driver = self.plain.driver
            return driver.driver if isinstance(driver, LeadingDriver) else driver
        if name in ("rest_points", "loads", "load_reach", "omega_max",
                    "warnings", "contact_substeps", "contact_dt", "configured_k_ex",
                    "example_ramp"):
            return getattr(self.columns, name)
        if name in ("sweeps", "substeps", "total_sweeps", "contact", "elastic", "k_ex",
                    "_marks", "_depth", "flight_passes", "drag"):
            return getattr(self.active, name)
        raise AttributeError(name)

    def step(self, index: int | None = None) -> int:
        """One step of :attr:`dt` (see the module docstring); returns its Newton
        iterations. A step taken back counts its wall time as the retaken step's
        overhead."""
        engine = self.active
        if self._touching or (self.columns_on and self._directions is None):
            iterations = engine.step(index)
            return self._after_step(engine, iterations)
        saved = self._save(engine)
        iterations = engine.step(index)
        if not engine.contact.scalars[1] > 0:
            return self._after_step(engine, iterations)
        if self.kinetic_energy(engine) < ONSET_KINETIC_SHARE * self.impact_energy:
            self._touching = True  # a slow touch: the basis it is on holds it
            return self._after_step(engine, iterations)
        chosen = self.choose_set(engine)
        if self.columns_on and chosen == self._set:
            return self._after_step(engine, iterations)
        started = engine._marks[0]
        self._restore(engine, saved)
        self.switch_columns(False, count=False)
        self._set = chosen
        self.switch_columns(True)
        iterations = self.columns.step(index)
        marks = self.columns._marks
        marks[:-1] -= marks[0] - started  # the taken-back step's time: overhead
        return self._after_step(self.columns, iterations)

    def _save(self, engine: FreeBodySimulation) -> dict:
        """The engine's state before a step that may be taken back."""
        np.copyto(self._saved[:engine._now.data.size], engine._now.data)
        return {name: getattr(engine, name) for name in _CARRIED + ("_elastic_energy",)}

    def _restore(self, engine: FreeBodySimulation, saved: dict) -> None:
        engine._now.data[:] = self._saved[:engine._now.data.size]
        for name, value in saved.items():
            setattr(engine, name, value)

    def _after_step(self, engine: FreeBodySimulation, iterations: int) -> int:
        """Count the steps the body has touched a plane at their end (on a set: hand it
        back once it rests); returns ``iterations``."""
        touching = engine.contact.scalars[1] > 0
        self._touching = bool(touching)
        if not self.columns_on:
            return iterations
        self.column_steps += 1
        self._held = self._held + 1 if touching else 0
        if self._held >= self._held_steps and (
                self.kinetic_energy(engine) <= REST_KINETIC_SHARE * self.impact_energy):
            self.switch_columns(False)
        return iterations

    def choose_set(self, engine: FreeBodySimulation) -> int:
        """The set for a hit of the body of ``engine`` (its state now): the one whose
        direction (:attr:`ColumnSet.direction`) is nearest the body-frame normal n of the
        plane the body is deepest behind (or nearest: its hull's points), the largest
        ``d · n``: per feature the nearest throw's normal, per pair the pair whose
        normals' cosines to n sum largest; the only set when there is one."""
        if self._directions is None:
            return 0
        state, planes = engine._now, engine.contact
        world = state.c + self._hull @ state.R.T
        gaps = np.einsum("pj,hj->ph", planes.normals, world).min(axis=1) - np.einsum(
            "pj,pj->p", planes.normals, planes.points)
        normal = state.R.T @ planes.normals[int(np.argmin(gaps))]  # body frame
        return int(np.argmax(self._directions @ normal))

    def _spring(self, k_ex: float) -> np.ndarray:
        """(k, k) ``K_zz + k_ex I``: the current set's stiffness with the example spring
        k_ex (1/s²)."""
        stiffness = self._blocks[self._set][0]
        return stiffness + float(k_ex) * np.eye(stiffness.shape[0])

    def kinetic_energy(self, body: FreeBodySimulation) -> float:
        """The kinetic energy of one of the engines (J), the rotation's on the rest
        inertia: ``½ |p|²/m + ½ (RᵀL)ᵀ I₀⁻¹ (RᵀL) + ½ |q̇|²`` (the deformation's
        coordinates mass-normalised). Allocation-free: the rest test runs at every step
        of a resting body on the columns."""
        state, spin = body._now, self._spin
        np.dot(state.L, state.R, out=spin)  # Rᵀ L, the body-frame angular momentum
        np.dot(self._inverse_inertia, spin, out=self._omega)
        return 0.5 * (float(state.p @ state.p) / self._mass + float(spin @ self._omega)
                      + float(state.qd @ state.qd))

    def switch_columns(self, on: bool, *, count: bool = True) -> None:
        """Hand the body to the current set's engine (``on``) or back to the plain one,
        now; nothing if it is already there. ``count``: a hand-back counts as a rest."""
        if on == self.columns_on:
            return
        source, target = (self.plain, self.columns) if on else (self.columns, self.plain)
        have, get = source._now, target._now
        for name in ("c", "p", "R", "L"):
            getattr(get, name)[...] = getattr(have, name)
        r0 = self.leading
        spring = self._spring(source.k_ex) if on else None
        # A = −(K_zz + k_ex I)⁻¹ K_zq: the columns' static answer to q (and q̇, q̈)
        static = -np.linalg.solve(spring, self._blocks[self._set][1]) if on else None
        for name in ("q", "qd", "qa"):
            value, into = getattr(have, name), getattr(get, name)
            if on:
                into[:r0] = value
                np.dot(static, value, out=into[r0:])
            else:
                into[:] = value[:r0]
        if on and source.k_ex > 0 and isinstance(source.driver, LeadingDriver):
            get.q[r0:] += np.linalg.solve(spring, source.k_ex * source.driver.target_entries(
                self.sets[self._set].slots))
        for name in _CARRIED:
            setattr(target, name, getattr(source, name))
        f, _ = target.elastic.force_and_tangent(get.q)
        get.f_elastic[:] = f
        target._elastic_energy = float(target.elastic.energy(get.q))
        target._next.data[:] = get.data
        target._contact_calls = -1  # evaluated afresh at the next step
        target._rate_held = False
        target._forget_contraction()
        self.columns_on = bool(on)
        if on:
            self.onsets += 1
            self._held = 0
        elif count:
            self.rests += 1

    def run(self, steps: int, *, stride: int = 1, on_step=None) -> FreeBodyRecord:
        """As :meth:`FreeBodySimulation.run`; the record's states are (r,)."""
        return run_free_body(self, steps, stride, on_step)

    def displacement(self) -> np.ndarray:
        """(n, 3) world displacement of every vertex (m)."""
        return self.active.displacement()

    def displacements(self, record: FreeBodyRecord) -> np.ndarray:
        """(f, n, 3) the world displacements (m) of a record of :meth:`run`."""
        return record.displacements(self.basis)

    _SWITCH = ("columns_on", "onsets", "rests", "column_steps", "_touching", "_held", "_set")

    @property
    def state(self) -> EngineState:
        """The stepping engine's snapshot and the switch's own state."""
        inner = self.active.state
        arrays = dict(inner.arrays)
        arrays.update({f"switch.{name}": np.array(getattr(self, name))
                       for name in self._SWITCH})
        return EngineState(inner.time, arrays)

    def reset(self, state: EngineState | None = None) -> None:
        """Back to ``state`` (from :attr:`state`) or, with ``None``, to t = 0."""
        if state is None:
            for engine in self.engines:
                engine.reset(None)
            state = self._initial
        arrays = dict(state.arrays)
        try:
            switch = {name: arrays.pop(f"switch.{name}").item() for name in self._SWITCH}
        except KeyError:
            raise LbshapeError("the state does not fit this engine (no impact switch)") \
                from None
        for name, value in switch.items():
            setattr(self, name, type(getattr(self, name))(value))
        self.active.reset(EngineState(state.time, arrays))
        self.phase_seconds = np.zeros((0, len(PHASES)))

    def set_examples(self, on: bool) -> bool:
        return [engine.set_examples(on) for engine in self.engines][-1]

    def set_drag(self, drag: Drag | None) -> None:
        for engine in self.engines:
            engine.set_drag(drag)
