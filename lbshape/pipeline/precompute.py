"""The precompute pipeline of a scene: its stages, run once and cached.

Stages (only those the scene needs; paper pre-computation steps 1–6), in order:

1. ``mesh``: the object's rest mesh and its fixed vertices;
2. ``modes``: linear elastic modes (fixed vertices from the scene);
3. ``derivatives``: modal derivatives (Barbič & James), and with the same
   factorisation of K the static responses to the scene's loads
   (:mod:`lbshape.pipeline.responses`);
4. ``basis``: mass-PCA nonlinear basis U (3n, r), ``UᵀMU = I``: the linear modes, the
   static responses, then the modal derivatives' principal components;
5. ``lb``: the object's LB spectrum (m pairs)                — scenes with examples;
6. ``examples``: example meshes, poses, frame and basis alignment, displacement
   coefficients                                              — scenes with examples;
7. ``target-table``: the exact interpolation target tabulated over the weight
   simplex (1–3 examples), checked against the exact target at held-out weights
   (:mod:`lbshape.shapespace.example_targets`)                  — scenes with examples;
8. ``lb-cubature``: one cubature per example for the LB displacement subspace (the
   ``lb`` interpolation route), trained on the example's rest shape along the path of
   exact targets between the examples                         — scenes with examples;
9. ``static-equilibria``: the object's nonlinear static equilibria under the scene's
   loads at full strength and at half of it
   (:func:`~lbshape.elastic.static_equilibrium.static_equilibria`), appended to U where
   it misses them               — fixed objects with loads, up to
   :data:`STATIC_EQUILIBRIA_MAX_VERTICES` vertices;
10. ``example-stiffness``: ``stiffness = "auto"`` only: k_ex from the examples' own
    stiffness (their shapes' ω² on the object) and the loads' generalized force
    (:func:`~lbshape.shapespace.auto_stiffness.auto_example_stiffness`), local examples'
    raised to their regions' static equilibrium (:mod:`~lbshape.shapespace.local_equilibrium`;
    stored: :attr:`~lbshape.pipeline.precomputed.Precomputed.auto_stiffness`);
11. ``example-basis``: the object's responses to the example pull (Krylov blocks of the
    spring-shifted stiffness on the examples' targets,
    :func:`~lbshape.pipeline.responses.example_responses`) that U misses, appended to it
    up to :data:`MAX_APPENDED_BASIS` columns (a free body: without their rigid part, up to
    :data:`MAX_APPENDED_FREE_BODY`, and at least :data:`MIN_APPENDED_FREE_BODY` beyond its
    own r); a strong local pull's anchored read-outs beyond — scenes with examples (k_ex > 0);
12. ``impact-basis``: impact columns from short full-space throws at the object's hull
    features, appended last, with their own polynomial energy and a linear coupling
    (:mod:`lbshape.pipeline.impact_columns`)
    — free bodies with ``reduced.impact_columns`` > 0;
13. ``cubature``: optimized cubature for the reduced elastic force on the final U
    without its impact columns (the force model of non-StVK materials and large meshes,
    and the energy of the ``modal`` route);
14. ``forces``: the exact reduced StVK force as polynomials in q (K, C̃, D̃ of
    :class:`~lbshape.elastic.polynomial_forces.PolynomialForceModel`) — StVK scenes
    whose ``reduced.forces`` resolves to ``polynomial`` (without the impact columns);
15. ``projections``: the maps ``T = Uᵀ M L`` of LB coefficients to the final reduced
    coordinates (:func:`~lbshape.shapespace.projections.reduced_projection`; also for
    the clamped LB basis, faded to zero at the fixed vertices) — scenes with examples;
16. ``frame``: the rigid frame's reduced inertia and fictitious-force tensors
    (:mod:`lbshape.dynamics.fictitious`)                      — free bodies.

Scenes with ``[[regions]]`` (local examples) replace stages 6–8 by
``regions``: per-region spectra and example parts embedded per region (their small
matrices in reduced coordinates come in ``projections``,
:meth:`~lbshape.shapespace.local_space.LocalShapeSpace.projected`); stage 5 still
computes the whole object's spectrum (eigenfunction pictures, and the measured
comparison of the two local-example variants).

The artifact (:mod:`lbshape.pipeline.precomputed`) is cached under
:func:`~lbshape.pipeline.precompute_key.scene_cache_key`, each stage's result under
:func:`~lbshape.pipeline.precompute_key.stage_keys` (what it reads); each stage's time,
peak memory, ranks and cache hit are recorded by :mod:`lbshape.pipeline.stages`.

**MPI.** ``precompute(scene, comm=MPI.COMM_WORLD)`` on every rank distributes the
n-sized stages over the ranks: ``modes`` and ``lb`` (DOLFINx assembly, SLEPc with
MUMPS), ``derivatives`` (parallel assembly, one MUMPS factorisation), and the element
passes of ``cubature`` and ``lb-cubature`` (split with
:func:`lbshape.fem.mpi.rank_share`; their inputs broadcast from rank 0). The other
stages run on rank 0 only (:func:`lbshape.fem.mpi.compute_on_root`: the other ranks
sleep, and a user error on rank 0 is raised on every rank). Rank 0 alone reads and
writes the cache (the artifact; stage entries serve serial runs only) and gets the
:class:`~lbshape.pipeline.precomputed.Precomputed`, the others ``None``. ``stage_ranks``
(artifact metadata): ranks per stage (``stage_peak_mb``: summed over them). The result
equals the serial one to solver tolerance.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import math
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from mpi4py import MPI

from lbshape.dynamics.fictitious import frame_tensors
from lbshape.dynamics.full_examples import FullSpaceExamples
from lbshape.dynamics.rigid_frame import best_rigid_frame
from lbshape.elastic.basis import (
    EQUILIBRIUM_MIN_OUTSIDE,
    NonlinearBasis,
    append_directions,
    default_linear_modes,
    nonlinear_basis,
)
from lbshape.elastic.cubature import Cubature, train_cubature, train_example_cubatures
from lbshape.elastic.cubature_poses import inverse_frequency_scales
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.elastic.modal_derivatives import ModalDerivatives, modal_derivatives
from lbshape.elastic.modes import LinearModes, linear_modes, rigid_body_modes
from lbshape.elastic.polynomial_forces import PolynomialForceModel, resolve_force_model
from lbshape.elastic.static_equilibrium import static_equilibria
from lbshape.errors import LbshapeError
from lbshape.fem.mpi import compute_on_root
from lbshape.geometry.mesh import TetMesh
from lbshape.io.cache import artifact_lock, load_artifact, save_artifact
from lbshape.pipeline.auto_stiffness import auto_stiffness_stage
from lbshape.pipeline.estimate import estimate_operators
from lbshape.pipeline.example_parts import ExampleParts
from lbshape.pipeline.impact_columns import impact_basis, leading_columns
from lbshape.pipeline.meshes import (
    build_mesh,
    example_meshes,
    selected_vertices,
)
from lbshape.pipeline.precompute_key import (
    ARTIFACT_NAME,
    CUBATURE_TRAINING_POSES,
    PRECOMPUTE_SEED,
    example_label,
    scene_cache_key,
    stage_keys,
)
from lbshape.pipeline.precomputed import (
    GlobalExamples,
    LBCubatures,
    LocalExamples,
    Precomputed,
    ShapeBasis,
    artifact,
    required_arrays,
)
from lbshape.pipeline.responses import (
    anchor_room,
    anchored_readout_responses,
    example_response_stiffness,
    example_responses,
    example_target_fields,
    response_loads,
    static_load,
    static_load_applies,
    strongly_pulled_regions,
)
from lbshape.pipeline.stages import Ranks, StageCache, StageRecorder
from lbshape.scene.schema import Scene
from lbshape.shapespace.alignment import BasisAlignment
from lbshape.shapespace.basis_choice import METHODS, warn_doubtful_transfer
from lbshape.shapespace.clamped_basis import clamped_eigenvectors
from lbshape.shapespace.example_shapes import (
    clamp_is_safe,
    energy_elements,
    example_rest_shapes,
)
from lbshape.shapespace.example_targets import tabulate_examples
from lbshape.shapespace.frames import body_frame
from lbshape.shapespace.local_build import RegionSpec, build_local_space
from lbshape.shapespace.projections import (
    block_basis,
    embed_example,
    make_shape_space,
    reduced_projection,
)
from lbshape.shapespace.target_table import TargetTable
from lbshape.spectral.spectrum import LBSpectrum, lb_spectrum

log = logging.getLogger(__name__)

#: target routes in the LB basis faded to zero at the fixed vertices (when safe). Off: the
#: full reference interpolates in the free basis (docs/decisions.md, "The clamped LB
#: basis"); the clamped basis stays available (``boundary=``).
CLAMPED_TARGETS = False
#: the static equilibria and the example responses grow the basis up to this many
#: columns (the equilibria first): at r = 48 one exact polynomial force and tangent costs
#: 0.27 ms (``dsymv``, alone on an Intel Xeon of 2.5 GHz), so a step of about two Newton
#: updates stays inside 1 ms (teddy-local 0.68, cross 0.82 ms); at r = 60 0.64 ms a call
MAX_APPENDED_BASIS = 48
#: a free body's example responses grow its basis up to this many columns: its step also
#: pays for the contact (r² per touching vertex, with friction) and the frame; the car's
#: mean step was 1.08 ms at r = 29 (all nine responses), 0.94 ms at r = 24, and its
#: body-frame deformation error against full 7.8 % and 6.9 % (20 % with none, r = 20)
MAX_APPENDED_FREE_BODY = 24
#: ... but a free body whose own r reaches that still gets up to this many: the Figure 4
#: bar (r = 30) had none, and in free flight, before its first bounce, 5.5 % of its
#: example-driven deformation lay outside U (5.6 % off the full reference); its two
#: responses above the threshold (r = 32) leave 0.3 % outside (0.4 % off)
MIN_APPENDED_FREE_BODY = 4
#: the static equilibria are solved in full space by sparse Cholesky (7 s of the 6.7k-vertex
#: bar's precompute, 30 s of the 18.6k one's; by LU 383 s); larger meshes skip the stage
STATIC_EQUILIBRIA_MAX_VERTICES = 20_000


def stage_names(scene: Scene) -> list[str]:
    """The stages this scene needs, in order."""
    names = ["mesh", "modes", "derivatives", "basis"]
    if scene.has_local_examples:
        names += ["lb", "regions"]
    elif scene.has_examples:
        names += ["lb", "examples", "target-table", "lb-cubature"]
    if static_load_applies(scene):
        names.append("static-equilibria")
    if scene.examples is not None and scene.examples.auto and (
            scene.has_examples or scene.has_local_examples):
        names.append("example-stiffness")
    if example_response_stiffness(scene) > 0:
        names.append("example-basis")
    if scene.reduced.impact_columns:
        names.append("impact-basis")
    names.append("cubature")
    if scene.material.model == "stvk" and scene.reduced.forces != "cubature":
        names.append("forces")
    if scene.has_examples or scene.has_local_examples:
        names.append("projections")
    if scene.is_free or "forces" in names:  # the estimate needs the polynomial forces
        names.append("frame" if scene.is_free else "estimate")
    return names


def precompute(scene: Scene, *, force: bool = False, progress: bool = False,
               save: bool = True, comm: MPI.Comm | None = None) -> Precomputed | None:
    """Build or reuse the scene's precompute (see the module docstring).

    Args:
        scene: the scene.
        force: recompute even if cached.
        progress: progress bars per stage on stderr (rank 0 only).
        save: write the artifact to the cache (rank 0 only); ``False`` leaves the
            cache untouched.
        comm: an MPI communicator to distribute the solver stages over (every rank of
            it calls this function); ``None``: serial.

    Returns:
        :class:`~lbshape.pipeline.precomputed.Precomputed` on rank 0 (serial: always),
        ``None`` on the other ranks.
    """
    comm = MPI.COMM_SELF if comm is None else comm
    root = comm.rank == 0
    key = scene_cache_key(scene)
    # concurrent jobs on one scene compute it once; only the rank that saves locks, the
    # others stay in step with its collective solves
    lock = artifact_lock(ARTIFACT_NAME, key) if save and root else contextlib.nullcontext()
    with lock:
        cached = None if force else compute_on_root(
            comm, lambda: load_artifact(ARTIFACT_NAME, key, required=required_arrays(scene)),
            share=False)
        if comm.bcast(cached is not None, root=0):
            return Precomputed.from_arrays(scene, key, *cached) if root else None
        stages = StageRecorder(stage_names(scene), show=progress and root)
        cache = StageCache(stage_keys(scene, stages.names, [
            CLAMPED_TARGETS, MAX_APPENDED_BASIS, MAX_APPENDED_FREE_BODY,
            MIN_APPENDED_FREE_BODY, STATIC_EQUILIBRIA_MAX_VERTICES]), read=not force, write=save)
        arrays, meta = _compute(scene, stages, comm, cache)
        peaks = comm.gather(stages.peak_mb, root=0)
        if not root:
            return None
        meta["stage_seconds"] = stages.seconds
        meta["stage_cached"] = stages.cached
        meta["stage_peak_mb"] = {name: float(sum(peak.get(name, 0.0) for peak in peaks))
                                 for name in stages.peak_mb}
        if save:
            save_artifact(ARTIFACT_NAME, key, arrays, meta)
    return Precomputed.from_arrays(scene, key, arrays, meta, from_cache=False)


# ------------------------------------------------------------------ all stages
def _compute(scene: Scene, stages: StageRecorder, comm: MPI.Comm,
             cache: StageCache | None = None) -> tuple[dict | None, dict | None]:
    """Every stage (or its ``cache`` entry); (arrays, meta) on rank 0, else (None, None)."""
    ranks = Ranks(comm, stages, cache)
    mesh, fixed = ranks.on_root("mesh", lambda: _read_mesh(scene), share=True)
    _check_sizes(scene, mesh, fixed)
    elastic = _basis_stages(scene, mesh, fixed, ranks)
    shape = local = None
    if scene.has_local_examples:
        local = _local_examples(scene, mesh, fixed, ranks)
    elif scene.has_examples:
        shape = _global_shape_space(scene, mesh, fixed, ranks)
    if "static-equilibria" in stages.names:
        elastic = elastic._replace(basis=ranks.on_root("static-equilibria", lambda: (
            _static_equilibria(scene, mesh, fixed, elastic))))
    basis, auto = elastic.basis, None
    if "example-stiffness" in stages.names:
        auto = ranks.on_root("example-stiffness", lambda: auto_stiffness_stage(
            scene, mesh, elastic.mass, elastic.basis.U, float(elastic.modes.omega2[0]),
            eigenvectors=None if shape is None else shape.targets.eigenvectors,
            coefficients=() if shape is None else shape.coefficients,
            space=None if local is None else local.space, stiffness=elastic.modes.stiffness,
            fixed_vertices=fixed))
        if ranks.root:
            log.info("%s", auto.summary())
    if "example-basis" in stages.names:
        basis = ranks.on_root("example-basis", lambda: _example_basis(
            scene, mesh, fixed, elastic, shape, local, None if auto is None else auto.k_ex))
    impact = None
    if "impact-basis" in stages.names:
        impact = ranks.on_root("impact-basis", lambda: impact_basis(
            scene, mesh, elastic.mass, elastic.modes.stiffness, basis,
            _throw_examples(scene, shape, None if auto is None else auto.k_ex)))
        basis = None if impact is None else impact.basis
    U, cubature, polynomial = _force_stages(scene, mesh, basis, ranks)
    examples = None
    if "projections" in stages.names:  # every rank takes part (the others wait)
        examples, local = ranks.on_root("projections", lambda: _projections(
            scene, mesh, U, fixed, shape, local)) or (None, None)
    frame = (ranks.on_root("frame", lambda: frame_tensors(
        mesh.points, mesh.tets, elastic.mass, U)) if scene.is_free else None)
    estimate = (ranks.on_root("estimate", lambda: estimate_operators(
        scene, mesh, scene.material, fixed, U))
        if polynomial is not None and "estimate" in stages.names else None)
    if not ranks.root:
        return None, None
    names = [] if scene.examples is None else [example_label(p) for p in scene.examples.poses]
    return artifact(scene, mesh=mesh, fixed=fixed, U=U,
                    omega2=np.asarray(elastic.modes.omega2), cubature=cubature,
                    polynomial=polynomial, examples=examples, local=local,
                    frame=frame, example_names=names, stage_ranks=ranks.count,
                    auto_stiffness=auto, estimate=estimate,
                    impact=impact)


# ------------------------------------------------------------- the elastic stages
class ElasticStages(NamedTuple):
    """What the ``modes`` to ``basis`` stages produced (the modes' vectors, the mass and
    the basis on rank 0)."""

    modes: LinearModes
    mass: sp.spmatrix | None  #: (3n, 3n) elastic mass M (kg), rank 0
    basis: NonlinearBasis | None  #: U (3n, r), ``UᵀMU = I``, rank 0


def _read_mesh(scene: Scene) -> tuple[TetMesh, np.ndarray]:
    """The ``mesh`` stage: the object's rest mesh and its fixed vertices."""
    mesh = build_mesh(scene.object)
    fixed = (np.empty(0, dtype=np.int64) if scene.fixed is None
             else selected_vertices(scene.fixed, mesh, what="fixed region"))
    return mesh, fixed


