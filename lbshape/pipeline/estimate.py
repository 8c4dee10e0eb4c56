"""The error estimate of a reduced run (:mod:`lbshape.analysis.error_estimate`) wired to a
scene and its precompute: the full-space force, mass and rest stiffness of the object,
its loads, and one sparse factor of the effective stiffness at the frame spacing: the
precompute's stored one at :data:`~lbshape.analysis.error_estimate.FACTOR_SPACING` for the
scene's damping, else one made here (:func:`lbshape.fem.cholesky.serial_cholesky`). Runs
after the run on its saved frames.

Free bodies: the estimate does not model the rigid motion nor impacts; a free body
reports ``None`` with the reason (the time of its first contact with a plane when it
touches one). Local examples: their spring ``k_ex S u`` and pull outside the basis are not
in the residual; such a run reports its estimate with a caveat in the message. Cubature
forces (not the exact projection of the full force): ``None`` with the reason.
"""

from __future__ import annotations

import time

import numpy as np

from lbshape.analysis.error_estimate import (
    DENSE_DOFS,
    MAX_FRAMES,
    ErrorEstimate,
    EstimateOperators,
    FrameForces,
    ResidualErrorEstimator,
    select_frames,
    unavailable,
)
from lbshape.dynamics.record import RunRecord
from lbshape.errors import LbshapeError
from lbshape.fem.cholesky import serial_cholesky
from lbshape.geometry.mesh import free_dof_mask
from lbshape.pipeline.precomputed import Precomputed
from lbshape.pipeline.responses import mesh_load_patterns
from lbshape.scene.schema import Scene

#: the stats keys the estimate fills
STATS_KEYS = ("error_estimate", "error_estimate_message", "error_estimate_ms")


def estimate_operators(scene: Scene, mesh, material, fixed: np.ndarray,
                       U: np.ndarray) -> dict[str, np.ndarray]:
    """The ``estimate`` stage of the precompute: everything per object the estimate reads
    (:class:`~lbshape.analysis.error_estimate.EstimateOperators` as arrays): the
    full-space force operators, M and K₀ with the fixed dofs' rows and columns zero, M U,
    K₀ U, the loads' patterns (their size; the profiles are the run's) and the factor of
    the effective stiffness at the stored frame spacing for the scene's damping."""
    forces = FrameForces(mesh.points, mesh.tets, material)
    keep = free_dof_mask(mesh.n_vertices, fixed)
    mass, stiffness = forces.operators(material.density, keep)
    patterns = np.zeros((3 * mesh.n_vertices, 0))
    if scene.loads:  # the patterns need the mass of every dof (reactions included)
        patterns = np.stack([load.pattern for load in mesh_load_patterns(
            scene, mesh, forces.mass(material.density))], axis=1)
    return EstimateOperators.build(forces, U, mass, stiffness, keep, patterns,
                                   damping=(scene.damping.alpha, scene.damping.beta)).arrays()


def estimator(scene: Scene, pre: Precomputed) -> ResidualErrorEstimator:
    """The :class:`~lbshape.analysis.error_estimate.ResidualErrorEstimator` of a fixed
    object's scene: from the precompute's ``estimate`` stage (:attr:`Precomputed.
    estimate`), or built here (n-sized set-up) for a precompute without it."""
    arrays = pre.estimate
    if arrays is None:
        arrays = estimate_operators(scene, pre.mesh, pre.material, pre.fixed_vertices, pre.U)
    operators = EstimateOperators.from_arrays(arrays, pre.material)
    loads = []
    if scene.loads:
        loads = [(operators.patterns[:, i], load.profile)
                 for i, load in enumerate(scene.loads)]
    return ResidualErrorEstimator.from_operators(
        operators, pre.U, alpha=scene.damping.alpha, beta=scene.damping.beta, loads=loads)


