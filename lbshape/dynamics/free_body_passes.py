"""How a free body's step of Δt is divided into passes (:class:`FreeBodyPasses`, a part of
:class:`~lbshape.dynamics.free_body.FreeBodySimulation`): a pass is steps 1–5 of the
step in :mod:`lbshape.dynamics.free_body` over a part of Δt, committed on its own.

- **In flight** (no plane touches the body) a step is
  :attr:`~FreeBodyPasses.flight_passes` passes of ``Δt / k``, each no longer than
  ``flight_dt``: by default the pass that resolves the deformation's highest frequency
  ``ω = sqrt(ω_max² + k_ex)`` (the basis's highest mode and the example spring of the
  step, both per unit mass) to :data:`FLIGHT_PERIOD_ERROR`: Newmark's period grows by
  ``(ω h)² / 12`` (:func:`resolved_pass`), but no shorter than ``contact_dt``: a body
  in flight takes no more passes than in contact (a stiff body's highest modes, little
  excited, do not make it slower than real time). One pass for most bodies.
- **In contact** (a plane touches the body at the step's start) a step is
  :attr:`~FreeBodyPasses.contact_substeps` passes of ``Δt / k`` ≤ ``contact_dt`` (or the
  flight passes, if more).
- A flight pass that ends (or fails) touching a plane is discarded, and the rest of the
  step from that pass's start is taken in contact passes.
"""

from __future__ import annotations

import math

import numpy as np

from lbshape.errors import LbshapeError, SolverError

#: the longest pass while a plane touches the body (s): a longer step is taken in
#: sub-steps. Reduced, each scene's own run at dt = 1 ms against the same at dt/8:
#: bar-s-cuboid 10.2 / 3.1 / 1.29 / 0.68 % with sub-steps of 1 / 0.5 / 0.33 / 0.25 ms;
#: 1/3 ms keeps it within 2 % at three passes a 1 ms step (four cost a body resting on
#: a plane 1.20 ms a step, three 0.96); the car without examples at 60 Hz, its contact
#: in sub-steps of 1/3 ms, within 0.23 % of its run at 1 ms (whole 60 Hz steps stall in
#: its wall impact)
CONTACT_DT = 1.0 / 3000.0
#: the period error a flight pass allows the deformation's highest frequency: Newmark
#: (average acceleration) lengthens a period by (ω h)² / 12, so ω h ≤ √0.12 = 0.35. The
#: car with examples (ω = 631 rad/s: its example spring √k_ex = 548 rad/s) takes 2 passes
#: at 1 ms; without examples (313 rad/s) and bar-s (243 rad/s) one
FLIGHT_PERIOD_ERROR = 0.01


def resolved_pass(omega_max: float | None, k_ex: float) -> float:
    """The longest pass (s) that resolves the deformation's highest frequency
    ``sqrt(omega_max² + k_ex)`` (rad/s; ``omega_max`` the basis's, ``None`` unknown; k_ex
    in 1/s²) to :data:`FLIGHT_PERIOD_ERROR`; ``inf`` when both are 0."""
    omega2 = (omega_max or 0.0) ** 2 + max(k_ex, 0.0)
    return math.sqrt(12.0 * FLIGHT_PERIOD_ERROR / omega2) if omega2 > 0 else math.inf


def passes(dt: float, longest: float) -> int:
    """The passes of ``dt`` (s) none longer than ``longest`` (s): ``ceil(dt / longest)``
    (round-off below it does not add one)."""
    return max(1, math.ceil(dt / longest * (1 - 1e-12))) if math.isfinite(longest) else 1


def checked_length(value: float | None, default: float | None, name: str) -> float | None:
    """``value`` (s) if a positive time, ``default`` if ``None``; else a one-line error."""
    value = default if value is None else value
    if value is not None and not (np.isfinite(value) and value > 0):
        raise LbshapeError(f"{name} must be > 0 s, got {value}")
    return value