def _basis_stages(scene: Scene, mesh: TetMesh, fixed: np.ndarray,
                  ranks: Ranks) -> ElasticStages:
    """The ``modes``, ``derivatives`` and ``basis`` stages."""
    material, reduced, comm = scene.material, scene.reduced, ranks.comm
    count = reduced.linear_modes or default_linear_modes(reduced.r)
    modes = ranks.distributed("modes", lambda: linear_modes(
        mesh, material, count, fixed_vertices=fixed if fixed.size else None, comm=comm))
    mass, derivatives = ranks.distributed("derivatives", lambda: _derivatives(
        scene, mesh, fixed, modes, comm))
    basis = ranks.on_root("basis", lambda: nonlinear_basis(
        modes, derivatives, mass, reduced.r, responses=derivatives.static_responses))
    return ElasticStages(modes, mass, basis)


def _force_stages(scene: Scene, mesh: TetMesh, basis: NonlinearBasis | None, ranks: Ranks
                  ) -> tuple[np.ndarray, Cubature, PolynomialForceModel | None]:
    """The ``cubature`` and ``forces`` stages on the final basis, its impact columns left
    out (they have their own energy, ``impact-basis``): (U on every rank, the cubature,
    the polynomial force model or None)."""
    reduced, comm = scene.reduced, ranks.comm

    leading = compute_on_root(comm, lambda: leading_columns(basis))

    def cubature_stage():  # every rank: the element passes are split across the ranks
        U, omega2 = compute_on_root(comm, lambda: (basis.U, np.asarray(basis.omega2)))
        return U, train_cubature(  # the impact columns have their own energy: not trained
            mesh, scene.material, U[:, :leading], rng=np.random.default_rng(PRECOMPUTE_SEED),
            scales=inverse_frequency_scales(omega2[:leading]),
            max_elements=reduced.s, tol=reduced.cubature_tolerance,
            n_train=CUBATURE_TRAINING_POSES, n_holdout=CUBATURE_TRAINING_POSES // 2,
            comm=comm)

    U, cubature = ranks.distributed("cubature", cubature_stage)
    polynomial = None
    if "forces" in ranks.stages.names:
        polynomial = ranks.distributed("forces", lambda: _polynomial_forces(
            scene, mesh, np.ascontiguousarray(U[:, :leading]), comm))
    return U, cubature, polynomial


