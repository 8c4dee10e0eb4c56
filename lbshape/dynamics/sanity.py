"""What stops a run, and what the user is told about a run that stopped or is coarse.

A run stops only when its state is wrong, never because it is large (a buckled, folded
or thrown object moves by more than its own size):

* a Newton iteration that does not converge or a singular Newton matrix;
* a non-finite load, force, residual or state;
* a kinetic plus elastic energy above :data:`ENERGY_FACTOR` times the energy made
  available (the initial energy plus the accumulated work of the loads, the example pull
  and a drag): a conservative or damped system stays below 1 times it (Newmark keeps the
  energy of a linear system exactly; the work is summed as absolute values, an upper
  bound), so a state beyond 10 times it holds energy nothing put in;
* a free body's reduced elastic energy below −:data:`ENERGY_FACTOR` times that energy:
  the material's energy is never negative, so a reduced force model that far below
  zero (the impact columns couple to the other coordinates linearly) is outside the
  deformations it holds, its body sinking into a well of the model, not of the
  material;
* an inverted element (det F ≤ 0) for a material that forbids inversion
  (:data:`INVERSION_FORBIDDEN`: Neo-Hookean, whose energy grows without bound as
  J → 0; the stable variant the project uses stays finite there only to keep Newton
  defined, so J ≤ 0 is a state the material cannot reach). The full engine checks every
  element; a reduced engine its cubature elements (s-sized, no n-sized work per step).

When a run stops, :func:`failure_advice` names the likely cause: a load far beyond what
the object carries (:class:`LoadReach`: the load at which the linear stiffness strains
the object by 100 %), or a step that is coarse against the
highest frequency the basis holds (:func:`coarse_step`); "lower dt" only in the latter
case.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

#: blow-up factor of the energy monitors: a state holding more than this many times the
#: energy made available stops the run (see the module docstring)
ENERGY_FACTOR = 10.0
#: material models whose elements cannot invert (det F ≤ 0 stops the run)
INVERSION_FORBIDDEN: tuple[str, ...] = ("neohookean",)
#: ``ω_max dt`` above which a step is coarse: fewer than two steps per period of the
#: highest vibration mode the basis holds (Nyquist, ω dt = π); Newmark keeps such a mode
#: bounded but lengthens its period by more than half (``ωΔt / (2 atan(ωΔt/2))`` = 1.57)
COARSE_STEP = math.pi
#: a load whose linear static strain (the largest element's) reaches this is far beyond
#: what the object carries: 100 % strain, where linear elasticity has long stopped holding
#: and a compressed element would have collapsed (J = 0)
LOAD_BEYOND = 1.0


def forbids_inversion(model: str | None) -> bool:
    """True for a material model whose elements cannot invert (:data:`INVERSION_FORBIDDEN`)."""
    return model in INVERSION_FORBIDDEN


def checks_inversion(elastic) -> bool:
    """True when the material of a reduced force model (its ``material``) forbids
    inversion: the engine then checks det F of its cubature elements each step."""
    return forbids_inversion(getattr(getattr(elastic, "material", None), "model", None))


def negative_energy_message(index: int, t: float, elastic: float, budget: float) -> str:
    """The one-line stop message of a reduced elastic energy ``elastic`` (J) below
    −:data:`ENERGY_FACTOR` times the ``budget`` (J) at step ``index`` (time t in s)."""
    return (f"the elastic energy fell to {elastic:.3e} J (below -{ENERGY_FACTOR:g} x budget "
            f"{budget:.3e} J) at step {index} (t = {t:.6g} s): the state left the range the "
            "reduced force model holds")


def inverted_message(index: int, t: float, jacobian: float, where: str) -> str:
    """The one-line stop message of an inverted element at step ``index`` (time t in s)."""
    return (f"an element inverted at step {index} (t = {t:.6g} s): det F = {jacobian:.3g} at "
            f"{where}; the material forbids inversion (det F <= 0)")


def coarse_step(omega_max: float | None, dt: float) -> str | None:
    """The warning for a step ``dt`` (s) coarse against ``omega_max`` (rad/s), the highest
    vibration frequency the basis holds (:data:`COARSE_STEP`); ``None`` when it is fine or
    unknown."""
    if omega_max is None or not omega_max > 0 or omega_max * dt <= COARSE_STEP:
        return None
    period = 2.0 * math.pi / omega_max
    return (f"dt = {dt:g} s is coarse for this basis: its highest mode ({omega_max:.4g} rad/s, "
            f"period {1e3 * period:.3g} ms) gets {period / dt:.2g} steps per period "
            f"(omega dt = {omega_max * dt:.3g} > {COARSE_STEP:.3g}); the answer may be off "
            f"by several % (dt <= {COARSE_STEP / omega_max:.2g} s resolves it)")


@dataclass(frozen=True)
class LoadReach:
    """What each load asks of the object, against what its linear stiffness carries.

    Attributes:
        newtons: (L,) each load at profile 1: the sum of its nodal force magnitudes (N).
        strains: (L,) the largest element strain (Frobenius norm of the symmetric
            displacement gradient) of its linear static displacement ``K₀⁻¹ f`` at
            profile 1; 1 is a strain of 100 %.
    """

    newtons: tuple[float, ...]
    strains: tuple[float, ...]

    def beyond(self, scales: Sequence[float]) -> str | None:
        """The advice for loads at ``scales`` (each profile's value at the failing step)
        when one is far beyond what the object carries (:data:`LOAD_BEYOND`), else
        ``None``."""
        worst, worst_strain = None, 0.0
        for index, (newtons, strain, scale) in enumerate(
                zip(self.newtons, self.strains, scales, strict=True)):
            acting = abs(float(scale)) * strain
            if newtons > 0 and strain > 0 and acting > worst_strain:
                worst, worst_strain = index, acting
        if worst is None or worst_strain < LOAD_BEYOND:
            return None
        acting = abs(float(scales[worst])) * self.newtons[worst]
        capacity = self.newtons[worst] / self.strains[worst]
        peak = "" if math.isclose(acting, self.newtons[worst], rel_tol=1e-3) else (
            f" at this step, of {self.newtons[worst]:.3g} N")
        return (f"the load ({acting:.3g} N{peak}) is far beyond what the object carries "
                f"(~{capacity:.3g} N at 100 % strain: its linear stiffness would strain it "
                f"{100 * worst_strain:.3g} %); lower the load or stiffen the material")


def failure_advice(*, reach: LoadReach | None, scales: Sequence[float],
                   omega_max: float | None, dt: float) -> str:
    """The likely cause of a stopped run, one clause ('' if neither is likely): a load far
    beyond the object's capacity first, else a coarse step ("lower dt")."""
    if reach is not None:
        load = reach.beyond(scales)
        if load is not None:
            return load
    if coarse_step(omega_max, dt) is not None:
        return (f"dt = {dt:g} s is coarse for the basis's highest mode "
                f"(omega dt = {omega_max * dt:.3g}): lower dt")
    return ""


def with_advice(message: str, advice: str) -> str:
    """``message`` with the ``advice`` clause appended (one line)."""
    return f"{message}; likely cause: {advice}" if advice else message


def stop_message(error: Exception, *, load_reach, scales: Sequence[float],
                 omega_max: float | None, dt: float) -> str:
    """An engine's stop message: ``error`` with its likely cause (:func:`failure_advice`).

    Args:
        load_reach: ``() -> LoadReach | None`` (the engine's loads in order; evaluated
            only here, once a run stopped: it may do n-sized work), or ``None``.
        scales: each load's profile value at the failing step.
    """
    reach = None
    if load_reach is not None:
        try:
            reach = load_reach()
        except Exception as exc:  # the advice never hides the failure it explains
            logging.getLogger(__name__).debug("no load advice: %s", exc)
    return with_advice(str(error), failure_advice(reach=reach, scales=scales,
                                                  omega_max=omega_max, dt=dt))


def step_warnings(omega_max: float | None, dt: float, logger) -> tuple[str, ...]:
    """The set-up warnings of an engine stepping ``dt`` (s) on a basis whose highest
    vibration frequency is ``omega_max`` (rad/s): a coarse step (:func:`coarse_step`),
    each logged once on ``logger``."""
    warnings = tuple(w for w in (coarse_step(omega_max, dt),) if w)
    for warning in warnings:
        logger.warning("%s", warning)
    return warnings


def total_force(pattern: np.ndarray) -> float:
    """The sum of the nodal force magnitudes (N) of a pattern (3n,)."""
    return float(np.linalg.norm(np.asarray(pattern, dtype=float).reshape(-1, 3), axis=1).sum())


def largest_strain(kernel, displacements: np.ndarray) -> float:
    """The largest element strain ``‖sym(F − I)‖_F`` of element displacements (e, 4, 3)
    (m) under an :class:`~lbshape.elastic.element_kernels.ElementKernel`."""
    H = kernel.deformation_gradient(displacements)
    H.reshape(-1, 9)[:, ::4] -= 1.0
    strain = 0.5 * (H + H.transpose(0, 2, 1))
    return float(np.sqrt((strain**2).sum(axis=(1, 2))).max())
