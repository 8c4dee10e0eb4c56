"""A free body whose impact columns act only around its impacts (:class:`ImpactSwitchedBody`).

A basis ending with impact columns (:mod:`lbshape.pipeline.impact_columns`) holds the
local crush of an impact, but it costs its extra coordinates on every step, also while
the body flies or rests (the Figure 4 bar without its example: 1.76 ms a step at rest
with 26 columns against 0.95 without, ``docs/decisions.md``). The columns are the trailing
k of the basis ``[U₀ V]`` and its leading r₀ columns are the plain basis, so two
:class:`~lbshape.dynamics.free_body.FreeBodySimulation` engines, one on U₀ (plain) and
one on ``[U₀ V]`` (columns), can hand one state to each other:

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

import numpy as np

from lbshape.dynamics.engine import Drag, EngineState
from lbshape.dynamics.free_body import PHASES, FreeBodySimulation, run_free_body
from lbshape.dynamics.free_body_record import FreeBodyRecord
from lbshape.dynamics.rigid_frame import RigidState
from lbshape.errors import LbshapeError

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

    def __init__(self, driver, r: int, leading: int):
        self.driver, self.leading = driver, int(leading)
        self.drivers = (driver,)  # its warm starts are the driver's
        self._q, self._target = np.zeros(r), np.zeros(r)

    @property
    def w(self) -> np.ndarray:
        """(k,) the weights of the last call."""
        return self.driver.w

    def weights_into(self, q: np.ndarray) -> np.ndarray:
        """The weights for q₀ (r₀,) into :attr:`w` (returned)."""
        self._q[:self.leading] = q
        return self.driver.weights_into(self._q)

    def target_from_weights_into(self, out: np.ndarray) -> None:
        """The leading r₀ entries of ``q*`` for the weights in :attr:`w` into ``out``."""
        self.driver.target_from_weights_into(self._target)
        out[:] = self._target[:self.leading]

    @property
    def columns_target(self) -> np.ndarray:
        """(r − r₀,) the trailing entries of the last target (0 before the first)."""
        return self._target[self.leading:]


class ImpactSwitchedBody:
    """One free body on two engines, the impact columns on around its impacts (see the
    module docstring).

    Args:
        plain: the engine on the leading r₀ columns U₀.
        columns: the engine on the whole basis ``[U₀ V]`` (r columns), same scene.
        coupling: (r, r) ``[U₀ V]ᵀ K₀ [U₀ V]`` (1/s²).
        impact_speed: v, the speed the body reaches its planes at (m/s, > 0).

    Attributes:
        columns_on: the columns' engine is the one stepping.
        onsets, rests: hand-overs to the columns' engine (taken-back steps) and back.
        column_steps: steps the columns' engine took.
    """

    phases: tuple[str, ...] = PHASES  #: the parts of a step timed in ``phase_seconds``

    def __init__(self, plain: FreeBodySimulation, columns: FreeBodySimulation,
                 coupling: np.ndarray, impact_speed: float):
        r0, r = plain.r, columns.r
        if not 0 < r0 < r or plain.contact is None or columns.contact is None:
            raise LbshapeError(f"an impact switch needs two engines with contact, the plain "
                               f"one on fewer columns (got {r0} and {r})")
        coupling = np.asarray(coupling, dtype=float)
        self.plain, self.columns = plain, columns
        self.r, self.leading = r, r0
        #: (k, k) K_zz and (k, r₀) K_zq: the columns' rest stiffness and coupling to q
        self._stiffness = coupling[r0:, r0:].copy()
        self._coupling = coupling[r0:, :r0].copy()
        if not (math.isfinite(impact_speed) and impact_speed > 0):
            raise LbshapeError(f"the impact speed must be > 0 m/s, got {impact_speed}")
        #: ½ m v² of the design impact (J)
        self.impact_energy = 0.5 * plain.frame.mass * float(impact_speed) ** 2
        self._held_steps = max(1, math.ceil(REST_HOLD / plain.dt * (1 - 1e-12)))
        self._q, self._qd = np.zeros(r), np.zeros(r)
        self._saved = np.zeros(plain._now.data.size)
        self._mass = float(plain.frame.mass)
        self._inverse_inertia = np.linalg.inv(plain.frame.inertia0)
        self._spin, self._omega = np.zeros(3), np.zeros(3)
        self.phase_seconds = np.zeros((0, len(PHASES)))
        self._initial = self._start()

    def _start(self) -> EngineState:
        """The state at t = 0 (the plain engine's, the switch's counters at zero)."""
        state = self.plain._now
        touching = self.plain.contact.evaluate(state.c, state.R, state.q, rigid=False).active
        self.columns_on, self.onsets, self.rests, self.column_steps = False, 0, 0, 0
        self._touching, self._held = bool(touching > 0), 0
        return self.state

    # ------------------------------------------------------------- protocol
    @property
    def active(self) -> FreeBodySimulation:
        """The engine that steps now."""
        return self.columns if self.columns_on else self.plain

    @property
    def dt(self) -> float:
        return self.plain.dt

    @property
    def newton(self):
        return self.plain.newton

    @newton.setter
    def newton(self, settings) -> None:
        self.plain.newton = self.columns.newton = settings

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
        if self.columns_on:
            return value
        out[:self.leading] = value
        return out

    @property
    def rigid(self) -> RigidState:
        return self.active.rigid

    def omega(self) -> np.ndarray:
        return self.active.omega()

    def energy(self) -> float:
        return self.active.energy()

    def __getattr__(self, name: str):
        """The scene's parts both engines share (``frame``, ``loads``, ``rest_points``,
        ``basis`` …) from the columns' engine, the step's read-outs (``sweeps``,
        ``substeps``, ``contact``, ``elastic`` …) from the one that steps."""
        if name in ("frame", "basis", "rest_points", "loads", "load_reach", "omega_max",
                    "warnings", "driver", "contact_substeps", "contact_dt", "configured_k_ex",
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
        if self.columns_on:
            iterations = self.columns.step(index)
            self.column_steps += 1
            self._after_columns_step()
            return iterations
        plain = self.plain
        if self._touching:
            iterations = plain.step(index)
            self._touching = plain.contact.scalars[1] > 0
            return iterations
        np.copyto(self._saved, plain._now.data)
        saved = {name: getattr(plain, name) for name in _CARRIED + ("_elastic_energy",)}
        iterations = plain.step(index)
        if not plain.contact.scalars[1] > 0:
            return iterations
        if self.kinetic_energy(plain) < ONSET_KINETIC_SHARE * self.impact_energy:
            self._touching = True  # a slow touch: the plain basis holds it
            return iterations
        started = plain._marks[0]
        plain._now.data[:] = self._saved
        for name, value in saved.items():
            setattr(plain, name, value)
        self.switch_columns(True)
        iterations = self.columns.step(index)
        self.column_steps += 1
        marks = self.columns._marks
        marks[:-1] -= marks[0] - started  # the taken-back step's time: overhead
        self._after_columns_step()
        return iterations

    def _after_columns_step(self) -> None:
        """Count the steps the body has touched a plane at their end, and hand it back
        once it rests."""
        touching = self.columns.contact.scalars[1] > 0
        self._held = self._held + 1 if touching else 0
        self._touching = bool(touching)
        if self._held >= self._held_steps and (
                self.kinetic_energy(self.columns) <= REST_KINETIC_SHARE * self.impact_energy):
            self.switch_columns(False)

    def _spring(self, k_ex: float) -> np.ndarray:
        """(k, k) ``K_zz + k_ex I``: the columns' stiffness with the example spring
        k_ex (1/s²)."""
        return self._stiffness + float(k_ex) * np.eye(self.r - self.leading)

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

    def switch_columns(self, on: bool) -> None:
        """Hand the body to the columns' engine (``on``) or back to the plain one, now;
        nothing if it is already there."""
        if on == self.columns_on:
            return
        source, target = (self.plain, self.columns) if on else (self.columns, self.plain)
        have, get = source._now, target._now
        for name in ("c", "p", "R", "L"):
            getattr(get, name)[...] = getattr(have, name)
        r0 = self.leading
        spring = self._spring(source.k_ex) if on else None
        # A = −(K_zz + k_ex I)⁻¹ K_zq: the columns' static answer to q (and q̇, q̈)
        static = -np.linalg.solve(spring, self._coupling) if on else None
        for name in ("q", "qd", "qa"):
            value, into = getattr(have, name), getattr(get, name)
            if on:
                into[:r0] = value
                np.dot(static, value, out=into[r0:])
            else:
                into[:] = value[:r0]
        if on and source.k_ex > 0 and isinstance(source.driver, LeadingDriver):
            get.q[r0:] += np.linalg.solve(spring, source.k_ex * source.driver.columns_target)
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
        else:
            self.rests += 1

    def run(self, steps: int, *, stride: int = 1, on_step=None) -> FreeBodyRecord:
        """As :meth:`FreeBodySimulation.run`; the record's states are (r,)."""
        return run_free_body(self, steps, stride, on_step)

    def displacement(self) -> np.ndarray:
        """(n, 3) world displacement of every vertex (m)."""
        return self.active.displacement()

    def displacements(self, record: FreeBodyRecord) -> np.ndarray:
        """(f, n, 3) the world displacements (m) of a record of :meth:`run`."""
        return record.displacements(self.columns.basis)

    _SWITCH = ("columns_on", "onsets", "rests", "column_steps", "_touching", "_held")

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
            self.plain.reset(None)
            self.columns.reset(None)
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
        self.plain.set_examples(on)
        return self.columns.set_examples(on)

    def set_drag(self, drag: Drag | None) -> None:
        self.plain.set_drag(drag)
        self.columns.set_drag(drag)