def _static_equilibria(scene: Scene, mesh: TetMesh, fixed: np.ndarray,
                       elastic: ElasticStages) -> NonlinearBasis:
    """The ``static-equilibria`` stage: U with the nonlinear static equilibria under the
    scene's loads (:func:`lbshape.pipeline.responses.static_load`) that it misses
    appended, within :data:`MAX_APPENDED_BASIS` columns."""
    if mesh.n_vertices > STATIC_EQUILIBRIA_MAX_VERTICES:
        log.info("static equilibria: skipped, %d vertices (more than %d)", mesh.n_vertices,
                 STATIC_EQUILIBRIA_MAX_VERTICES)
        return elastic.basis
    room = MAX_APPENDED_BASIS - elastic.basis.r
    if room <= 0:
        return elastic.basis
    load = static_load(scene, mesh, elastic.mass)
    equilibria = static_equilibria(mesh, scene.material, fixed, load)
    return append_directions(elastic.basis, equilibria, elastic.mass,
                             elastic.modes.stiffness, kind="static_equilibria",
                             max_columns=room, min_outside=EQUILIBRIUM_MIN_OUTSIDE)


def _example_basis(scene: Scene, mesh: TetMesh, fixed: np.ndarray, elastic: ElasticStages,
                   shape: _GlobalShape | None, local: LocalExamples | None,
                   auto: float | None = None) -> NonlinearBasis:
    """The ``example-basis`` stage: U with the example responses it misses appended
    (:func:`~lbshape.pipeline.responses.example_responses`; unshifted under a
    :func:`~lbshape.pipeline.responses.strongly_pulled_regions`, whose shifted ones are
    nearly its targets), then their :func:`~lbshape.pipeline.responses.anchored_readout_responses`;
    ``auto``: the k_ex of ``stiffness = "auto"``."""
    room = (max(MAX_APPENDED_FREE_BODY - elastic.basis.r, MIN_APPENDED_FREE_BODY)
            if scene.is_free else max(MAX_APPENDED_BASIS - elastic.basis.r, 0))
    anchored = () if local is None or scene.is_free else local.space.regions
    K0, k_ex = elastic.modes.stiffness, example_response_stiffness(scene, auto)
    pulled = strongly_pulled_regions(k_ex, mesh, scene.material, anchored)
    if room == 0 and not pulled:  # none
        return elastic.basis
    density, mass = scene.material.density, elastic.mass
    fields, spring = (example_target_fields(mesh, mass, density, regions=local.space.regions)
                      if local is not None else example_target_fields(
                          mesh, mass, density, targets=shape.targets.path,
                          eigenvectors=shape.targets.eigenvectors))
    rigid = rigid_body_modes(mesh.points, mass) if scene.is_free else None
    responses = example_responses(K0, spring, 0.0 if pulled else k_ex, fields, mass, fixed,
                                  rigid=rigid)
    basis = append_directions(elastic.basis, responses, mass, K0,
                              kind="example_responses", max_columns=room)
    if not pulled:
        return basis
    X = anchored_readout_responses(  # beyond the cap: the anchor fit's feedback
        K0, spring, k_ex, mesh, density, anchored, fixed, pulled=pulled)
    room = anchor_room(scene, mesh.n_tets, basis.r, X.shape[1])
    return append_directions(basis, X, mass, K0, rtol=0.0, min_outside=0.0, max_columns=room)


