"""Reduced real-time simulation with example-driven forces (paper run-time steps 1–3, 5).

Equation of motion in mass-orthonormal reduced coordinates q (r,):
``q̈ + D q̇ + f_int(q) + k_ex (q − q*) = Uᵀ f_ext(t)``, with ``f_int`` from the
cubature (:class:`~lbshape.elastic.reduced_forces.ReducedForceModel`), Rayleigh damping
``D = α I + β K₀`` (K₀ the elastic tangent at rest), and the target ``q*``
recomputed once per step from the state at the start of the step (weights and
target: :class:`~lbshape.shapespace.example_driver.ExampleDriver`). The example force is
split, as in the full-space reference, into a spring ``k_ex q`` (position
dependent, potential ``½ k_ex |q|²``) and a pull ``k_ex q*`` held constant within
the step and applied as an external load, so the energy monitor counts the pull
as external work and Newton does not fight two cancelling large terms near the
target. The step itself only
touches r-, m- and s-sized arrays; full-space displacements ``U q`` are formed
only for output frames, outside the timed step.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence

import numpy as np

from lbshape.dynamics.integrators import make_stepper
from lbshape.dynamics.loads import TimedLoad
from lbshape.dynamics.record import RunRecord, RunRecorder
from lbshape.errors import SolverError
from lbshape.shapespace.example_driver import ExampleDriver

log = logging.getLogger(__name__)


class ReducedSimulation:
    """Implicit reduced dynamics with optional example forces.

    Args:
        elastic: reduced internal force model (``force_and_tangent(q)``).
        r: reduced dimension.
        dt: time step (s).
        integrator: ``"newmark"`` or ``"backward-euler"``.
        alpha, beta: Rayleigh coefficients (1/s, s).
        loads: reduced loads (patterns ``Uᵀ f`` (r,)).
        driver: the example driver, or ``None`` (no example machinery at all). A
            driver with a ``spring`` attribute (r, r) (local examples,
            :class:`~lbshape.shapespace.local_examples.LocalExampleDriver`) uses it in
            place of the identity in the spring ``k_ex S q``.
        k_ex: example stiffness (1/s²); 0 disables the example force.
    """

    def __init__(
        self,
        elastic,
        *,
        r: int,
        dt: float,
        integrator: str = "newmark",
        alpha: float = 0.0,
        beta: float = 0.0,
        loads: Sequence[TimedLoad] = (),
        driver: ExampleDriver | None = None,
        k_ex: float = 0.0,
    ):
        self.elastic = elastic
        self.r = int(r)
        self.loads = list(loads)
        self.driver = driver if (driver is not None and k_ex > 0.0) else None
        self.k_ex = float(k_ex) if self.driver is not None else 0.0
        self.q_target = np.zeros(self.r)
        spring = getattr(self.driver, "spring", None)
        self._spring = np.eye(self.r) if spring is None else np.asarray(spring, dtype=float)
        _, K0 = elastic.force_and_tangent(np.zeros(self.r))
        self.stepper = make_stepper(
            integrator,
            np.eye(self.r),
            self._force_and_tangent,
            dt=dt,
            external=self._external if (self.loads or self.driver is not None) else None,
            alpha=alpha,
            beta=beta,
            damping_stiffness=K0,
            potential=self._potential,
        )

    def _force_and_tangent(self, q: np.ndarray):
        f, K = self.elastic.force_and_tangent(q)
        if self.k_ex:
            f = f + self.k_ex * (self._spring @ q)
            K = K + self.k_ex * self._spring
        return f, K

    def _potential(self, q: np.ndarray) -> float:
        energy = float(self.elastic.energy(q))
        if self.k_ex:
            energy += 0.5 * self.k_ex * float(q @ (self._spring @ q))
        return energy

    def _external(self, t: float) -> np.ndarray:
        total = self.k_ex * self.q_target if self.k_ex else np.zeros(self.r)
        for load in self.loads:
            scale = load.profile(t)
            if scale:
                total += scale * load.pattern
        return total

    def run(
        self,
        steps: int,
        *,
        stride: int = 1,
        on_step: Callable[[int, float, np.ndarray], None] | None = None,
    ) -> RunRecord:
        """Advance ``steps`` steps; a solver failure ends the run with ``stable=False``.

        Args:
            steps: number of steps.
            stride: keep every ``stride``-th state (and the initial one), ≥ 1.
            on_step: called after each step with (step index from 0, time in s, q (r,)).

        Returns:
            The :class:`~lbshape.dynamics.record.RunRecord`; its states are the
            reduced coordinates q (r,).
        """
        recorder = RunRecorder(stride=stride)
        recorder.start(self.stepper.time, self.stepper.x)
        for index in range(steps):
            started = time.perf_counter()
            try:
                if self.driver is not None:
                    self.q_target = self.driver.target(self.stepper.x).q_target
                interpolated = time.perf_counter()
                info = self.stepper.step()
            except SolverError as exc:
                log.error("reduced simulation stopped: %s", exc)
                return recorder.record(stable=False, message=str(exc))
            finished = time.perf_counter()
            recorder.step(self.stepper.time, self.stepper.x, interp_seconds=interpolated - started,
                          total_seconds=finished - started, iterations=info.iterations)
            if on_step is not None:
                on_step(index, self.stepper.time, self.stepper.x)
        return recorder.record()
