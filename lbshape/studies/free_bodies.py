"""Free bodies evaluated the way the field evaluates them (``lbshape bench --free-bodies``).

Beside the whole-trajectory error of Table 2, per free body (car, bar-s-cuboid,
bar-s-cylinder), with and without its examples:

* **before contact** — the error up to the first sample at which any vertex of the full
  reference penetrates a plane (:func:`~lbshape.analysis.free_body_eval.window_error`);
* **rest pose** — the symmetric surface-to-surface distance of the final poses over the
  diagonal (:func:`~lbshape.analysis.free_body_eval.surface_distance`): a symmetric
  object settling in an equivalent pose scores 0;
* **the reference's noise floor** — the full reference re-run with the throw ±1 %, the
  contact stiffness ±10 % and half the step (:data:`PERTURBATIONS`), and here also on the
  object meshed at half its size (:func:`refinement_change`: its displacements
  interpolated onto this mesh's vertices); the largest change of its trajectory (the same
  norm as the error) is the floor printed beside every whole-trajectory error, with the
  ratio error / floor;
* **designed impacts** (:func:`designed_impact`) — the bar and the car
  (:data:`IMPACT_DESIGNS`) thrown at a plane so that a face, an edge or a corner hits at
  two speeds, with and without examples; the reduced body restarts from the
  full run's state projected onto its coordinates and frame
  (:func:`~lbshape.analysis.free_body_eval.project_state`, :func:`restart_reduced`)
  :data:`PRE_STEPS` steps before the first contact, and both run through the impact:
  restitution, change of linear and angular momentum, energy lost, deepest penetration.

The engines are driven through :class:`~lbshape.pipeline.simulation.Simulation` and
:func:`~lbshape.pipeline.simulate.simulate`; the restart writes the projected state into
the reduced free-body engine's snapshot (:attr:`Engine.state
<lbshape.dynamics.engine.Engine.state>`, its ``now`` body state) and restores it.
:func:`write_free_bodies` writes ``free_bodies.md`` and ``free_bodies.json`` (errors only,
no timings).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import subprocess
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lbshape.analysis.free_body_eval import (
    CONTACT_DEPTH,
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
from lbshape.geometry.mesh import interpolate_at
from lbshape.io.atomic import write_json_atomic, write_text_atomic
from lbshape.io.machine import load_text, machine_description, threads_text
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import simulate
from lbshape.pipeline.simulation import Simulation
from lbshape.scene.reader import load_scene
from lbshape.scene.variants import (
    impact_scene,
    with_contact_stiffness,
    with_mesh_size,
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
#: the noise floor's mesh refinement: the object's mesh size times this, and its label
REFINEMENT = 0.5
REFINEMENT_LABEL = "mesh h/2"


@dataclass(frozen=True)
class ImpactDesign:
    """The designed impacts of one free body: plane normals (body frame = world at rest)
    of a face, an edge and a corner hit, the speeds (m/s), and the words the report
    describes them with."""

    normals: dict[str, tuple[float, float, float]]
    speeds: tuple[float, ...]
    description: str


#: the free bodies with designed impacts (the bars of bar-s-cuboid and bar-s-cylinder
#: are one body): the Figure 4 bar at 1.5 and 3 m/s; the car's front, where its scene
#: hits the wall, at its throw speed (5 m/s) and half of it
IMPACT_DESIGNS: dict[str, ImpactDesign] = {
    "bar-s-cuboid": ImpactDesign(
        {"face": (1.0, 0.0, 0.0), "edge": (1.0, 1.0, 0.0), "corner": (1.0, 1.0, 1.0)},
        (1.5, 3.0), "the Figure 4 bar (long axis z, square section in x, y) thrown along −n "
        "at a plane of normal n: face hit n = x, edge hit n = (x + y)/√2, corner hit "
        "n = (x + y + z)/√3"),
    "car": ImpactDesign(
        {"face": (-1.0, 0.0, 0.0), "edge": (-1.0, -1.0, 0.0), "corner": (-1.0, -1.0, 1.0)},
        (2.5, 5.0), "the car (length along x, front at +x, bottom at z = 0) thrown along "
        "−n at a plane of normal n: its front face n = −x (its scene's wall hit), the "
        "front left edge n = −(x + y)/√2, the lower front left corner "
        "n = (−x − y + z)/√3"),
}
#: the Figure 4 bar's impacts, the ones ``scripts/bench_impact_columns.py`` compares
IMPACT_BODY = "bar-s-cuboid"
IMPACT_NORMALS = IMPACT_DESIGNS[IMPACT_BODY].normals
IMPACT_SPEEDS = IMPACT_DESIGNS[IMPACT_BODY].speeds
#: the flight time (s) to the plane: the gap between the body and the plane at t = 0 is
#: speed × flight
IMPACT_FLIGHT = 0.008
#: steps of a designed impact's runs
IMPACT_STEPS = 200
#: the job names of the designed impacts among :func:`free_body_job`'s scene names start
#: with this, the body's name after it
IMPACTS_JOB = "@impacts:"
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


def noise_floor(scene, pre, full, mass, *, steps: int, refine: bool = False) -> NoiseFloor:
    """The reference's noise floor of ``full`` (the scene's full run over ``steps``): the
    :data:`PERTURBATIONS`, and with ``refine`` the mesh refinement
    (:func:`refinement_change`) where the object is a built-in shape."""
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
    if refine and scene.object.shape is None:
        log.info("noise floor %s: no %s (the object is not a built-in shape)", scene.name,
                 REFINEMENT_LABEL)
    elif refine:
        change, pose = refinement_change(scene, pre, full, mass, steps=steps)
        changes.append((REFINEMENT_LABEL, change))
        poses.append((REFINEMENT_LABEL, pose))
    return NoiseFloor(tuple(changes), tuple(poses))


def refinement_change(scene, pre, full, mass, *, steps: int
                      ) -> tuple[float | None, float | None]:
    """How far the full reference moves when the object is meshed at :data:`REFINEMENT`
    times its size (:func:`~lbshape.scene.variants.with_mesh_size`): the refined run's
    displacements are interpolated onto this mesh's rest vertices (P1, in the refined rest
    mesh: :func:`~lbshape.geometry.mesh.interpolate_at`) and compared with ``full`` in the
    error's norm, and its final surface by the Chamfer distance over the diagonal.
    (None, None) if either run stopped."""
    variant = with_mesh_size(scene, REFINEMENT)
    log.info("noise floor %s: full, %s", scene.name, REFINEMENT_LABEL)
    fine = precompute(variant)
    output = simulate(variant, fine, method="full", steps=steps)
    if not (output.stats["stable"] and full.stats["stable"]):
        return None, None
    rest = pre.mesh.points
    moved = interpolate_at(fine.mesh.points, fine.mesh.tets, output.displacements, rest)
    change = run_difference(dataclasses.replace(output, displacements=moved), full, mass)
    pose = surface_distance(rest + moved[-1], rest + full.displacements[-1],
                            pre.mesh.boundary_faces(), _diagonal(rest)).chamfer
    return change, pose


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
    r = int(np.size(state.q))
    if getattr(engine, "per_feature", False):
        # impact columns per feature: on the plain basis, the hit's onset picks the set
        r = engine.leading
    elif hasattr(engine, "switch_columns"):  # an impact: the basis with its impact columns
        engine.switch_columns(True)
    if not hasattr(engine, "elastic") or "now" not in engine.state.arrays:
        raise LbshapeError("a restart needs the reduced free-body engine")
    arrays = dict(engine.state.arrays)
    state = dataclasses.replace(state, q=state.q[:r], qd=state.qd[:r], qa=state.qa[:r])
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
    touching = np.flatnonzero(depth[start:] > CONTACT_DEPTH)
    if not touching.size:
        return None
    clear = depth <= CONTACT_DEPTH
    for index in range(start + int(touching[0]) + 1, len(points) - CLEAR_SAMPLES):
        if clear[index:index + CLEAR_SAMPLES].all():
            return index
    return None


@dataclass(frozen=True)
class ImpactComparison:
    """One designed impact, both methods from the same pre-impact state.

    Attributes:
        kind, speed, examples: the impact (``face``/``edge``/``corner``, m/s, examples on).
        body: the free body's scene name.
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
    body: str = IMPACT_BODY

    def stats(self) -> dict:
        """The JSON entry: each measure of both methods and the relative differences."""
        out = {"body": self.body, "kind": self.kind, "speed": self.speed,
               "examples": self.examples,
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
    """One designed impact of the free body ``base`` (its precompute ``pre``; the normals
    of its :data:`IMPACT_DESIGNS` entry, the bar's for a body without one)."""
    rest = pre.mesh.points
    normal = impact_design(base.name).normals[kind]
    scene = impact_scene(base, rest, normal, speed, speed * IMPACT_FLIGHT,
                         f"{base.name}-{kind}-{speed:g}")
    if not examples:
        scene = without_examples(scene)
    mass = mass_matrix(pre.mesh, pre.material.density)
    dt = scene.simulation.dt
    result = ImpactComparison(kind, float(speed), examples, arm=0.5 * _diagonal(rest),
                              body=base.name)
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


def impact_design(name: str) -> ImpactDesign:
    """The :data:`IMPACT_DESIGNS` entry of the scene ``name`` (the bar's for a body
    without one)."""
    return IMPACT_DESIGNS.get(name, IMPACT_DESIGNS[IMPACT_BODY])


def designed_impacts(base, pre, *, kinds: Sequence[str] | None = None,
                     speeds: Sequence[float] | None = None,
                     steps: int = IMPACT_STEPS) -> list[ImpactComparison]:
    """Every designed impact (kinds × speeds × with/without examples; by default the
    body's :func:`impact_design`)."""
    design = impact_design(base.name)
    out = []
    for examples in (False, True):
        for kind in kinds or tuple(design.normals):
            for speed in speeds or design.speeds:
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
        floor = (noise_floor(variant, pre, full, mass, steps=steps, refine=True) if perturb
                 else NoiseFloor((), ()))
        keys = whole_run(variant, pre, reduced, full, mass, floor.floor)
        out.append(WholeRun(scene.name, examples and len(variants) == 2,
                            run_difference(reduced, full, mass), keys, floor))
    return out


def impact_jobs() -> list[str]:
    """The job names of the designed impacts of every body of :data:`IMPACT_DESIGNS`."""
    return [IMPACTS_JOB + name for name in IMPACT_DESIGNS]


def free_body_job(item: str, *, steps: int | None = None) -> tuple[str, list]:
    """One job of ``lbshape bench --free-bodies`` (picklable, for worker processes):
    ``("impacts", designed impacts of the body)`` for ``IMPACTS_JOB + body``
    (:func:`impact_jobs`), else ``("whole", evaluate_scene of the scene item)``."""
    if item.startswith(IMPACTS_JOB):
        body = load_scene(item[len(IMPACTS_JOB):])
        return "impacts", designed_impacts(body, precompute(body))
    scene = load_scene(item)
    return "whole", evaluate_scene(scene, precompute(scene), steps=steps)


# ------------------------------------------------------------------- the report
#: the command that writes the files
COMMAND = "OMP_NUM_THREADS=1 lbshape bench --free-bodies"


def _pct(value) -> str:
    return "—" if value is None else f"{100 * value:.2f}%"


def _num(value, digits: int = 3) -> str:
    return "—" if value is None else f"{value:.{digits}f}"


def _sci(value) -> str:
    return "—" if value is None else f"{value:.1e}"


def _commit() -> str:
    try:
        done = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, cwd=Path(__file__).parent, check=False)
    except OSError:
        return "unknown"
    return done.stdout.strip() or "unknown"