def _derivatives(scene: Scene, mesh: TetMesh, fixed: np.ndarray, modes: LinearModes,
                 comm: MPI.Comm) -> tuple[sp.spmatrix | None, ModalDerivatives]:
    """The ``derivatives`` stage: (the elastic mass on rank 0, the modal derivatives
    with the static responses, one factorisation of K)."""
    def loads_on_root():
        mass = mass_matrix(mesh, scene.material.density)
        return mass, response_loads(scene, mesh, mass, fixed)

    mass, loads = compute_on_root(comm, loads_on_root, share=False) or (None, None)
    return mass, modal_derivatives(mesh, scene.material, modes, static_loads=loads, comm=comm)


def _polynomial_forces(scene: Scene, mesh: TetMesh, U: np.ndarray,
                       comm: MPI.Comm) -> PolynomialForceModel | None:
    """The ``forces`` stage: the polynomial force model when ``reduced.forces`` resolves
    to ``polynomial`` for this mesh (element chunks split across the ranks), else None."""
    chosen = resolve_force_model(scene.reduced.forces, scene.material.model,
                                 mesh.n_tets, U.shape[1])
    if chosen == "polynomial":
        return PolynomialForceModel(mesh.points, mesh.tets, scene.material, U, comm=comm)
    log.info("reduced forces: the cubature (the polynomial build is too large for "
             "%d tetrahedra at r = %d)", mesh.n_tets, U.shape[1])
    return None


