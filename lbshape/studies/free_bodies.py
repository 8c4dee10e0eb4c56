"""Free bodies evaluated the way the field evaluates them (``lbshape bench --free-bodies``).

Beside the whole-trajectory error of Table 2, per free body (car, bar-s-cuboid,
bar-s-cylinder), with and without its examples:

* **before contact** — the error up to the first sample at which any vertex of the full
  reference penetrates a plane (:func:`~lbshape.analysis.free_body_eval.window_error`);
* **rest pose** — the symmetric surface-to-surface distance of the final poses over the
  diagonal (:func:`~lbshape.analysis.free_body_eval.surface_distance`): a symmetric
  object settling in an equivalent pose scores 0;
* **the reference's noise floor** — the full reference re-run with the throw ±1 %, the
  contact stiffness ±10 % and half the step (:data:`PERTURBATIONS`); the largest change
  of its trajectory (the same norm as the error) is the floor printed beside every
  whole-trajectory error, with the ratio error / floor;
* **designed impacts** (:func:`designed_impact`) — the bar thrown at a plane so that a
  face, an edge or a corner hits (:data:`IMPACT_NORMALS`) at two speeds
  (:data:`IMPACT_SPEEDS`), with and without examples; the reduced body restarts from the
  full run's state projected onto its coordinates and frame
  (:func:`~lbshape.analysis.free_body_eval.project_state`, :func:`restart_reduced`)
  :data:`PRE_STEPS` steps before the first contact, and both run through the impact:
  restitution, change of linear and angular momentum, energy lost, deepest penetration.

The engines are driven through :class:`~lbshape.pipeline.simulation.Simulation` and
:func:`~lbshape.pipeline.simulate.simulate`; the restart writes the projected state into
the reduced free-body engine's snapshot (:attr:`Engine.state
<lbshape.dynamics.engine.Engine.state>`, its ``now`` body state) and restores it.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from lbshape.analysis.free_body_eval import (
    first_contact,
    impact_measures,
    penetration,
    project_state,
    surface_distance,
    window_error,
)
from lbshape.analysis.norms import trajectory_error
from lbshape.dynamics.engine import EngineState
from lbshape.dynamics.free_body_kernels import BodyState
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.errors import LbshapeError
from lbshape.pipeline.simulate import simulate
from lbshape.pipeline.simulation import Simulation
from lbshape.scene.variants import (
    impact_scene,
    with_contact_stiffness,
    with_step,
    with_throw,
    without_examples,
)

log = logging.getLogger(__name__)

#: the free bodies evaluated by default
FREE_SCENES: tuple[str, ...] = ("car", "bar-s-cuboid", "bar-s-cylinder")
#: the keys a free body's Table 2 rows gain (None for a fixed object or when not run)
KEYS: tuple[str, ...] = ("error_pre_contact", "first_contact_s", "rest_pose_chamfer",
                         "rest_pose_hausdorff", "noise_floor", "error_over_floor")
#: the reference's perturbations: (label, what changes)
PERTURBATIONS: tuple[tuple[str, str, float], ...] = (
    ("throw +1%", "throw", 1.01), ("throw -1%", "throw", 0.99),
    ("contact stiffness +10%", "stiffness", 1.10), ("contact stiffness -10%", "stiffness", 0.90),
    ("half step", "step", 0.5),
)
#: the designed impacts' body and plane normals (body frame = world at rest; the bar's
#: long axis is z, its square section in x, y)
IMPACT_BODY = "bar-s-cuboid"
IMPACT_NORMALS: dict[str, tuple[float, float, float]] = {
    "face": (1.0, 0.0, 0.0), "edge": (1.0, 1.0, 0.0), "corner": (1.0, 1.0, 1.0)}
#: impact speeds (m/s) and the flight time (s) to the plane: the gap between the body
#: and the plane at t = 0 is speed × flight
IMPACT_SPEEDS: tuple[float, ...] = (1.5, 3.0)
IMPACT_FLIGHT = 0.008
#: steps of a designed impact's runs
IMPACT_STEPS = 200
#: the job name of the designed impacts among :func:`free_body_job`'s scene names
IMPACTS_JOB = "@impacts"
#: the reduced body restarts this many steps before the reference's first contact
PRE_STEPS = 3
#: an impact is over after this many consecutive samples without penetration
CLEAR_SAMPLES = 5


# ----------------------------------------------------------------- whole trajectory
def _common(output, other) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the sample times two runs share (to 1e-9 s)."""
    times, other_times = np.asarray(output.times), np.asarray(other.times)
    pairs = [(i, int(j[0])) for i, t in enumerate(times)
             if (j := np.flatnonzero(np.abs(other_times - t) < 1e-9)).size]
    if not pairs:
        raise LbshapeError("the two runs share no sample time")
    index = np.array(pairs)
    return index[:, 0], index[:, 1]