def whole_lines(runs: Sequence[WholeRun]) -> list[str]:
    """The whole-trajectory table with the noise floor beside each error."""
    labels = [label for label, _, _ in PERTURBATIONS]
    if any(label == REFINEMENT_LABEL for run in runs for label, _ in run.floor.changes):
        labels.append(REFINEMENT_LABEL)
    lines = [
        "| model | examples | error (whole trajectory) | noise floor | error / floor | "
        "error before first contact | first contact (s) | rest pose Chamfer | "
        "rest pose Hausdorff | rest-pose floor | " + " | ".join(labels) + " |",
        "|---|---|---|---|---|---|---|---|---|---|" + "---|" * len(labels),
    ]
    for run in runs:
        keys, changes = run.keys, dict(run.floor.changes)
        lines.append(
            f"| {run.scene} | {'yes' if run.examples else 'no'} | {_pct(run.error)} | "
            f"{_pct(keys['noise_floor'])} | {ratio_text(run.error, keys['noise_floor'])} | "
            f"{_pct(keys['error_pre_contact'])} | {_num(keys['first_contact_s'])} | "
            f"{_pct(keys['rest_pose_chamfer'])} | {_pct(keys['rest_pose_hausdorff'])} | "
            f"{_pct(run.floor.rest_floor)} | "
            + " | ".join(_pct(changes.get(label)) for label in labels) + " |")
    return lines