def _check_sizes(scene: Scene, mesh: TetMesh, fixed: np.ndarray) -> None:
    free_dofs = 3 * (mesh.n_vertices - fixed.size) - (0 if fixed.size else 6)
    r, s, m = scene.reduced.r, scene.reduced.s, scene.reduced.m
    if r > free_dofs:
        raise LbshapeError(f"reduced.r={r} is larger than the mesh's {free_dofs} free DOFs")
    if s > mesh.n_tets:
        raise LbshapeError(f"reduced.s={s} is larger than the mesh's {mesh.n_tets} tetrahedra")
    if scene.has_examples and m + 1 >= mesh.n_vertices:
        raise LbshapeError(f"reduced.m={m} is too large for a mesh with {mesh.n_vertices} vertices")


# ------------------------------------------------------------ global examples
class EmbeddedExamples(NamedTuple):
    """The ``examples`` stage: each example in the object's shape space."""

    coefficients: list[np.ndarray]  #: (m, 3) displacement coefficients per example
    alignments: list[BasisAlignment]  #: each example's basis map to the object's


class TargetStage(NamedTuple):
    """The ``target-table`` stage."""

    table: TargetTable | None  #: the exact target tabulated, or None
    path: np.ndarray  #: (P, 3m) exact targets over the weight simplex
    clamped: bool  #: the targets use the clamped basis
    eigenvectors: np.ndarray  #: (n, m) Φ of the targets (Φ or Φ_F)
    phi_clamped: np.ndarray  #: (n, m) Φ_F, faded to zero at the fixed vertices