def run_difference(output, reference, mass) -> float | None:
    """The trajectory error of ``output`` against ``reference`` over the times they share
    (None if either stopped)."""
    if not (output.stats["stable"] and reference.stats["stable"]):
        return None
    mine, theirs = _common(output, reference)
    return float(trajectory_error(output.displacements[mine], reference.displacements[theirs],
                                  mass))


def perturbed(scene, kind: str, factor: float):
    """The scene with one perturbation of :data:`PERTURBATIONS` applied."""
    if kind == "throw":
        return with_throw(scene, factor)
    if kind == "stiffness":
        return with_contact_stiffness(scene, factor)
    if kind == "step":
        dt = scene.simulation.dt
        return with_step(scene, factor * dt, scene.simulation.steps * dt)
    raise LbshapeError(f"unknown perturbation {kind!r}")


@dataclass(frozen=True)
class NoiseFloor:
    """How far the full reference moves under :data:`PERTURBATIONS`.

    Attributes:
        changes: ``(label, trajectory change or None if the run stopped)`` per
            perturbation (the error norm of Table 2 against the unperturbed reference).
        rest_pose: ``(label, symmetric Chamfer distance of the final poses / diagonal)``.
    """

    changes: tuple[tuple[str, float | None], ...]
    rest_pose: tuple[tuple[str, float | None], ...]

    @property
    def floor(self) -> float | None:
        """The largest change (None if none could be measured)."""
        values = [value for _, value in self.changes if value is not None]
        return max(values) if values else None

    @property
    def rest_floor(self) -> float | None:
        """The largest rest-pose change."""
        values = [value for _, value in self.rest_pose if value is not None]
        return max(values) if values else None


def noise_floor(scene, pre, full, mass, *, steps: int) -> NoiseFloor:
    """The reference's noise floor of ``full`` (the scene's full run over ``steps``)."""
    triangles = pre.mesh.boundary_faces()
    rest = pre.mesh.points
    diagonal = _diagonal(rest)
    changes, poses = [], []
    duration = steps * scene.simulation.dt
    for label, kind, factor in PERTURBATIONS:
        variant = perturbed(scene, kind, factor)
        variant_steps = int(round(duration / variant.simulation.dt))
        log.info("noise floor %s: full, %s", scene.name, label)
        output = simulate(variant, pre, method="full", steps=variant_steps)
        change = run_difference(output, full, mass)
        pose = None
        if output.stats["stable"] and full.stats["stable"]:
            pose = surface_distance(rest + output.displacements[-1],
                                    rest + full.displacements[-1], triangles,
                                    diagonal).chamfer
        changes.append((label, change))
        poses.append((label, pose))
    return NoiseFloor(tuple(changes), tuple(poses))


def _diagonal(rest: np.ndarray) -> float:
    return float(np.linalg.norm(rest.max(axis=0) - rest.min(axis=0)))


def whole_run(scene, pre, output, full, mass, floor: float | None) -> dict:
    """The :data:`KEYS` of a run against its full reference (same scene and sampling):
    error before the reference's first contact, its time (s), the rest pose's symmetric
    Chamfer and Hausdorff distances over the diagonal, the noise floor given and the
    ratio of the whole-trajectory error to it."""
    result = dict.fromkeys(KEYS)
    result["noise_floor"] = floor
    if not (output.stats["stable"] and full.stats["stable"]):
        return result
    rest = pre.mesh.points
    contact = first_contact(rest + full.displacements, scene.planes)
    end = len(full.times) if contact is None else contact
    result["first_contact_s"] = None if contact is None else float(full.times[contact])
    result["error_pre_contact"] = window_error(output.displacements, full.displacements,
                                               mass, end)
    pose = surface_distance(rest + output.displacements[-1], rest + full.displacements[-1],
                            pre.mesh.boundary_faces(), _diagonal(rest))
    result["rest_pose_chamfer"], result["rest_pose_hausdorff"] = pose.chamfer, pose.hausdorff
    error = run_difference(output, full, mass)
    if error is not None and floor:
        result["error_over_floor"] = error / floor
    return result