def estimate_error(scene: Scene, pre: Precomputed, record: RunRecord,
                   frames: np.ndarray | None = None, *, max_frames: int = MAX_FRAMES
                   ) -> ErrorEstimate:
    """The error estimate of a reduced run's record (its saved frames), or ``None`` with a
    reason: a run that stopped, a free body (``frames``: its (f, n, 3) world displacements,
    to find its first contact). ``max_frames``: the most frame intervals integrated over
    (:func:`~lbshape.analysis.error_estimate.select_frames`). ``seconds``: the whole
    estimate, set-up and factor included."""
    started = time.perf_counter()
    if not record.stable:
        return unavailable("the run stopped: " + record.message)
    if scene.is_free:
        return unavailable(free_body_reason(scene, pre, record, frames))
    if pre.elastic.force_model != "polynomial":
        return unavailable(CUBATURE_REASON)
    times, Q, Qdot = select_frames(record.times, record.states, max_frames)
    if len(times) < 2:
        return ErrorEstimate(0.0, "", np.zeros(len(times)),
                             time.perf_counter() - started)
    est = estimator(scene, pre)
    spacing = float(times[1] - times[0])
    size = est.size(np.asarray(record.states, dtype=float))
    try:
        stored = est.stored_solver(spacing)
        if stored is not None:
            result = est.estimate(times, Q, stored, Qdot=Qdot, size=size)
        elif est.U.shape[0] <= DENSE_DOFS:
            result = est.estimate(times, Q, est.dense_solver(spacing), Qdot=Qdot, size=size)
        else:
            with serial_cholesky(est.effective_matrix(spacing),
                                 what="the effective stiffness of the error estimate") as solve:
                result = est.estimate(times, Q, solve.vector, Qdot=Qdot, size=size)
    except (LbshapeError, np.linalg.LinAlgError) as exc:
        return unavailable(f"the estimate failed: {exc}")
    caveat = LOCAL_EXAMPLES_CAVEAT if _local_examples_act(scene, pre) else result.message
    return ErrorEstimate(result.value, caveat, result.norms, time.perf_counter() - started)


#: why a run with cubature forces has no estimate
CUBATURE_REASON = (
    "cubature forces: the force model's own error inside the basis is not in the estimate "
    "(the residual assumes the exact projection of the full force, the polynomial forces); "
    "on bar-cuboid with a 60-element cubature the estimate missed most of the error")


#: the caveat that comes with the estimate of a run with local examples
LOCAL_EXAMPLES_CAVEAT = (
    "caveat: local examples' spring and pull outside the basis are not in the residual; "
    "the estimate may be low (0.6x the measured error on teddy-local with its examples)")


def _local_examples_act(scene: Scene, pre: Precomputed) -> bool:
    """A local example force acts (k_ex > 0 and local examples precomputed)."""
    return (scene.examples is not None and scene.examples.acts
            and pre.has_local_examples and not pre.has_examples)


def free_body_reason(scene: Scene, pre: Precomputed, record: RunRecord,
                     frames: np.ndarray | None) -> str:
    """Why a free body has no estimate: its first contact, or its rigid motion."""
    if scene.planes and frames is not None and len(frames):
        points = pre.mesh.points[None] + np.asarray(frames)  # (f, n, 3) world
        for plane in scene.planes:
            normal = np.asarray(plane.normal, dtype=float)
            normal = normal / np.linalg.norm(normal)
            gaps = ((points - np.asarray(plane.point, dtype=float)) @ normal).min(axis=1)
            touching = np.flatnonzero(gaps <= 0.0)
            if touching.size:
                t = float(record.times[touching[0]])
                return (f"free body: not trusted after its first contact with a plane "
                        f"(t = {t:.3f} s); impacts and the rigid motion are outside the "
                        f"estimate's model")
    return ("free body: the estimate covers fixed objects only (the rigid motion is outside "
            "its model)")


def estimate_stats(scene: Scene, pre: Precomputed, method: str, record: RunRecord,
                   frames: np.ndarray) -> dict:
    """The ``stats.json`` keys (:data:`STATS_KEYS`) of a run of ``method``: the estimate of a
    reduced or euclidean run (:func:`estimate_error`); ``None`` for the full reference."""
    if method == "full":
        return stats(unavailable("the full-space reference: no reduction error to estimate"))
    return stats(estimate_error(scene, pre, record, frames))


def stats(estimate: ErrorEstimate) -> dict:
    """The ``stats.json`` keys of an estimate (:data:`STATS_KEYS`): the estimated relative
    trajectory error (a fraction, or None), why it is None ('' otherwise) and its wall time
    in ms."""
    return {"error_estimate": estimate.value,
            "error_estimate_message": estimate.message,
            "error_estimate_ms": 1e3 * estimate.seconds}