class _GlobalShape(NamedTuple):
    """What the ``lb`` to ``lb-cubature`` stages give (rank 0; none of it depends on U)."""

    spectrum: LBSpectrum
    embedded: EmbeddedExamples
    coefficients: list[np.ndarray]  #: (m, 3) per example (a free body's: its deformation)
    targets: TargetStage
    lb_cubatures: LBCubatures


class LBCubatureInputs(NamedTuple):
    """What every rank of the ``lb-cubature`` stage receives from rank 0."""

    eigenvectors: np.ndarray  #: (n, m) Φ of the targets
    eigenvalues: np.ndarray  #: (m,) λ (the perturbations' scales)
    example_coefficients: np.ndarray  #: (k, m, 3)
    path: np.ndarray  #: (P, 3m) the exact targets to train on


def _throw_examples(scene: Scene, shape: _GlobalShape | None,
                    auto: float | None) -> FullSpaceExamples | None:
    """The global examples' pull for the impact throws (the full reference's example
    force: LB eigenpairs, the examples' coefficients, k_ex), or None (no global examples
    or k_ex = 0)."""
    k_ex = example_response_stiffness(scene, auto)
    if shape is None or not k_ex > 0 or not math.isfinite(k_ex):
        return None
    spectrum, m = shape.spectrum, scene.reduced.m
    coefficients = np.asarray(shape.coefficients, dtype=float).reshape(-1, m, 3)
    return FullSpaceExamples(spectrum.eigenvalues, spectrum.eigenvectors, coefficients, k_ex)


