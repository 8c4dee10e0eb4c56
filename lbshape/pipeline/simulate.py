"""Run a scene with one of the three methods and write its outputs.

* ``reduced`` — the paper's method: reduced dynamics, target found in a reduced
  space with no n-sized work (the scene's ``reduced.interpolation`` route, see
  :mod:`lbshape.pipeline.routes`: by default the exact polynomial StVK energy
  in LB space, else a cubature on the LB subspace or the paper's modal route);
* ``euclidean`` — the Zhu et al. 2015 baseline: the same reduced dynamics, but the
  target is found in LB space with the energy summed over all elements;
* ``full`` — full-space FEM with full-space interpolation: the accuracy reference.

This module is the one place where scene data becomes engine input: load patterns
(:func:`load_patterns`), the example stiffness and driver, and the engines set up
from a scene and its precompute (:func:`reduced_simulation`, :func:`full_simulation`).
The engines (:mod:`lbshape.dynamics`) see arrays only and both return a
:class:`~lbshape.dynamics.record.RunRecord`.

Outputs in ``DIR``: ``stats.json`` (keys fixed by the command-line contract, plus
``phase_ms``, the one per-phase timing record of a reduced step: :func:`phase_medians`),
``trajectory.pvd`` + ``trajectory_*.vtu`` (ParaView), and ``states.npz`` (the
sampled full-space displacements, for error measurements). A run that stopped on a
solver failure leaves ``DIR`` holding only ``FAILED.txt`` (:func:`write_outputs`).
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lbshape.analysis.free_body import KEYS as FREE_BODY_KEYS
from lbshape.analysis.reference import reference_error
from lbshape.dynamics.contact import PlaneContact
from lbshape.dynamics.contact_warmup import warm_contact
from lbshape.dynamics.engine import Engine, NewtonSettings
from lbshape.dynamics.free_body import FreeBodySimulation, FreeLoad
from lbshape.dynamics.free_body_ramp import RampedFreeBody
from lbshape.dynamics.full import (
    FullSpaceContact,
    FullSpaceExamples,
    FullSpaceSimulator,
    rigid_velocity,
)
from lbshape.dynamics.impact_switch import ColumnSet, ImpactSwitchedBody, LeadingDriver
from lbshape.dynamics.loads import TimedLoad
from lbshape.dynamics.record import RunRecord
from lbshape.dynamics.reduced import REALTIME_NEWTON, ReducedSimulation
from lbshape.elastic.column_forces import ColumnForceModel
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.elastic.polynomial_forces import PolynomialForceModel
from lbshape.elastic.reduced_forces import ReducedForceModel
from lbshape.errors import LbshapeError, SolverError
from lbshape.io.atomic import (
    atomic_folder,
    check_replaceable,
    write_failed_folder,
    write_json_atomic,
    write_npz_atomic,
)
from lbshape.io.trajectory import TrajectoryWriter
from lbshape.pipeline.diagnosis import basis_omega_max, load_reach, run_warnings
from lbshape.pipeline.estimate import estimate_stats
from lbshape.pipeline.impact_columns import throw_speed
from lbshape.pipeline.influence import (
    STATS_KEYS,
    Influence,
    compare_runs,
    has_example_force,
    is_free_body,
)
from lbshape.pipeline.precomputed import Precomputed
from lbshape.pipeline.responses import mesh_load_patterns
from lbshape.pipeline.routes import example_driver
from lbshape.scene.schema import Scene
from lbshape.scene.variants import without_examples
from lbshape.shapespace.interpolation import BASELINE_ROUTE, resolve_route
from lbshape.shapespace.local_driver import local_example_driver, local_route
from lbshape.shapespace.local_full_force import FullSpaceLocalForce

log = logging.getLogger(__name__)

METHODS = ("reduced", "euclidean", "full")
#: steps excluded from the per-step timing means
WARMUP_STEPS = 10
#: most trajectory frames written per run
MAX_FRAMES = 100
#: the files of a run's output folder (glob patterns); a folder holding anything else is
#: never replaced
RUN_FILES = ("stats.json", "states.npz", "trajectory.pvd", "trajectory_*.vtu")
#: the references :func:`compare` runs
COMPARE_REFERENCES = ("full",)
#: the keys :func:`compare` adds to a run's stats (a free body also
#: :data:`lbshape.analysis.free_body.KEYS`)
COMPARE_KEYS = ("error_vs_full", "final_error_vs_full", "full_t_total_ms", "speed_up",
                "compare_message")


@dataclass(frozen=True)
class SimulationOutput:
    """A finished (or stopped) run.

    Attributes:
        stats: the ``stats.json`` payload.
        times: (k,) sample times (s).
        displacements: (k, n, 3) sampled full-space displacements (m).
        message: solver failure message ('' if stable).
        phase_ms: reduced methods: the median time per step of each part of the step
            after the warm-up, in ms (:func:`phase_medians`); ``None`` for ``full``. Also
            ``stats["phase_ms"]``.
        step_median_ms: the median wall time of a step after the warm-up (ms; the whole
            step, as ``t_total_ms`` whose mean the stats give).
    """

    stats: dict
    times: np.ndarray
    displacements: np.ndarray
    message: str = ""
    phase_ms: dict | None = None
    step_median_ms: float | None = None


def phase_medians(sim: Engine) -> dict | None:
    """The one phase record of an engine's last run: ``{phase: median ms per step after
    the warm-up}``, phases in the engine's order (:attr:`Engine.phases
    <lbshape.dynamics.engine.Engine.phases>`: a fixed object's
    :data:`~lbshape.dynamics.reduced.PHASES`, a free body's
    :data:`~lbshape.dynamics.free_body.PHASES`, the same names plus ``rigid`` and
    ``contact``); ``None`` without timed steps or for an engine that times none (full)."""
    names = sim.phases
    if not names:
        return None
    phases = getattr(sim, "phase_seconds", np.zeros((0, len(names))))
    phases = phases[warmup_steps(len(phases)):]
    if not len(phases):
        return None
    return dict(zip(names, (1e3 * np.median(phases, axis=0)).tolist(), strict=True))


def warmup_steps(steps: int) -> int:
    """How many of a run's first ``steps`` steps the timing means leave out:
    :data:`WARMUP_STEPS`, or half of a shorter run (its first step, where the kernels
    and caches warm up, always; none of a one-step run). ``stats["timed_steps"]`` is
    ``steps`` minus this."""
    if steps > WARMUP_STEPS:
        return WARMUP_STEPS
    return steps // 2


def load_patterns(scene: Scene, pre: Precomputed, mass) -> list[TimedLoad]:
    """The scene's loads as full-space patterns (3n,) in N with their time profiles.

    Args:
        scene: the scene (its ``loads``).
        pre: its precompute (the mesh the regions are selected on).
        mass: (3n, 3n) node-major consistent mass in kg.
    """
    return mesh_load_patterns(scene, pre.mesh, mass)


def example_stiffness(scene: Scene, pre: Precomputed) -> float:
    """k_ex in 1/s² when the example force is active (examples precomputed, k_ex > 0), else 0.

    ``stiffness = "auto"``: the value the precompute set (:attr:`Precomputed.auto_stiffness`).

    Raises:
        LbshapeError: ``"auto"`` with a precompute that did not set it.
    """
    active = pre.has_examples or pre.has_local_examples
    if scene.examples is None or not active:
        return 0.0
    if scene.examples.auto:
        if pre.auto_stiffness is None:
            raise LbshapeError(f"scene {scene.name}: stiffness = \"auto\" but its precompute "
                               "set no k_ex (recompute it)")
        return float(pre.auto_stiffness.k_ex)
    k_ex = float(scene.examples.stiffness)
    return k_ex if k_ex > 0 else 0.0


def example_ramp(scene: Scene) -> float:
    """The ``[examples] ramp`` in s (0: none; :mod:`lbshape.dynamics.example_ramp`)."""
    return 0.0 if scene.examples is None else float(scene.examples.ramp)


def reduced_simulation(scene: Scene, pre: Precomputed, *, method: str = "reduced",
                       newton_iterations: int | None = None,
                       newton: NewtonSettings = REALTIME_NEWTON,
                       exact_forces: bool = False, impact_switch: bool = True
                       ) -> ReducedSimulation:
    """The :class:`~lbshape.dynamics.reduced.ReducedSimulation` of a scene.

    ``method`` picks the example target's route: the scene's
    ``reduced.interpolation`` for ``reduced``, the all-element baseline for
    ``euclidean``. ``newton_iterations``: ``None`` (the default) iterates Newton until the
    relative residual is below ``newton.rtol`` (:data:`~lbshape.dynamics.reduced.REALTIME_NEWTON`,
    the real-time settings); a number fixes the updates per step, residual unchecked (studies).
    ``exact_forces``: the reduced elastic force summed element by element over every
    element with weight 1 instead of the precompute's force model
    (:func:`reduced_force_model`; a check of the force model's share of the error; slow).
    ``impact_switch``: a free body with impact columns steps on them from each impact
    until it rests (:mod:`lbshape.dynamics.impact_switch`); ``False`` keeps them
    throughout (comparisons).
    """
    elastic = reduced_force_model(pre, exact_forces=exact_forces)
    loads = []
    if scene.loads:
        mass = mass_matrix(pre.mesh, pre.material.density)
        loads = [TimedLoad(pre.U.T @ load.pattern, load.profile)
                 for load in load_patterns(scene, pre, mass)]
    k_ex = example_stiffness(scene, pre)
    driver = None
    if k_ex > 0:
        route = (resolve_route(scene.reduced.interpolation, scene.material.model)
                 if method == "reduced" else BASELINE_ROUTE)
    if k_ex > 0 and pre.has_examples:
        driver = example_driver(pre, route=route)
    elif k_ex > 0:  # local examples
        driver = local_example_driver(pre.mesh, pre.material, pre.local,
                                      route=local_route(route, pre.material))
    if scene.is_free:
        body = _free_body_simulation(scene, pre, elastic, driver, k_ex, newton, impact_switch)
        warm_contact(body)  # its contact kernels loaded now, not at its first contact
        return body
    return ReducedSimulation(
        elastic, r=pre.r, dt=scene.simulation.dt, integrator=scene.simulation.integrator,
        alpha=scene.damping.alpha, beta=scene.damping.beta, loads=loads, driver=driver,
        k_ex=k_ex, example_ramp=example_ramp(scene), contact=_contact(scene, pre, None),
        newton_iterations=newton_iterations,
        newton=newton, omega_max=basis_omega_max(pre), load_reach=load_reach(scene, pre),
        basis=pre.U, rest_points=pre.mesh.points,
    )


def reduced_force_model(pre: Precomputed, *, exact_forces: bool = False):
    """The reduced elastic force model of a precompute: the exact polynomials
    (:class:`~lbshape.elastic.polynomial_forces.PolynomialForceModel`) when it has them,
    else the cubature (:class:`~lbshape.elastic.reduced_forces.ReducedForceModel`);
    ``exact_forces``: the element sum over every element with weight 1 (slow; equal to the
    polynomials for StVK). A basis ending with impact columns: either on the columns before
    them, with the columns' own energy and a linear coupling
    (:class:`~lbshape.elastic.column_forces.ColumnForceModel`)."""
    if exact_forces and pre.elastic.impact_directions is not None:
        raise LbshapeError("exact forces: impact columns per feature have no whole-basis "
                           "force (one set acts at a time)")
    if exact_forces:
        every = np.arange(pre.mesh.n_tets, dtype=np.int64)
        return ReducedForceModel(pre.mesh.points, pre.mesh.tets, pre.material, pre.U, every,
                                 np.ones(pre.mesh.n_tets))
    elastic = pre.elastic
    leading = pre.r if elastic.impact_coupling is None else elastic.leading
    if elastic.force_model == "polynomial":
        model = PolynomialForceModel.from_arrays(*elastic.force_coefficients)
    else:
        model = ReducedForceModel(pre.mesh.points, pre.mesh.tets, pre.material,
                                  np.ascontiguousarray(pre.U[:, :leading]),
                                  elastic.cubature_elements, elastic.cubature_weights)
    if elastic.impact_coupling is None:
        return model
    if elastic.impact_directions is not None:  # per feature: each set's, column_set_models
        return model
    columns = (None if elastic.impact_forces is None
               else PolynomialForceModel.from_arrays(*elastic.impact_forces))
    return ColumnForceModel(model, elastic.impact_coupling, leading, columns)


def column_set_models(pre: Precomputed, base) -> list[tuple[np.ndarray, ColumnForceModel]]:
    """Per feature (``reduced.impact_columns_per`` ``"feature"`` or ``"feature-pair"``):
    each set's columns of the whole basis (r₀ + k,), the leading r₀ first, and its force
    model on them (``base`` the leading columns' model, the set's own polynomial energy
    and coupling)."""
    elastic = pre.elastic
    r0 = elastic.leading
    out = []
    for j, slots in enumerate(elastic.impact_column_sets()):
        index = np.concatenate([np.arange(r0), slots])
        own = (None if elastic.impact_forces is None else PolynomialForceModel.from_arrays(
            *(array[j] for array in elastic.impact_forces)))
        out.append((index, ColumnForceModel(
            base, elastic.impact_coupling[np.ix_(index, index)], r0, own)))
    return out


def force_elements(pre: Precomputed) -> int:
    """How many elements the reduced force sums over: every one for the polynomials, s
    for the cubature."""
    return pre.mesh.n_tets if pre.elastic.force_model == "polynomial" else int(
        pre.elastic.cubature_elements.size)


def _contact(scene: Scene, pre: Precomputed, center, U: np.ndarray | None = None):
    """The scene's plane contact on the object's surface with the basis U (3n, r; the
    precompute's by default), or None without planes."""
    if not scene.planes:
        return None
    return PlaneContact.for_mesh(list(scene.planes), pre.mesh.points, pre.mesh.tets,
                                 pre.U if U is None else U, center=center)


def _free_body_simulation(scene: Scene, pre: Precomputed, elastic, driver, k_ex: float,
                          newton: NewtonSettings = REALTIME_NEWTON, impact_switch: bool = True):
    """The free-body engine of a free scene: a
    :class:`~lbshape.dynamics.free_body.FreeBodySimulation`, or with impact columns
    (``elastic`` a :class:`~lbshape.elastic.column_forces.ColumnForceModel`) and
    ``impact_switch`` the :class:`~lbshape.dynamics.impact_switch.ImpactSwitchedBody` of
    one on the leading columns and one on the whole basis."""
    if pre.frame is None:
        raise LbshapeError(f"scene {scene.name}: the precompute has no rigid frame tensors")
    if scene.has_local_examples:
        raise LbshapeError(f"scene {scene.name}: local examples on a free body are not "
                           "supported; fix a region or use global examples")
    directions = pre.elastic.impact_directions
    if directions is not None and not impact_switch:
        raise LbshapeError(f"scene {scene.name}: impact columns per feature run switched "
                           "only (one set at a time)")
    if directions is None:
        columns = _free_body_engine(scene, pre, elastic, pre.frame, pre.U, driver, k_ex,
                                    newton)
        if not (impact_switch and isinstance(elastic, ColumnForceModel)):
            return columns
    r0 = pre.elastic.leading
    base = elastic.base if isinstance(elastic, ColumnForceModel) else elastic
    plain = _free_body_engine(
        scene, pre, base, pre.frame.leading(r0), np.ascontiguousarray(pre.U[:, :r0]),
        None if driver is None else LeadingDriver(driver, pre.r, r0), k_ex, newton)
    if directions is None:
        return ImpactSwitchedBody(plain, [ColumnSet(columns, np.arange(r0, pre.r))],
                                  pre.elastic.impact_coupling,
                                  throw_speed(scene, pre.mesh.points))
    sets = [ColumnSet(_free_body_engine(
        scene, pre, model, pre.frame.columns(index), np.ascontiguousarray(pre.U[:, index]),
        None if driver is None else LeadingDriver(driver, pre.r, r0, index), k_ex, newton),
        index[r0:], direction) for (index, model), direction in zip(
            column_set_models(pre, base), directions, strict=True)]
    return ImpactSwitchedBody(plain, sets, pre.elastic.impact_coupling,
                              throw_speed(scene, pre.mesh.points), basis=pre.U,
                              frame=pre.frame)


def _free_body_engine(scene: Scene, pre: Precomputed, elastic, frame, U: np.ndarray, driver,
                      k_ex: float, newton: NewtonSettings):
    """The :class:`~lbshape.dynamics.free_body.FreeBodySimulation` of a free scene on the
    basis U (3n, r) with its force model and frame tensors."""
    body = pre.mesh.points - frame.center
    loads = []
    if scene.loads:
        mass = mass_matrix(pre.mesh, pre.material.density)
        loads = [FreeLoad.from_pattern(load.pattern, U, body, load.profile)
                 for load in load_patterns(scene, pre, mass)]
    ramp = example_ramp(scene)
    engine, extra = ((RampedFreeBody, {"example_ramp": ramp}) if ramp and k_ex > 0
                     else (FreeBodySimulation, {}))
    return engine(
        elastic, frame, dt=scene.simulation.dt, integrator=scene.simulation.integrator,
        alpha=scene.damping.alpha, beta=scene.damping.beta, loads=loads, driver=driver,
        k_ex=k_ex, contact=_contact(scene, pre, frame.center, U),
        velocity=scene.initial.velocity, angular_velocity=scene.initial.angular_velocity,
        rest_points=pre.mesh.points, omega_max=basis_omega_max(pre), basis=U,
        newton=newton, load_reach=load_reach(scene, pre),
        contact_dt=scene.simulation.contact_dt, flight_dt=scene.simulation.flight_dt, **extra,
    )


def full_simulation(scene: Scene, pre: Precomputed) -> FullSpaceSimulator:
    """The :class:`~lbshape.dynamics.full.FullSpaceSimulator` of a scene (the ``full`` method).

    Contact planes act on the surface vertices; a free body moves in the inertial
    frame with its ``[initial]`` velocity; local examples use
    :class:`~lbshape.shapespace.local_full_force.FullSpaceLocalForce`.
    """
    loads = load_patterns(scene, pre, mass_matrix(pre.mesh, pre.material.density))
    k_ex = example_stiffness(scene, pre)
    examples, local = None, None
    if k_ex > 0 and pre.has_examples:
        examples = FullSpaceExamples(pre.shape.eigenvalues, pre.shape.eigenvectors,
                                     pre.examples.example_coefficients, k_ex)
    elif k_ex > 0:  # local examples (example_stiffness is 0 without any examples)
        local = (FullSpaceLocalForce(pre.mesh, pre.material, pre.local), k_ex)
    contact = None
    if scene.planes:
        contact = FullSpaceContact(list(scene.planes), pre.mesh.points, pre.mesh.tets)
    velocity = None
    if pre.fixed_vertices.size == 0:  # a free body (the reader refuses alpha > 0 for it)
        velocity = rigid_velocity(pre.mesh, pre.material.density, scene.initial.velocity,
                                  scene.initial.angular_velocity)
    return FullSpaceSimulator(
        pre.mesh, pre.material, dt=scene.simulation.dt, fixed_vertices=pre.fixed_vertices,
        integrator=scene.simulation.integrator, alpha=scene.damping.alpha,
        beta=scene.damping.beta, loads=loads, examples=examples, local_examples=local,
        contact=contact, initial_velocity=velocity, omega_max=basis_omega_max(pre),
        load_reach=load_reach(scene, pre), example_ramp=example_ramp(scene),
    )


def run_full_space(scene: Scene, pre: Precomputed, *, steps: int, stride: int = 1,
                   on_step: Callable[[int, float, np.ndarray], None] | None = None
                   ) -> RunRecord:
    """Run the ``full`` method of a scene for ``steps`` steps, keeping every ``stride``-th state
    (``on_step``: called after each step, see :meth:`FullSpaceSimulator.run`).

    A divergence does not raise: the record of what was computed comes back with
    ``stable`` False and the failure message.
    """
    return full_simulation(scene, pre).run(steps, stride=stride, on_step=on_step)


def simulate(scene: Scene, pre: Precomputed, *, method: str = "reduced",
             steps: int | None = None, out: Path | None = None,
             influence: bool = False, progress: bool = False,
             label: str | None = None, compare: str | None = None) -> SimulationOutput:
    """Run ``scene`` with ``method`` for ``steps`` (default: the scene's) steps.

    With ``influence`` and a scene whose examples act (``k_ex > 0``), the same
    scene is also run without examples and the stats gain the example influence
    keys (:data:`lbshape.pipeline.influence.STATS_KEYS`). With ``out`` the run's folder
    is written by :func:`write_outputs` (a run that stopped: only ``FAILED.txt``); a
    folder holding other files is refused before the run. ``progress``: a progress
    bar per run on stderr (``label`` names it; default the scene and method), updated
    outside the steps' timing. ``compare="full"``: the full reference is run once and the
    stats gain its error and speed-up (:func:`compare`, keys :data:`COMPARE_KEYS`); a
    reference that stops is reported there (``compare_message``), never as an error.
    """
    if method not in METHODS:
        raise LbshapeError(f"method must be one of {METHODS}, got {method!r}")
    steps = scene.simulation.steps if steps is None else int(steps)
    if steps < 1:
        raise LbshapeError(f"steps must be >= 1, got {steps}")
    if compare is not None:
        _check_compare(compare, method)
    if out is not None:
        check_replaceable(out, RUN_FILES)  # refuse a folder of other files before the run
    stride = max(1, math.ceil(steps / MAX_FRAMES))
    engine = (full_simulation(scene, pre) if method == "full"
              else reduced_simulation(scene, pre, method=method))
    with _progress_bar(steps, label or f"{scene.name} [{method}]", progress) as on_step:
        record = engine.run(steps, stride=stride, on_step=on_step)
    phase_ms = phase_medians(engine)
    frames = engine.displacements(record)
    if method == "full":
        r, s = 3 * (pre.mesh.n_vertices - pre.fixed_vertices.size), pre.mesh.n_tets
    else:
        r, s = pre.r, force_elements(pre)
    warmup = warmup_steps(record.steps)
    t_interp, t_total = record.mean_ms(warmup=warmup)
    totals = record.t_total_ms[warmup:]
    max_disp = float(np.max(np.linalg.norm(frames, axis=2))) if frames.size else 0.0
    stats = {
        "scene": scene.name, "method": method,
        "n_vertices": pre.mesh.n_vertices, "n_tets": pre.mesh.n_tets,
        "m": scene.reduced.m, "r": int(r), "s": int(s),
        "dt": scene.simulation.dt, "steps": record.steps,
        "t_interp_ms": t_interp, "t_total_ms": t_total,
        "stable": bool(record.stable), "max_displacement": max_disp, "phase_ms": phase_ms,
        "forces": "full" if method == "full" else pre.elastic.force_model,
        "example_stiffness": example_stiffness(scene, pre) if scene.examples else None,
        "timed_steps": int(record.steps - warmup),
        **step_time_spread(totals, scene.simulation.dt),
        **_force_stats(pre, method),
        **estimate_stats(scene, pre, method, record, frames),
        "warnings": run_warnings(scene, pre),
    }
    output = SimulationOutput(stats, record.times, frames, record.message, phase_ms=phase_ms,
                              step_median_ms=float(np.median(totals)) if totals.size else None)
    if influence and record.stable and has_example_force(scene, pre):
        stats.update(influence_stats(scene, pre, output, method=method, steps=steps,
                                     progress=progress))
    if compare is not None and record.stable:
        stats.update(_reference_stats(scene, pre, output, compare, progress))
    if out is not None:
        write_outputs(Path(out), pre, output)
    return output


def step_time_spread(totals_ms: np.ndarray, dt: float) -> dict:
    """``{"t_p95_ms", "t_max_ms", "steps_over_dt"}`` of a run's timed steps: the 95th
    percentile and the largest wall time of a step (ms), and how many steps took longer
    than the simulated time they advance (``dt``, s: a step slower than real time); the
    times ``None`` (and the count 0) without timed steps.

    Args:
        totals_ms: (k,) wall time of each timed step (ms).
        dt: the step (s).
    """
    totals = np.asarray(totals_ms, dtype=float)
    if not totals.size:
        return {"t_p95_ms": None, "t_max_ms": None, "steps_over_dt": 0}
    return {"t_p95_ms": float(np.percentile(totals, 95)), "t_max_ms": float(totals.max()),
            "steps_over_dt": int(np.count_nonzero(totals > 1e3 * dt))}


def _force_stats(pre: Precomputed, method: str) -> dict:
    """``{"force_model", "force_elements"}``: which elastic force ran — ``"polynomial"``
    (the exact reduced polynomials, summed over every element), ``"cubature"`` (the
    reduced cubature over its s elements) or ``"full"`` (full-space FEM over every
    element) — and over how many elements."""
    if method == "full":
        return {"force_model": "full", "force_elements": int(pre.mesh.n_tets)}
    return {"force_model": pre.elastic.force_model, "force_elements": force_elements(pre)}


def _check_compare(reference: str, method: str) -> None:
    if reference not in COMPARE_REFERENCES:
        raise LbshapeError(f"compare must be one of {COMPARE_REFERENCES}, got {reference!r}")
    if method == reference:
        raise LbshapeError(f"--compare {reference}: the {method} method is the reference "
                           "itself; compare a reduced or euclidean run with it")


def run_error(output: SimulationOutput, reference: SimulationOutput | None,
              pre: Precomputed, mass=None) -> dict | None:
    """A run's error against a reference run of the same scene, steps and sample times:
    :func:`lbshape.analysis.reference.reference_error` (``error_vs_full``,
    ``final_error_vs_full`` and a free body's centre / rotation / deformation split).

    The one computation behind :func:`compare` and the benchmark's ``error_vs_full``.
    ``mass``: the (3n, 3n) consistent mass in kg (default: built from ``pre``). None when
    the reference is missing or either run stopped.
    """
    if reference is None or not (reference.stats["stable"] and output.stats["stable"]):
        return None
    if mass is None:
        mass = mass_matrix(pre.mesh, pre.material.density)
    return reference_error(output.displacements, reference.displacements, mass,
                           times=output.times, times_full=reference.times,
                           rest=pre.mesh.points if is_free_body(pre) else None)


def compare(scene: Scene, pre: Precomputed, output: SimulationOutput, *,
            reference: str = "full", progress: bool = False) -> dict:
    """Run the ``full`` reference of ``output`` once (same scene, precompute and steps)
    and measure ``output`` against it (:func:`run_error`).

    Returns:
        ``{"error_vs_full", "final_error_vs_full", "full_t_total_ms", "speed_up",
        "compare_message"}`` — the trajectory error (Table 2's), the final-frame
        error, the reference's mean step time in ms, its ratio to the run's
        ``t_total_ms``, and None; a free body adds
        :data:`lbshape.analysis.free_body.KEYS`. A reference that stops (or cannot
        run) gives None values and ``compare_message`` saying why: it never raises
        and never changes ``output``.

    Raises:
        LbshapeError: ``reference`` is not ``"full"``, or ``output`` is a full run.
    """
    _check_compare(reference, output.stats["method"])
    keys = COMPARE_KEYS + (FREE_BODY_KEYS if is_free_body(pre) else ())
    result = dict.fromkeys(keys)
    if not output.stats["stable"]:
        result["compare_message"] = "no comparison: the run stopped before its last step"
        return result
    try:
        full = simulate(scene, pre, method="full", steps=output.stats["steps"],
                        progress=progress, label=f"{scene.name} [full] (reference)")
        message = full.message
    except LbshapeError as exc:
        full, message = None, str(exc)
    if message:
        result["compare_message"] = f"full reference unavailable: {message}"
        return result
    try:
        result.update(run_error(output, full, pre))
    except LbshapeError as exc:  # e.g. a reference that never moves
        result["compare_message"] = f"error vs full unavailable: {exc}"
    result["full_t_total_ms"] = full.stats["t_total_ms"]
    t_total = output.stats["t_total_ms"]
    result["speed_up"] = full.stats["t_total_ms"] / t_total if t_total > 0 else None
    return result


def _reference_stats(scene: Scene, pre: Precomputed, output: SimulationOutput,
                     reference: str, progress: bool) -> dict:
    """:func:`compare` for :func:`simulate` (whose ``compare`` argument hides the name)."""
    return compare(scene, pre, output, reference=reference, progress=progress)


def influence_stats(scene: Scene, pre: Precomputed, output: SimulationOutput, *, method: str,
                    steps: int | None = None, progress: bool = False) -> dict:
    """The example influence keys of a finished run (:func:`example_influence`); when the
    run without examples cannot be compared (it stopped), every key is ``None`` and
    ``influence_message`` gives the reason: a secondary run never fails the primary one."""
    try:
        return example_influence(scene, pre, output, method=method, steps=steps,
                                 progress=progress)[0].stats()
    except LbshapeError as exc:
        log.warning("example influence of %s (%s) unavailable: %s", scene.name, method, exc)
        return {**dict.fromkeys(STATS_KEYS), "influence_message": str(exc)}


def example_influence(scene: Scene, pre: Precomputed, output: SimulationOutput, *,
                      method: str, steps: int | None = None, progress: bool = False
                      ) -> tuple[Influence, SimulationOutput]:
    """Run ``scene`` without examples and compare with ``output``, its run with examples.

    See :mod:`lbshape.pipeline.influence`. The reference uses the same method,
    steps and precompute with ``k_ex = 0`` (``progress``: its progress bar).

    Returns:
        ``(influence, the run without examples)``.

    Raises:
        LbshapeError: no example force in the scene.
        SolverError: a run stopped early (the message names which).
    """
    if not has_example_force(scene, pre):
        raise LbshapeError(f"scene {scene.name} has no example force to measure")
    reference = simulate(without_examples(scene), pre, method=method, steps=steps,
                         progress=progress,
                         label=f"{scene.name} [{method}] without examples (influence)")
    if output.message or reference.message:
        which = "with" if output.message else "without"
        raise SolverError(f"the {method} run {which} examples stopped: "
                          f"{output.message or reference.message}")
    return compare_runs(pre, output, reference), reference


def write_outputs(out: Path, pre: Precomputed, output: SimulationOutput) -> Path:
    """A run's folder ``out``, replaced as a whole (:func:`lbshape.io.atomic.atomic_folder`).

    A stable run: ``stats.json``, ``states.npz`` and the ParaView trajectory, written
    beside ``out`` and renamed into place once complete. A run that stopped
    (``output.message``): ``out`` holds only ``FAILED.txt`` (the message, then the
    stats up to the stop as JSON), so it cannot be taken for a result; in both cases
    an earlier run's files in ``out`` are gone. Returns the folder.

    Raises:
        LbshapeError: ``out`` holds files other than a run's (:data:`RUN_FILES`).
    """
    if output.message:
        text = (f"simulation stopped: {output.message}\n"
                f"This folder holds no result: the {output.stats['method']} run of scene "
                f"{output.stats['scene']} stopped after {output.stats['steps']} steps.\n"
                f"Its stats up to the stop:\n"
                f"{json.dumps({**output.stats, 'message': output.message}, indent=2)}")
        write_failed_folder(out, text, RUN_FILES)
        return out
    with atomic_folder(out, RUN_FILES) as folder:
        writer = TrajectoryWriter(folder, pre.mesh)
        for t, u in zip(output.times, output.displacements, strict=True):
            writer.write(float(t), u)
        writer.close()
        write_npz_atomic(folder / "states.npz", times=output.times,
                         displacements=output.displacements)
        write_json_atomic(folder / "stats.json", output.stats)
    return out


#: a progress bar is redrawn at most this often (s): the bar costs nothing per step
PROGRESS_INTERVAL = 0.2


@contextlib.contextmanager
def _progress_bar(steps: int, label: str, enabled: bool):
    """An ``on_step`` callback that advances a tqdm bar on stderr (None when disabled)."""
    if not enabled:
        yield None
        return
    from tqdm import tqdm

    with tqdm(total=steps, desc=label, unit="step", file=sys.stderr,
              mininterval=PROGRESS_INTERVAL) as bar:
        def on_step(index: int, _time: float, _state) -> None:
            # index counts the steps from 0 (the initial state is no step): the bar
            # ends at steps/steps
            bar.update(min(index + 1, steps) - bar.n)

        yield on_step