def impact_met(impact: ImpactComparison) -> bool | None:
    """Whether the impact meets its target (restitution, Δp and ΔL within 5 % without
    examples, 10 % with); None when it did not run."""
    if impact.full is None or impact.reduced is None:
        return None
    s = impact.stats()
    limit = 0.10 if impact.examples else 0.05
    return max(s["restitution_error"], s["delta_p_error"], s["delta_L_error"]) <= limit


def impacts_summary(impacts: Sequence[ImpactComparison]) -> str:
    """'k of n within 5 % without examples, k of n within 10 % with'."""
    parts = []
    for examples, limit, words in ((False, 5, "without examples"), (True, 10, "with")):
        rows = [impact for impact in impacts if impact.examples == examples]
        met = sum(bool(impact_met(impact)) for impact in rows)
        parts.append(f"{met} of {len(rows)} within {limit} % {words}")
    return ", ".join(parts)


def impact_lines(impacts: Sequence[ImpactComparison]) -> list[str]:
    """The designed impacts' table, full against reduced."""
    lines = [
        "| hit | speed (m/s) | examples | restart error | restitution full / reduced | "
        "restitution error | Δp error | ΔL error | energy lost full / reduced | "
        "deepest penetration full / reduced (mm) | within 5 % / 10 % |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for impact in impacts:
        s = impact.stats()
        head = f"| {impact.kind} | {impact.speed:g} | {'yes' if impact.examples else 'no'} | "
        if impact.full is None:
            lines.append(head + f"{_sci(impact.restart_error)} | — | {impact.message} |"
                         + " — |" * 5)
            continue
        lines.append(
            head + f"{_sci(impact.restart_error)} | {s['restitution_full']:.3f} / "
            f"{s['restitution_reduced']:.3f} | {_pct(s['restitution_error'])} | "
            f"{_pct(s['delta_p_error'])} | {_pct(s['delta_L_error'])} | "
            f"{_pct(s['energy_lost_full'])} / {_pct(s['energy_lost_reduced'])} | "
            f"{s['depth_full_mm']:.2f} / {s['depth_reduced_mm']:.2f} | "
            f"{'yes' if impact_met(impact) else '**no**'} |")
    return lines


def _impact_sections(impacts: Sequence[ImpactComparison]) -> list[str]:
    """One section per body: its design, the count within target and the table."""
    lines = []
    for body in dict.fromkeys(impact.body for impact in impacts):
        rows = [impact for impact in impacts if impact.body == body]
        design = impact_design(body)
        lines += [f"### {body}: {impacts_summary(rows)}", "",
                  f"{design.description[0].upper()}{design.description[1:]}; "
                  f"{' and '.join(f'{v:g}' for v in design.speeds)} m/s.", "",
                  *impact_lines(rows), ""]
    return lines


def write_free_bodies(runs: Sequence[WholeRun], impacts: Sequence[ImpactComparison],
                      out_dir: Path, *, command: str = COMMAND) -> tuple[Path, Path]:
    """Write ``free_bodies.md`` and ``free_bodies.json`` to ``out_dir``."""
    machine = machine_description()
    perturbations = ", ".join(label for label, _, _ in PERTURBATIONS)
    perturbations += (f" and the object meshed at {REFINEMENT:g} × its size ({REFINEMENT_LABEL}: "
                      "the refined run's displacements interpolated onto this mesh's rest "
                      "vertices, P1 in the refined rest mesh)")
    text = "\n".join([
        "# Free bodies: before contact, per impact, at rest, and the reference's noise floor",
        "",
        f"Command: `{command}` (commit {_commit()}). Errors only, no timings.",
        "",
        "## Whole trajectories beside the reference's noise floor",
        "",
        "Error: Table 2's `max_t ‖u − u_full‖_M / max_t ‖u_full‖_M` of the reduced run. "
        f"Noise floor: the largest change of the full reference under {perturbations} "
        "(each re-run measured against the unperturbed reference with the same norm, over "
        "the sample times both have); the per-perturbation changes are the last columns. "
        "Error / floor below about 1: the difference is inside what the reference itself "
        "does not determine. Error before first contact: the same norm over the samples "
        "before the first one at which a vertex of the reference is behind a plane. Rest "
        "pose: the symmetric Chamfer (mean) and Hausdorff (largest) distance between the "
        "final surfaces (each surface vertex to the other surface's triangles, both ways) "
        "over the rest shape's bounding-box diagonal, blind to which vertex is where (a "
        "square bar turned 90° about its long axis scores 0); the rest-pose floor: the "
        "largest Chamfer distance between the perturbed and the unperturbed reference.",
        "",
        *whole_lines(runs),
        "",
        "## Designed impacts from a synchronised pre-impact state",
        "",
        "Each body thrown at a plane (below) without gravity (the impact alone), from "
        f"{1e3 * IMPACT_FLIGHT:g} ms of flight away, {IMPACT_STEPS} steps. The full run "
        f"goes first; {PRE_STEPS} steps before its "
        "first contact its state (positions and central-difference velocities) is "
        "projected onto the reduced coordinates and frame (best mass-weighted rigid fit, "
        "momenta, q and its differences by least squares in M) and the reduced body "
        "restarts there (restart error: its displacement against the reference's at the "
        "restart, M-norm, relative). Both then run through the impact; the comparison "
        f"window ends at the first sample that starts {CLEAR_SAMPLES} samples without "
        "penetration in both runs. Restitution `−v_n(after)/v_n(before)` of the centre "
        "of mass (negative: the centre still moves towards the plane after a corner or "
        "edge hit turned the body); Δp: the contact's change of linear momentum "
        "(no other load acts), error `|Δp − Δp_full| / |Δp_full|`; ΔL: change of "
        "angular momentum about the centre of mass, error `|ΔL − ΔL_full| / "
        "max(|ΔL_full|, |Δp_full| × half diagonal)`; energy lost: kinetic energy lost over "
        "the centre's kinetic energy before (the vibration's elastic energy counts as lost). "
        "Target: restitution, Δp and ΔL within 5 % without examples, 10 % with.",
        "",
        *_impact_sections(impacts),
        "## Conditions",
        "",
        f"- Machine: {machine['cpu']}, {machine['cores']} cores, Python {machine['python']},"
        f" numpy {machine['numpy']}; threads: {threads_text(machine)}.",
        f"- Load average (1, 5, 15 min) when written: {load_text(machine)} (no timings here).",
        "",
    ])
    out_dir = Path(out_dir)
    md = write_text_atomic(out_dir / "free_bodies.md", text)
    js = write_json_atomic(out_dir / "free_bodies.json", {
        "command": command, "whole": [run.stats() for run in runs],
        "impacts": [impact.stats() for impact in impacts], "machine": machine})
    return md, js