def _global_shape_space(scene: Scene, mesh: TetMesh, fixed: np.ndarray,
                        ranks: Ranks) -> _GlobalShape | None:
    """The ``lb`` (distributed) to ``lb-cubature`` stages of a scene with examples (on
    rank 0; ``None`` on the other ranks)."""
    m = scene.reduced.m
    spectrum = ranks.distributed("lb", lambda: lb_spectrum(mesh, m, comm=ranks.comm))
    embedded = ranks.on_root("examples", lambda: _embed_examples(scene, mesh, spectrum))
    coefficients = None
    if ranks.root:
        coefficients = embedded.coefficients
        if scene.is_free:
            coefficients = [deformation_coefficients(mesh.points, spectrum.eigenvectors,
                                                     spectrum.mass, c) for c in coefficients]
    targets = ranks.on_root("target-table", lambda: _target_table(
        scene, mesh, fixed, spectrum, np.asarray(coefficients)))
    lb_cubatures = ranks.distributed("lb-cubature", lambda: _train_lb_cubatures(
        scene, mesh, compute_on_root(ranks.comm, lambda: LBCubatureInputs(
            targets.eigenvectors, spectrum.eigenvalues, np.asarray(coefficients),
            targets.path)),
        comm=ranks.comm))
    if not ranks.root:
        return None
    return _GlobalShape(spectrum, embedded, coefficients, targets, lb_cubatures)


def _embed_examples(scene: Scene, mesh: TetMesh, spectrum: LBSpectrum) -> EmbeddedExamples:
    """The ``examples`` stage: every example's coefficients and basis alignment."""
    m = scene.reduced.m
    frame = body_frame(mesh)
    build = functools.cache(build_mesh)  # examples often pose one mesh
    coefficients, alignments = [], []
    for index, pose in enumerate(scene.examples.poses):
        label = f"example {index} ({example_label(pose)})"
        try:
            rest, posed = example_meshes(pose, mesh, build=build)
        except LbshapeError as exc:
            raise LbshapeError(f"{label}: {exc}") from None
        if rest.n_vertices <= m + 1:
            raise LbshapeError(
                f"{label}: m={m} is too large for an example mesh with "
                f"{rest.n_vertices} vertices"
            )
        landmarks = np.asarray(pose.landmarks, dtype=np.int64) if pose.landmarks else None
        try:
            embedded = embed_example(mesh, spectrum, rest, [posed.points],
                                     object_frame=frame, landmarks=landmarks)
        except LbshapeError as exc:
            raise LbshapeError(f"{label}: {exc}") from None
        coefficients.append(embedded.coefficients[0])
        alignments.append(embedded.alignment)
        log.info("%s: alignment residual %.3g, transfer difference %.3g", label,
                 embedded.alignment.residual, embedded.transfer_differences[0])
        warn_doubtful_transfer(label, embedded)
    return EmbeddedExamples(coefficients, alignments)


def deformation_coefficients(points: np.ndarray, eigenvectors: np.ndarray, volume_mass,
                             coefficients: np.ndarray) -> np.ndarray:
    """(m, 3) LB coefficients of an example's *deformation*: the displacement ``Φ c``
    (n, 3) (m) with its best rigid fit removed
    (:func:`~lbshape.dynamics.rigid_frame.best_rigid_frame`, the frame a free body's
    runtime and its measures use), ``Φᵀ M₁ u_body`` (Φ (n, m), M₁ the volume mass).

    A free body's shape space: its basis U holds no rigid motion and its state is
    compared in the body frame, so an example posed with a rotation (an arc keeping
    one end in place) must pull towards its shape, not towards that rotation.
    """
    u = eigenvectors @ np.asarray(coefficients, dtype=float).reshape(eigenvectors.shape[1], 3)
    body = best_rigid_frame(volume_mass, points, points + u)[2]
    return eigenvectors.T @ (volume_mass @ body)


def _projections(scene: Scene, mesh: TetMesh, U: np.ndarray, fixed: np.ndarray,
                 shape: _GlobalShape | None, local: LocalExamples | None
                 ) -> tuple[GlobalExamples | None, LocalExamples | None]:
    """The ``projections`` stage, on the final basis U: the maps ``T = Uᵀ M L`` of LB
    coefficients to reduced coordinates
    (:func:`~lbshape.shapespace.projections.reduced_projection`; global examples: also
    for the clamped basis), or each region's small matrices (local examples)."""
    if local is not None:
        return None, local._replace(space=local.space.projected(mesh, scene.material, U))
    density = scene.material.density
    spectrum, targets = shape.spectrum, shape.targets
    names = [example_label(p) for p in scene.examples.poses]
    space = make_shape_space(
        spectrum.eigenvalues, spectrum.eigenvectors, spectrum.mass, mesh.points, U,
        shape.coefficients, shape.embedded.alignments, names, density=density,
    )
    return GlobalExamples(
        shape=ShapeBasis(spectrum.eigenvalues, spectrum.eigenvectors, tuple(names), mesh,
                         fixed),
        density=density, example_coefficients=space.example_coefficients,
        projection=space.projection,
        projection_clamped=reduced_projection(U, targets.phi_clamped, spectrum.mass, density),
        alignment_residuals=space.alignment_residuals,
        alignment_method_codes=np.array([METHODS.index(m) for m in space.alignment_methods],
                                        dtype=np.int64),
        target_table=targets.table, target_clamped=targets.clamped,
        lb_cubatures=shape.lb_cubatures), None


