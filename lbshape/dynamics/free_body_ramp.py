"""The reduced free body with its example force ramped in (``[examples] ramp``, the law in
:mod:`lbshape.dynamics.example_ramp`), kept apart from :mod:`lbshape.dynamics.free_body`."""

from __future__ import annotations

from lbshape.dynamics.example_ramp import check_ramp, ramp_factor
from lbshape.dynamics.free_body import FreeBodySimulation
from lbshape.errors import SolverError


class RampedFreeBody(FreeBodySimulation):
    """:class:`~lbshape.dynamics.free_body.FreeBodySimulation` with its example stiffness
    ramped in (see the module docstring); ``example_ramp``: T in s, > 0 (the pipeline builds
    the plain free body for T = 0). ``k_ex`` is the stiffness of the current step;
    ``configured_k_ex`` the full one the ramp rises to."""

    def __init__(self, *args, example_ramp: float, **kwargs):
        super().__init__(*args, **kwargs)
        self.example_ramp = check_ramp(example_ramp)
        self.configured_k_ex = self.k_ex
        self.k_ex = self.configured_k_ex * ramp_factor(self.time, self.example_ramp)
        self.energy0 = self.energy()  # the spring's energy at t = 0 with k_ex(0)

    def set_example_force(self, driver, k_ex: float) -> None:
        """As :meth:`FreeBodySimulation.set_example_force`; ``k_ex`` is the full stiffness
        the ramp rises to."""
        super().set_example_force(driver, k_ex)
        self.configured_k_ex = self.k_ex
        self.k_ex = self.configured_k_ex * ramp_factor(self.time, self.example_ramp)

    def reset(self, state=None) -> None:
        """As :meth:`FreeBodySimulation.reset`, ``k_ex`` the ramp's at the state's time
        (the next step's work of the ramp counts from it)."""
        super().reset(state)
        self.k_ex = self.configured_k_ex * ramp_factor(self.time, self.example_ramp)

    def step(self, index: int | None = None) -> int:
        """:meth:`FreeBodySimulation.step` at ``k_ex(t₁)``; the spring energy ``½ Δk |q|²``
        of the change is work for the energy monitor."""
        if self.driver is None:
            return super().step(index)
        k0, work = self.k_ex, self.work
        self.k_ex = self.configured_k_ex * ramp_factor(self.time + self.dt, self.example_ramp)
        self.work += 0.5 * (self.k_ex - k0) * float(self.q @ self.q)
        try:
            return super().step(index)
        except SolverError:  # the state stays at the last step, and so does k_ex
            self.k_ex, self.work = k0, work
            raise
