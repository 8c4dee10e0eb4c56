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
* an inverted element (det F ≤ 0) for a material that forbids inversion
  (:data:`INVERSION_FORBIDDEN`: Neo-Hookean, whose energy grows without bound as
  J → 0; the stable variant the project uses stays finite there only to keep Newton
  defined, so J ≤ 0 is a state the material cannot reach). The full engine checks every
  element; a reduced engine its cubature elements (s-sized, no n-sized work per step).

When a run stops, :func:`failure_advice` names the likely cause: a load far beyond what
the object carries (:class:`LoadReach`: the load at which the linear stiffness moves
the object by its own size, a strain of order 1), or a step that is coarse against the
highest frequency the basis holds (:func:`coarse_step`); "lower dt" only in the latter
case.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

#: blow-up factor of the energy monitors: a state holding more than this many times the
#: energy made available stops the run (see the module docstring)
ENERGY_FACTOR = 10.0
#: material models whose elements cannot invert (det F ≤ 0 stops the run)
INVERSION_FORBIDDEN: tuple[str, ...] = ("neohookean",)
#: ``ω_max dt`` above which a step is coarse: fewer than two steps per period of the
#: highest vibration mode the basis holds (Nyquist, ω dt = π); Newmark keeps such a mode
#: bounded but lengthens its period by more than half (``ωΔt / (2 atan(ωΔt/2))`` = 1.57)
COARSE_STEP = math.pi
#: a load whose linear static displacement reaches this many times the object's size is
#: far beyond what the object carries: at 1 (a strain of order 1, 100 %) the linear
#: estimate is the object's capacity, and loads a buckled bar legitimately carries reach
#: 1.4-2.4 of it (the slender bar of tests/dynamics/test_sanity.py folding at 300-800 N)
LOAD_BEYOND = 3.0


def forbids_inversion(model: str | None) -> bool:
    """True for a material model whose elements cannot invert (:data:`INVERSION_FORBIDDEN`)."""
    return model in INVERSION_FORBIDDEN


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
        reach: (L,) its linear static displacement at profile 1 (largest vertex
            displacement ``K₀⁻¹ f``) over the object's size (bounding-box diagonal); 1
            means the load moves the object by its own size, a strain of order 1.
    """

    newtons: tuple[float, ...]
    reach: tuple[float, ...]

    @classmethod
    def from_static(cls, newtons: Sequence[float], displacements: Sequence[float],
                    size: float) -> LoadReach:
        """From each load's force (N) and largest linear static displacement (m), and the
        object's size (m)."""
        return cls(tuple(float(n) for n in newtons),
                   tuple(float(d) / float(size) for d in displacements))

    def beyond(self, scales: Sequence[float]) -> str | None:
        """The advice for loads at ``scales`` (each profile's value at the failing step)
        when one is far beyond what the object carries (:data:`LOAD_BEYOND`), else
        ``None``."""
        worst, worst_ratio = None, 0.0
        for index, (newtons, reach, scale) in enumerate(
                zip(self.newtons, self.reach, scales, strict=True)):
            ratio = abs(float(scale)) * reach
            if newtons > 0 and reach > 0 and ratio > worst_ratio:
                worst, worst_ratio = index, ratio
        if worst is None or worst_ratio < LOAD_BEYOND:
            return None
        acting = abs(float(scales[worst])) * self.newtons[worst]
        capacity = self.newtons[worst] / self.reach[worst]
        peak = "" if math.isclose(acting, self.newtons[worst], rel_tol=1e-3) else (
            f" at this step, of {self.newtons[worst]:.3g} N")
        return (f"the load ({acting:.3g} N{peak}) is far beyond what the object carries "
                f"(~{capacity:.3g} N at 100 % strain: its linear stiffness would move it "
                f"{worst_ratio:.3g} times its own size); lower the load or stiffen the "
                "material")


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


def object_size(points: np.ndarray) -> float:
    """The bounding-box diagonal (m) of rest positions (n, 3)."""
    points = np.asarray(points, dtype=float)
    return float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))


def total_force(pattern: np.ndarray) -> float:
    """The sum of the nodal force magnitudes (N) of a pattern (3n,)."""
    return float(np.linalg.norm(np.asarray(pattern, dtype=float).reshape(-1, 3), axis=1).sum())


def reduced_load_reach(K0: np.ndarray, patterns: Sequence[np.ndarray],
                       newtons: Sequence[float | None], basis: np.ndarray | None,
                       rest_points: np.ndarray | None) -> LoadReach | None:
    """The :class:`LoadReach` of reduced loads (patterns ``Uᵀ f`` (r,), each load's force in
    N or None) under the reduced rest tangent K0 (r, r); None without the basis, the rest
    points or the loads' forces (for failure messages: n-sized, never in a step)."""
    if basis is None or rest_points is None or not patterns or any(n is None for n in newtons):
        return None
    try:
        static = np.linalg.solve(np.asarray(K0, dtype=float),
                                 np.array(patterns, dtype=float).T)  # (r, L)
    except np.linalg.LinAlgError:
        return None
    moved = (np.asarray(basis) @ static).reshape(-1, 3, static.shape[1])
    largest = np.linalg.norm(moved, axis=1).max(axis=0)
    return LoadReach.from_static(newtons, largest, object_size(rest_points))


def step_warnings(omega_max: float | None, dt: float, logger) -> tuple[str, ...]:
    """The set-up warnings of an engine stepping ``dt`` (s) on a basis whose highest
    vibration frequency is ``omega_max`` (rad/s): a coarse step (:func:`coarse_step`),
    each logged once on ``logger``."""
    warnings = tuple(w for w in (coarse_step(omega_max, dt),) if w)
    for warning in warnings:
        logger.warning("%s", warning)
    return warnings


def reduced_stop_message(error: Exception, elastic, *, patterns: Sequence[np.ndarray],
                         newtons: Sequence[float | None], scales: Sequence[float],
                         basis: np.ndarray | None, rest_points: np.ndarray | None,
                         omega_max: float | None, dt: float) -> str:
    """A reduced engine's stop message: ``error`` with the likely cause
    (:func:`failure_advice`; the loads' reach under the rest tangent of ``elastic``, whose
    ``force_and_tangent`` gives it; n-sized, only once a run stopped)."""
    reach = None
    if len(patterns):
        _, K0 = elastic.force_and_tangent(np.zeros(np.shape(patterns[0])[0]))
        reach = reduced_load_reach(K0, patterns, newtons, basis, rest_points)
    return with_advice(str(error), failure_advice(reach=reach, scales=scales,
                                                  omega_max=omega_max, dt=dt))


def full_load_reach(K0: sp.spmatrix, patterns: np.ndarray, free_dofs: np.ndarray,
                    points: np.ndarray) -> LoadReach | None:
    """The :class:`LoadReach` of full-space loads (patterns (L, nf) in N on the free dofs
    ``free_dofs`` of the points (n, 3)) under the rest tangent K0 (nf, nf) restricted to
    them; None when K0 is singular (one sparse solve: only once a run stopped)."""
    patterns = np.atleast_2d(np.asarray(patterns, dtype=float))
    try:
        static = spla.splu(sp.csc_matrix(K0)).solve(np.ascontiguousarray(patterns.T))
    except RuntimeError:
        return None
    moved = np.zeros((3 * len(points), patterns.shape[0]))
    moved[free_dofs] = static.reshape(len(free_dofs), -1)
    largest = np.linalg.norm(moved.reshape(len(points), 3, -1), axis=1).max(axis=0)
    return LoadReach.from_static([total_force(p) for p in patterns], largest,
                                 object_size(points))