def _target_table(scene: Scene, mesh: TetMesh, fixed: np.ndarray, spectrum: LBSpectrum,
                  coefficients: np.ndarray) -> TargetStage:
    """The ``target-table`` stage: the basis of the targets (free, or clamped when
    :data:`CLAMPED_TARGETS` and safe), the table and the path of exact targets
    (coefficients (k, m, 3): the examples')."""
    phi_clamped = clamped_eigenvectors(spectrum.eigenvectors, fixed, mesh.points)
    clamped = CLAMPED_TARGETS and fixed.size > 0 and clamp_is_safe(
        mesh.points, mesh.tets, spectrum.eigenvectors, phi_clamped, coefficients)
    if CLAMPED_TARGETS and fixed.size and not clamped:
        log.warning("the clamped LB basis would flatten elements of the examples' rest "
                    "shapes: the target routes keep the free basis")
    phi_target = phi_clamped if clamped else spectrum.eigenvectors
    targets = tabulate_examples(mesh.points, mesh.tets, scene.material, phi_target,
                                coefficients, mass=spectrum.mass)
    return TargetStage(targets.table, targets.path, clamped, phi_target, phi_clamped)


def _train_lb_cubatures(scene: Scene, mesh: TetMesh, inputs: LBCubatureInputs, *,
                        comm: MPI.Comm) -> LBCubatures:
    """One cubature per example for the LB basis ``Φ ⊗ I₃`` (the one of the target
    routes) over the example energies' elements
    (:func:`~lbshape.shapespace.example_shapes.energy_elements`), trained on the
    example's rest shape along the path (P, 3m) of exact
    targets between the examples (:func:`lbshape.elastic.cubature.train_example_cubatures`,
    its element passes split across the ranks of ``comm``); arrays (k, s) padded."""
    coefficients = inputs.example_coefficients
    k = coefficients.shape[0]
    rests = example_rest_shapes(mesh.points, inputs.eigenvectors, coefficients)
    kept = energy_elements(mesh.points, mesh.tets, rests)  # the example energies' elements
    rules = train_example_cubatures(
        rests, mesh.tets[kept], scene.material, block_basis(inputs.eigenvectors),
        coefficients.reshape(k, -1), inputs.path,
        rng=np.random.default_rng(PRECOMPUTE_SEED + 1),
        scales=inverse_frequency_scales(np.repeat(inputs.eigenvalues, 3)),
        max_elements=scene.reduced.s, tol=scene.reduced.cubature_tolerance, comm=comm,
    )
    width = max(rule.size for rule in rules)
    elements = np.full((k, width), -1, dtype=np.int64)
    weights = np.zeros((k, width))
    for index, rule in enumerate(rules):
        elements[index, :rule.size] = kept[rule.elements]
        weights[index, :rule.size] = rule.weights
    return LBCubatures(elements, weights,
                       np.array([max(r.train_error for r in rules),
                                 max(r.holdout_error for r in rules)]))


# ------------------------------------------------------------- local examples
def _local_examples(scene: Scene, mesh: TetMesh, fixed: np.ndarray,
                    ranks: Ranks) -> LocalExamples | None:
    """The ``lb`` (distributed) and ``regions`` (rank 0) stages of a scene with local
    examples, without the regions' maps to reduced coordinates (``projections``); None on
    the other ranks."""
    m = scene.reduced.m
    spectrum = ranks.distributed("lb", lambda: lb_spectrum(mesh, m, comm=ranks.comm))
    parts = ExampleParts(scene, mesh)
    specs = [RegionSpec(reg.name, reg.selection.group, reg.selection.region, reg.examples)
             for reg in scene.regions]
    local = ranks.on_root("regions", lambda: build_local_space(
        mesh, scene.material, None, specs, parts.example_part, m=m,
        object_pose=parts.object_pose,
        global_eigenvectors=spectrum.eigenvectors, fixed_vertices=fixed))
    if local is None:
        return None
    return LocalExamples(local, spectrum)