# ------------------------------------------------------------------ restart, impacts
def restart_reduced(sim: Simulation, state, time: float, steps_taken: int = 0) -> None:
    """Put the reduced free body of ``sim`` in the projected ``state``
    (:class:`~lbshape.analysis.free_body_eval.ProjectedState`) at ``time`` (s): its
    snapshot with the body state replaced, the elastic force at q, the energy monitor
    restarted from the restart's energy (no work done yet)."""
    engine = sim.engine
    if not hasattr(engine, "elastic") or "now" not in engine.state.arrays:
        raise LbshapeError("a restart needs the reduced free-body engine")
    arrays = dict(engine.state.arrays)
    r = int(np.size(state.q))
    force = np.asarray(engine.elastic.force_and_tangent(np.asarray(state.q))[0], dtype=float)
    for key in ("now", "next"):
        body = BodyState.allocate(r)
        body.data[:] = arrays[key]
        for name in ("c", "p", "R", "L", "q", "qd", "qa"):
            getattr(body, name)[...] = getattr(state, name)
        body.f_elastic[:] = force
        arrays[key] = body.data
    scalars = {"time": float(time), "steps_taken": int(steps_taken), "work": 0.0,
               "_contact_calls": -1, "sweeps": 0, "total_sweeps": 0,
               "_elastic_energy": float(engine.elastic.energy(np.asarray(state.q)))}
    arrays.update({name: np.array(value) for name, value in scalars.items()})
    sim.reset(EngineState(float(time), arrays))
    arrays["energy0"] = np.array(float(engine.energy()))
    sim.reset(EngineState(float(time), arrays))


def _impact_end(points: np.ndarray, planes, start: int) -> int | None:
    """The first sample after ``start`` that begins :data:`CLEAR_SAMPLES` samples without
    penetration, after a penetrating one (None if the contact never ends in the run)."""
    depth = penetration(points, planes)
    touching = np.flatnonzero(depth[start:] > 0.0)
    if not touching.size:
        return None
    clear = depth == 0.0
    for index in range(start + int(touching[0]) + 1, len(points) - CLEAR_SAMPLES):
        if clear[index:index + CLEAR_SAMPLES].all():
            return index
    return None


@dataclass(frozen=True)
class ImpactComparison:
    """One designed impact, both methods from the same pre-impact state.

    Attributes:
        kind, speed, examples: the impact (``face``/``edge``/``corner``, m/s, examples on).
        full, reduced: the :class:`~lbshape.analysis.free_body_eval.ImpactMeasures`.
        restart_error: the reduced body's displacement right after the restart against
            the reference's (M-norm, over the reference's).
        message: why the comparison is missing ('' when it ran).
        arm: the length (m, the body's half diagonal) a ΔL error is measured against:
            ``|ΔL − ΔL_full| / max(|ΔL_full|, |Δp_full| arm)`` (a face hit changes L by
            about 0).
    """

    kind: str
    speed: float
    examples: bool
    full: object = None
    reduced: object = None
    restart_error: float | None = None
    message: str = ""
    arm: float = 0.5

    def stats(self) -> dict:
        """The JSON entry: each measure of both methods and the relative differences."""
        out = {"kind": self.kind, "speed": self.speed, "examples": self.examples,
               "restart_error": self.restart_error, "message": self.message}
        if self.full is None or self.reduced is None:
            return out
        f, r = self.full, self.reduced
        dp = float(np.linalg.norm(f.delta_p))
        arm = dp * self.arm
        out.update({
            "restitution_full": f.restitution, "restitution_reduced": r.restitution,
            "restitution_error": abs(r.restitution - f.restitution) / abs(f.restitution),
            "delta_p_full": float(dp), "delta_p_error": float(np.linalg.norm(
                r.delta_p - f.delta_p)) / dp,
            "delta_L_full": float(np.linalg.norm(f.delta_L)),
            "delta_L_error": float(np.linalg.norm(r.delta_L - f.delta_L)) / max(
                float(np.linalg.norm(f.delta_L)), arm),
            "energy_lost_full": f.energy_lost, "energy_lost_reduced": r.energy_lost,
            "depth_full_mm": 1e3 * f.depth, "depth_reduced_mm": 1e3 * r.depth,
        })
        return out


def designed_impact(base, pre, kind: str, speed: float, *, examples: bool,
                    steps: int = IMPACT_STEPS) -> ImpactComparison:
    """One designed impact of the free body ``base`` (its precompute ``pre``)."""
    rest = pre.mesh.points
    scene = impact_scene(base, rest, IMPACT_NORMALS[kind], speed, speed * IMPACT_FLIGHT,
                         f"{base.name}-{kind}-{speed:g}")
    if not examples:
        scene = without_examples(scene)
    mass = mass_matrix(pre.mesh, pre.material.density)
    dt = scene.simulation.dt
    result = ImpactComparison(kind, float(speed), examples, arm=0.5 * _diagonal(rest))
    full = Simulation(scene, pre, method="full")
    record = full.run(steps)
    if not record.stable:
        return dataclasses.replace(result, message=f"full run stopped: {record.message}")
    points_full = rest + full.displacements(record)
    contact = first_contact(points_full, scene.planes)
    if contact is None or contact < PRE_STEPS + 2:
        return dataclasses.replace(result, message="no contact after the flight")
    start = contact - PRE_STEPS
    projected = project_state(points_full[start - 1:start + 2], dt, rest, mass, pre.U)
    reduced = Simulation(scene, pre, method="reduced")
    restart_reduced(reduced, projected, start * dt, start)
    restart_error = float(trajectory_error(reduced.displacement()[None],
                                           points_full[start][None] - rest, mass))
    record_r = reduced.run(steps - start)
    if not record_r.stable:
        return dataclasses.replace(result, restart_error=restart_error,
                                   message=f"reduced run stopped: {record_r.message}")
    points_r = rest + reduced.displacements(record_r)
    window = points_full[start:]
    ends = [_impact_end(p, scene.planes, 0) for p in (window, points_r)]
    if None in ends or max(ends) > len(window) - 2:
        return dataclasses.replace(result, restart_error=restart_error,
                                   message="the impact does not end within the run")
    after = max(ends)
    gravity = np.asarray(scene.loads[0].vector if scene.loads else (0.0, 0.0, 0.0))
    normal = np.asarray(scene.planes[0].normal)
    measures = [impact_measures(p, mass, dt, normal, gravity, scene.planes, 1, after)
                for p in (window, points_r)]
    return dataclasses.replace(result, full=measures[0], reduced=measures[1],
                               restart_error=restart_error)


