"""The implicit schemes' coefficients, held once (:data:`SCHEMES`): every engine reads them
from here (:class:`~lbshape.dynamics.integrators.ImplicitStepper`,
:mod:`lbshape.dynamics.reduced`, :mod:`lbshape.dynamics.free_body`); the schemes
themselves are described in :mod:`lbshape.dynamics.integrators`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lbshape.errors import LbshapeError


@dataclass(frozen=True)
class Scheme:
    """The coefficients of one implicit scheme: the one table every engine reads.

    With ``h = Δt`` and the step's displacement increment ``Δx = x₁ − x₀``:

    * predictor (the first guess of Δx): ``Δx = h v₀ + ½ k_a h² a₀``;
    * end-of-step kinematics: ``a₁ = c_a/h² Δx − k_v/h v₀ − k_a a₀``,
      ``v₁ = c_v/h Δx − j_v v₀``;
    * hence the Newton matrix ``dR/dΔx = c_a/h² M + c_v/h D + K``.

    A second-order scheme (``k_a ≠ 0``; Newmark, where ``k_v = c_a``) is also written
    ``a₁ = c_a/h² (Δx − h v₀) − k_a a₀``; the first-order one (``k_a = 0``; backward
    Euler, ``c_a = k_v = c_v = 1``, ``j_v = 0``) as the difference quotients
    ``v₁ = Δx/h``, ``a₁ = (v₁ − v₀)/h``. The same numbers to round-off; which form an
    engine evaluates is its own (the forms round differently).

    Attributes:
        name: the scene's name of the scheme (:data:`INTEGRATORS`).
        ca, kv, ka, cv, jv: ``c_a``, ``k_v``, ``k_a``, ``c_v``, ``j_v`` above.
    """

    name: str
    ca: float
    kv: float
    ka: float
    cv: float
    jv: float

    @property
    def array(self) -> np.ndarray:
        """(5,) ``[c_a, k_v, k_a, c_v, j_v]`` (for compiled kernels)."""
        return np.array([self.ca, self.kv, self.ka, self.cv, self.jv])

    def step_rates(self, dt: float) -> tuple[float, float, float, float, float]:
        """``(c_a/h², k_v/h, k_a, c_v/h, j_v)`` for the step ``h = dt`` (s): the factors of
        Δx, v₀ and a₀ in a₁ and v₁."""
        h = float(dt)
        return (self.ca / h**2, self.kv / h, self.ka, self.cv / h, self.jv)


#: the schemes by scene name: Newmark average acceleration (β = ¼, γ = ½) and backward
#: Euler
SCHEMES: dict[str, Scheme] = {
    "newmark": Scheme("newmark", ca=4.0, kv=4.0, ka=1.0, cv=2.0, jv=1.0),
    "backward-euler": Scheme("backward-euler", ca=1.0, kv=1.0, ka=0.0, cv=1.0, jv=0.0),
}
#: time integrators by scene name
INTEGRATORS: tuple[str, ...] = tuple(SCHEMES)


def get_scheme(integrator: str) -> Scheme:
    """The :class:`Scheme` named ``integrator``; :class:`LbshapeError` for an unknown name."""
    try:
        return SCHEMES[integrator]
    except KeyError:
        raise LbshapeError(
            f"integrator must be one of {INTEGRATORS}, got {integrator!r}") from None
