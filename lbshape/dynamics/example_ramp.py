"""The example force ramped in from t = 0 (``[examples] ramp``).

``k_ex(t) = k_ex s(min(1, t / T))`` with ``s(x) = 3x² − 2x³`` (C¹: the stiffness and its
rate are continuous, the rate zero at both ends), T the ramp in s; T = 0 is no ramp (the
engines then never call this module and run exactly as without it). Every engine that
applies the example force sets ``k_ex(t₁)`` at the start of each step, in the pull and
its tangent alike, and counts the spring energy the change adds at the current state as
work of its energy monitor (a stiffer spring at a fixed state is energy put in):
:class:`~lbshape.dynamics.reduced.ReducedSimulation`,
:class:`~lbshape.dynamics.full.FullSpaceSimulator` and the reduced free body
(:class:`~lbshape.dynamics.free_body_ramp.RampedFreeBody`). Switching the examples off
and on keeps the ramp, which runs on the simulation's time (a reset to t = 0 starts it
again).
"""

from __future__ import annotations

import math

from lbshape.errors import LbshapeError


def check_ramp(seconds) -> float:
    """The ramp T in s as a float (≥ 0 and finite), else :class:`LbshapeError`."""
    if isinstance(seconds, bool) or not isinstance(seconds, int | float) \
            or not math.isfinite(seconds) or seconds < 0:
        raise LbshapeError(f"example ramp must be a finite number of seconds >= 0, "
                           f"got {seconds!r}")
    return float(seconds)


def ramp_factor(t: float, seconds: float) -> float:
    """``s(min(1, t / T))`` in [0, 1] (1 for T = 0: no ramp; 0 for t ≤ 0)."""
    if seconds <= 0.0:
        return 1.0
    x = min(1.0, max(0.0, t / seconds))
    return x * x * (3.0 - 2.0 * x)