class FreeBodyPasses:
    """The passes of a step (see the module docstring), for
    :class:`~lbshape.dynamics.free_body.FreeBodySimulation` (which holds ``_advance``,
    ``_commit``, ``_set_step_length``, ``contact`` …)."""

    def _set_passes(self, contact_dt: float | None, flight_dt: float | None) -> None:
        """The longest passes asked for (s; ``None``: :data:`CONTACT_DT`, and the resolved
        pass of :func:`resolved_pass`) and the passes of a step in contact."""
        self.contact_dt = checked_length(contact_dt, CONTACT_DT, "contact_dt")
        self._flight_dt_asked = checked_length(flight_dt, None, "flight_dt")
        #: sub-steps of a step while a plane touches the body: Δt / k ≤ ``contact_dt``
        self.contact_substeps = passes(self.dt, self.contact_dt)

    @property
    def flight_dt(self) -> float:
        """The longest pass in flight (s): the one asked for, or the one that resolves the
        highest frequency at the current example stiffness (a ramp's included), at least
        ``contact_dt``."""
        asked = self._flight_dt_asked
        if asked is not None:
            return asked
        return max(resolved_pass(self.omega_max, self.k_ex), self.contact_dt)

    @property
    def flight_passes(self) -> int:
        """The passes of the next step in flight."""
        return passes(self.dt, self.flight_dt)

    def _contact_at_start(self) -> bool:
        """A plane touches the body at the end of the last step, the start of this one (the
        contact's arrays hold that evaluation), and the contact takes sub-steps."""
        contact = self.contact
        return (contact is not None and self.contact_substeps > 1 and self._contact_fresh()
                and contact.scalars[1] > 0)

    def _retake_in_substeps(self) -> bool:
        """Whether a flight pass, not committed, is taken again in contact passes: it ended
        (or failed) with a plane touching the body. If so, its sweeps are uncounted, their
        friction rate is dropped and the contact is evaluated afresh at the start."""
        contact = self.contact
        if contact is None or self.contact_substeps == 1 or contact.scalars[1] == 0:
            return False
        self._contact_calls = -1
        self._rate_held = False
        self.total_sweeps -= self.sweeps
        self.sweeps = 0
        return True

    def step(self, index: int | None = None) -> int:
        """Advance one step of :attr:`dt` in passes (see the module docstring); return the
        Newton iterations. The wall time of its parts (:data:`PHASES`, s) is left in
        ``_marks`` for :meth:`run`.

        Raises:
            SolverError: see :mod:`lbshape.dynamics.free_body`; the state is that of the
                last accepted pass (unchanged when the step had none)."""
        clock, marks = self._clock, self._marks
        marks[0] = clock()
        index = self.steps_taken + 1 if index is None else index
        times = self._seconds
        times[:] = 0.0
        self.sweeps = 0
        try:
            if self._contact_at_start():
                iterations, self.substeps = self._contact_passes(index, self.time, self.dt,
                                                                 times)
            else:
                iterations, self.substeps = self._flight(index, self.time, times)
        finally:
            self._use_length(self.dt)
        # PHASES: weights, target, example force (the generalized load), rigid, contact,
        # internal force and tangent, solve; the rest of the step is overhead
        for mark, part in enumerate((5, 6, 3, 2, 1, 0, 4), start=1):
            marks[mark] = marks[mark - 1] + times[part]
        marks[8] = clock()
        return iterations

    def _flight(self, index: int, start: float, times: np.ndarray) -> tuple[int, int]:
        """The flight passes of a step from ``start``; the rest of the step in contact
        passes from a pass that touched a plane. Returns (Newton iterations, passes)."""
        flight, iterations = self.flight_passes, 0
        self._use_length(self.dt / flight)
        for done in range(flight):
            t1 = start + self.dt * (done + 1) / flight
            failure = None
            try:
                taken = self._advance(index, t1, times)
            except SolverError as exc:
                failure = exc
            if self._retake_in_substeps():
                rest = self.dt if done == 0 else self.dt * (flight - done) / flight
                more, count = self._contact_passes(index, start + self.dt * done / flight,
                                                   rest, times)
                return iterations + more, done + count
            if failure is not None:
                raise failure
            self._commit(index, t1)
            iterations += taken
        return iterations, flight

    def _contact_passes(self, index: int, start: float, span: float,
                        times: np.ndarray) -> tuple[int, int]:
        """``span`` s from ``start`` in passes no longer than ``contact_dt`` nor the flight
        pass, each committed. Returns (Newton iterations, passes)."""
        count = max(passes(span, self.contact_dt), passes(span, self.flight_dt))
        iterations = 0
        self._use_length(span / count)
        for k in range(1, count + 1):
            t1 = start + span * k / count
            iterations += self._advance(index, t1, times)
            self._commit(index, t1)
        return iterations, count

    def _use_length(self, h: float) -> None:
        """Passes of ``h`` s from now on (the scheme's rates set again only on a change)."""
        if h != self._h:
            self._set_step_length(h)