def designed_impacts(base, pre, *, kinds: Sequence[str] = tuple(IMPACT_NORMALS),
                     speeds: Sequence[float] = IMPACT_SPEEDS,
                     steps: int = IMPACT_STEPS) -> list[ImpactComparison]:
    """Every designed impact (kinds × speeds × with/without examples)."""
    out = []
    for examples in (False, True):
        for kind in kinds:
            for speed in speeds:
                log.info("impact %s %s %g m/s examples %s", base.name, kind, speed, examples)
                out.append(designed_impact(base, pre, kind, speed, examples=examples,
                                           steps=steps))
    return out


def ratio_text(error: float | None, floor: float | None) -> str:
    """``error / floor`` as text (— when undefined)."""
    if error is None or not floor or not math.isfinite(error):
        return "—"
    return f"{error / floor:.1f}"


# ------------------------------------------------------------------- per scene
@dataclass(frozen=True)
class WholeRun:
    """One free body's whole-trajectory evaluation with or without its examples.

    Attributes:
        scene: the scene's name.
        examples: whether its examples act.
        error: Table 2's whole-trajectory error of the reduced run against full (None
            if a run stopped).
        keys: the :data:`KEYS` (:func:`whole_run`).
        floor: the reference's :class:`NoiseFloor`.
    """

    scene: str
    examples: bool
    error: float | None
    keys: dict
    floor: NoiseFloor

    def stats(self) -> dict:
        """The JSON entry."""
        return {"scene": self.scene, "examples": self.examples, "error_vs_full": self.error,
                **self.keys, "floor_changes": dict(self.floor.changes),
                "floor_rest_pose_chamfer": dict(self.floor.rest_pose)}


def evaluate_scene(scene, pre, *, steps: int | None = None,
                   perturb: bool = True) -> list[WholeRun]:
    """The whole-trajectory evaluation of a free body, with its examples and (if it has
    an example force) without: full and reduced runs, the noise floor (``perturb``
    False: no floor) and :func:`whole_run`."""
    if not scene.is_free:
        raise LbshapeError(f"scene {scene.name} is not a free body")
    steps = scene.simulation.steps if steps is None else int(steps)
    mass = mass_matrix(pre.mesh, pre.material.density)
    variants = [(True, scene)]
    if scene.examples is not None and scene.examples.stiffness != 0:
        variants.append((False, without_examples(scene)))
    out = []
    for examples, variant in variants:
        log.info("free bodies %s (examples %s): full and reduced", scene.name, examples)
        full = simulate(variant, pre, method="full", steps=steps)
        reduced = simulate(variant, pre, method="reduced", steps=steps)
        floor = (noise_floor(variant, pre, full, mass, steps=steps) if perturb
                 else NoiseFloor((), ()))
        keys = whole_run(variant, pre, reduced, full, mass, floor.floor)
        out.append(WholeRun(scene.name, examples and len(variants) == 2,
                            run_difference(reduced, full, mass), keys, floor))
    return out


def free_body_job(item: str, *, steps: int | None = None) -> tuple[str, list]:
    """One job of ``lbshape bench --free-bodies`` (picklable, for worker processes):
    ``("impacts", designed impacts of IMPACT_BODY)`` for :data:`IMPACTS_JOB`, else
    ``("whole", evaluate_scene of the scene item)``."""
    from lbshape.pipeline.precompute import precompute
    from lbshape.scene.reader import load_scene

    if item == IMPACTS_JOB:
        body = load_scene(IMPACT_BODY)
        return "impacts", designed_impacts(body, precompute(body))
    scene = load_scene(item)
    return "whole", evaluate_scene(scene, precompute(scene), steps=steps)
