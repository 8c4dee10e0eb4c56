"""The precompute pipeline of a scene, with a validated cache.

Stages (only those the scene needs; paper pre-computation steps 1–6):

1. ``mesh``: the object's rest mesh and its fixed vertices;
2. ``modes``: linear elastic modes (fixed vertices from the scene);
3. ``derivatives``: modal derivatives (Barbič & James), and with the same
   factorisation of K the static responses to the scene's loads and example pulls
   (:mod:`lbshape.pipeline.responses`);
4. ``basis``: mass-PCA nonlinear basis U (3n, r), ``UᵀMU = I``: the linear modes, the
   static responses, then the modal derivatives' principal components;
5. ``cubature``: optimized cubature for the reduced elastic force (the force model of
   non-StVK materials and large meshes, and the energy of the ``modal`` route);
5b. ``forces``: the exact reduced StVK force as polynomials in q (K, C̃, D̃ of
   :class:`~lbshape.elastic.polynomial_forces.PolynomialForceModel`)   — StVK scenes
   whose ``reduced.forces`` resolves to ``polynomial``;
6. ``lb``: the object's LB spectrum (m pairs)                — scenes with examples;
7. ``examples``: example meshes, poses, frame and basis alignment, displacement
   coefficients                                              — scenes with examples;
8. ``projections``: direct projections T (also for the clamped LB basis, faded to
   zero at the fixed vertices)                       — scenes with examples;
9. ``target-table``: the exact interpolation target tabulated over the weight
   simplex (1–3 examples), checked against the exact target at held-out weights
   (:mod:`lbshape.shapespace.target_table`)                     — scenes with examples;
10. ``lb-cubature``: one cubature per example for the LB displacement subspace (the
   ``lb`` interpolation route), trained on the example's rest shape along the path of
   exact targets between the examples                         — scenes with examples;
11. ``frame``: the rigid frame's reduced inertia and fictitious-force tensors
    (:mod:`lbshape.dynamics.fictitious`)                      — free bodies.

Scenes with ``[[regions]]`` (local examples) replace stages 7–9 by
``regions``: per-region spectra, example parts embedded per region and the small
region matrices (:mod:`lbshape.shapespace.local_examples`); stage 6 still
computes the whole object's spectrum (eigenfunction pictures, and the measured
comparison of the two local-example variants).

Everything is cached under a key derived from :meth:`Scene.precompute_key_fields`,
the gmsh scripts or mesh files behind the meshes, the package versions, and what
the basis's static responses depend on (:func:`lbshape.pipeline.responses.response_key`:
each load's type, region and direction, and whether k_ex > 0), so changing dt, steps,
a load's size or profile, damping or the value of k_ex never redoes the precompute,
while changing any mesh byte, material value, m, r, s, example, or where and along
what a load acts does.

**MPI.** ``precompute(scene, comm=MPI.COMM_WORLD)`` on every rank distributes the
n-sized stages over the ranks: ``modes`` and ``lb`` (DOLFINx assembly, SLEPc with
MUMPS), ``derivatives`` (parallel assembly, one MUMPS factorisation), and the element
passes of ``cubature`` and ``lb-cubature`` (split with
:func:`lbshape.fem.mpi.rank_share`; their inputs broadcast from rank 0). The other
stages run on rank 0 only (:func:`lbshape.fem.mpi.compute_on_root`: the other ranks
sleep, and a user error on rank 0 is raised on every rank). Rank 0 alone reads and
writes the cache and gets the :class:`Precomputed`; the others get ``None``.
``stage_ranks`` in the artifact's metadata says over how many ranks each stage ran
(``stage_peak_mb`` is summed over the ranks). The result equals the serial one to
solver tolerance.

**Basis scaling.** U is orthonormal in the elastic mass ``M = ρ M₃``; the shape
space (:mod:`lbshape.shapespace.projections`) works with the volume mass M₃. Its projection
is computed for ``√ρ U`` (M₃-orthonormal), so with ``P`` that projection:
reduced coordinates of an LB displacement are ``q = √ρ P c`` and the LB
coefficients of ``U q`` are ``c = Pᵀ q / √ρ``.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import math
import os
import sys
import threading
import time
from dataclasses import dataclass, field

import numpy as np
from mpi4py import MPI

from lbshape import __version__
from lbshape.dynamics.fictitious import FrameTensors, frame_tensors
from lbshape.elastic.basis import default_linear_modes, nonlinear_basis
from lbshape.elastic.cubature import (
    inverse_frequency_scales,
    train_cubature,
    train_example_cubatures,
)
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.elastic.materials import Material
from lbshape.elastic.modal_derivatives import modal_derivatives
from lbshape.elastic.modes import linear_modes
from lbshape.elastic.polynomial_forces import PolynomialForceModel, resolve_force_model
from lbshape.errors import LbshapeError
from lbshape.fem.mpi import compute_on_root
from lbshape.geometry.mesh import TetMesh
from lbshape.geometry.shapes import MESHES_DIR, get_shape
from lbshape.io.cache import (
    artifact_lock,
    cache_key,
    file_digest,
    load_artifact,
    save_artifact,
)
from lbshape.pipeline.meshes import (
    build_mesh,
    example_meshes,
    posed_part,
    selected_vertices,
)
from lbshape.pipeline.responses import response_key, response_loads
from lbshape.scene.schema import MeshSource, Scene
from lbshape.shapespace.example_shapes import (
    clamp_is_safe,
    energy_elements,
    example_rest_shapes,
)
from lbshape.shapespace.frames import body_frame
from lbshape.shapespace.local_examples import (
    LocalShapeSpace,
    RegionSpec,
    build_local_space,
    region_cells,
    submesh,
)
from lbshape.shapespace.projections import direct_projection, embed_example, make_shape_space
from lbshape.shapespace.target_table import (
    TargetTable,
    block_basis,
    clamped_eigenvectors,
    tabulate_examples,
)
from lbshape.spectral.spectrum import lb_spectrum

log = logging.getLogger(__name__)

#: training poses for the elastic cubature (held-out poses: half as many)
CUBATURE_TRAINING_POSES = 120
#: seed of every random choice of the precompute (training poses, candidates)
PRECOMPUTE_SEED = 20170401
#: bumped whenever the artifact's content or meaning changes (part of the cache key)
PIPELINE_VERSION = 14
#: target routes in the LB basis faded to zero at the fixed vertices (when safe). Off: the
#: full-space reference interpolates in the free basis, and the clamped targets moved the
#: coarse demo bar 28.7 % away from it (3.3 % free) while gaining 3.8 % -> 3.1 % on the bars;
#: the clamped basis stays available to the routes and benchmarks (``boundary=``).
CLAMPED_TARGETS = False
#: FrameTensors fields stored as ``frame_<field>`` arrays (free bodies)
_FRAME_FIELDS = ("mass", "center", "Y0", "G", "C", "H", "S", "translation")
#: arrays every artifact holds, and those of scenes with examples
_REQUIRED = ("points", "tets", "fixed", "U", "omega2", "cub_elements", "cub_weights")
_REQUIRED_FRAME = tuple(f"frame_{name}" for name in _FRAME_FIELDS)
_REQUIRED_EXAMPLES = ("eigenvalues", "eigenvectors", "example_coefficients", "projection",
                      "alignment_residuals", "lb_cub_elements", "lb_cub_weights",
                      "lb_cub_errors")


@dataclass(frozen=True)
class Precomputed:
    """Everything the runtime of a scene needs (n-sized arrays only for output).

    Attributes:
        scene: scene name.
        key: cache key.
        mesh: object rest mesh.
        material: the scene's material.
        fixed_vertices: (f,) fixed vertex indices (empty for a free object).
        U: (3n, r) nonlinear basis, ``Uᵀ M U = I`` (M the elastic mass).
        omega2: (k,) squared angular frequencies of the linear modes used (rad²/s²).
        cubature_elements: (s,) element indices; ``cubature_weights`` (s,).
        cubature_errors: training and held-out relative force errors.
        force_model: the reduced elastic force of the engines: ``"polynomial"`` (exact,
            :attr:`force_coefficients`) or ``"cubature"``.
        force_coefficients: (K (r, r), C̃ (P, r), D̃ (P, P)) of the polynomial force
            model, or None.
        eigenvalues: (m,) object's LB eigenvalues (1/m²) or None without examples.
        eigenvectors: (n, m) object's LB eigenvectors (M₃-orthonormal) or None.
        example_coefficients: (k, m, 3) example LB displacement coefficients or None.
        projection: (r, 3m) ``P = (√ρ U)ᵀ M₃ L`` or None.
        projection_clamped: (r, 3m) the same for the clamped basis ``L_F`` (faded to
            zero at the fixed vertices), or None.
        target_table: the :class:`~lbshape.shapespace.target_table.TargetTable` of the
            exact target in the :attr:`target_boundary` LB basis, or None (no examples,
            more than 3, or refused by its check).
        target_boundary: ``"clamped"`` when the target routes use the LB basis faded to
            zero at the fixed vertices (only with :data:`CLAMPED_TARGETS` and when it
            keeps the examples' elements healthy,
            :func:`~lbshape.shapespace.example_shapes.clamp_is_safe`), else ``"free"``;
            the table and the per-example LB cubature use it.
        alignment_residuals: (k,) basis alignment residuals or None.
        lb_cubature_elements, lb_cubature_weights: cubature of the LB displacement
            subspace (basis :meth:`lb_basis`), or None: (s,) shared by the examples or
            (k, s) one row per example (padded with element -1, weight 0);
            ``lb_cubature_errors`` (largest over the examples).
        example_names: (k,) labels.
        local: the local-example shape space (scenes with regions), or None.
        frame: reduced rigid-frame tensors of a free body, or None (fixed object).
        stage_seconds: wall time per stage (s) of the run that built the artifact.
        stage_peak_mb: largest resident memory (MB) of the process during each stage of
            that run; under MPI the sum of every rank's peak (the job's memory).
        stage_ranks: the number of MPI ranks each stage of that run was distributed
            over (1: rank 0 alone, or a serial run).
        from_cache: True when loaded from the cache.
    """

    scene: str
    key: str
    mesh: TetMesh
    material: Material
    fixed_vertices: np.ndarray
    U: np.ndarray
    omega2: np.ndarray
    cubature_elements: np.ndarray
    cubature_weights: np.ndarray
    cubature_errors: dict
    eigenvalues: np.ndarray | None = None
    eigenvectors: np.ndarray | None = None
    example_coefficients: np.ndarray | None = None
    projection: np.ndarray | None = None
    alignment_residuals: np.ndarray | None = None
    lb_cubature_elements: np.ndarray | None = None
    lb_cubature_weights: np.ndarray | None = None
    lb_cubature_errors: dict = field(default_factory=dict)
    projection_clamped: np.ndarray | None = None
    target_table: object | None = None
    target_boundary: str = "free"
    example_names: tuple[str, ...] = ()
    local: LocalShapeSpace | None = None
    frame: FrameTensors | None = None
    stage_seconds: dict = field(default_factory=dict)
    stage_peak_mb: dict = field(default_factory=dict)
    stage_ranks: dict = field(default_factory=dict)
    from_cache: bool = False
    force_model: str = "cubature"
    force_coefficients: tuple | None = None

    @property
    def r(self) -> int:
        return int(self.U.shape[1])

    @property
    def has_examples(self) -> bool:
        """Global examples (the whole object's shape space)."""
        return self.example_coefficients is not None

    @property
    def has_local_examples(self) -> bool:
        """Local examples by region (:attr:`local`)."""
        return self.local is not None

    # --- shape-space maps in the elastic reduced coordinates (see module docstring)
    @property
    def lb_to_reduced(self) -> np.ndarray:
        """(r, 3m) maps LB displacement coefficients c to reduced coordinates q."""
        return math.sqrt(self.material.density) * self.projection

    @property
    def descriptor_matrix(self) -> np.ndarray:
        """(3m, r) ``D``: λ-weighted LB coefficients of ``U q`` are ``D q``."""
        weights = np.repeat(self.eigenvalues, 3)
        return weights[:, None] * self.projection.T / math.sqrt(self.material.density)

    @property
    def example_descriptors(self) -> np.ndarray:
        """(k, 3m) λ-weighted example displacement coefficients."""
        k = self.example_coefficients.shape[0]
        return self.example_coefficients.reshape(k, -1) * np.repeat(self.eigenvalues, 3)

    def example_rest_points(self, index: int, *, clamped: bool = False) -> np.ndarray:
        """(n, 3) example ``index`` reconstructed on the object's mesh (its rest shape);
        ``clamped``: with the clamped basis (no displacement at the fixed vertices)."""
        return self.mesh.points + self.target_eigenvectors(clamped) @ \
            self.example_coefficients[index]

    def example_energy_elements(self, *, clamped: bool = False) -> np.ndarray:
        """(e,) int64 the elements the example energies sum over
        (:func:`~lbshape.shapespace.example_shapes.energy_elements` of the rest shapes
        of :meth:`example_rest_points`)."""
        k = self.example_coefficients.shape[0]
        return energy_elements(self.mesh.points, self.mesh.tets, [
            self.example_rest_points(i, clamped=clamped) for i in range(k)])

    def target_eigenvectors(self, clamped: bool = False) -> np.ndarray:
        """(n, m) Φ, or Φ_F faded to zero at the fixed vertices when ``clamped``."""
        if not clamped or self.fixed_vertices.size == 0:
            return self.eigenvectors
        return clamped_eigenvectors(self.eigenvectors, self.fixed_vertices, self.mesh.points)

    def lb_basis(self, *, clamped: bool = False) -> np.ndarray:
        """(3n, 3m) dense ``L = Φ ⊗ I₃`` (node-major rows, column 3i+k); ``clamped``: L_F."""
        return block_basis(self.target_eigenvectors(clamped))

    def lb_to_reduced_for(self, *, clamped: bool) -> np.ndarray:
        """(r, 3m) the map of LB coefficients to reduced coordinates for L or L_F."""
        if clamped and self.projection_clamped is not None:
            return math.sqrt(self.material.density) * self.projection_clamped
        return self.lb_to_reduced


def _source_digest(source: MeshSource) -> dict:
    """The mesh source's key plus the digest of the gmsh script behind a shape."""
    key = dict(source.key())
    if source.shape is not None:
        spec = get_shape(source.shape)
        key["script_sha256"] = file_digest(MESHES_DIR / spec.script)
        key["size_used"] = source.size if source.size is not None else spec.default_size
    return key


def scene_cache_key(scene: Scene) -> str:
    """The cache key of a scene's precompute (see the module docstring)."""
    import dolfinx

    sources = [_source_digest(scene.object)]
    if scene.examples is not None:
        sources += [_source_digest(p.source) for p in scene.examples.poses]
    return cache_key(
        "precompute", scene.precompute_key_fields(), response_key(scene), sources,
        {"lbshape": __version__, "dolfinx": dolfinx.__version__, "numpy": np.__version__},
        CUBATURE_TRAINING_POSES, PRECOMPUTE_SEED, PIPELINE_VERSION,
    )


class _Stages:
    """A progress bar per stage (stderr), the time spent in each and its peak memory.

    Peak memory: the largest resident set size (MB) of the process while the stage
    ran, sampled every :data:`RSS_INTERVAL` seconds by a thread (and at the stage's
    start and end), so a stage that frees what it used shows its own peak, not the
    process's largest so far.
    """

    def __init__(self, names: list[str], *, show: bool):
        self.names = names
        self.show = show
        self.seconds: dict[str, float] = {}
        self.peak_mb: dict[str, float] = {}

    @contextlib.contextmanager
    def stage(self, name: str):
        from tqdm import tqdm

        index = self.names.index(name) + 1
        bar = tqdm(total=1, desc=f"[{index}/{len(self.names)}] {name:<12}", disable=not self.show,
                   file=sys.stderr, leave=True, bar_format="{desc} {bar:20} {elapsed}")
        sampler = _PeakMemory()
        started = time.perf_counter()
        try:
            with sampler:
                yield
        finally:
            self.seconds[name] = time.perf_counter() - started
            self.peak_mb[name] = sampler.peak_mb
            bar.update(1)
            bar.close()


#: seconds between two samples of the resident set size
RSS_INTERVAL = 0.02


class _PeakMemory:
    """Context manager: the largest resident set size (MB) seen while it is open."""

    def __init__(self):
        self.peak_mb = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)

    def __enter__(self):
        self._record()
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self._record()
        return False

    def _sample(self) -> None:
        while not self._stop.wait(RSS_INTERVAL):
            self._record()

    def _record(self) -> None:
        self.peak_mb = max(self.peak_mb, resident_mb())


def resident_mb() -> float:
    """The process's resident set size in MB (the peak so far where the current
    size cannot be read)."""
    try:
        with open("/proc/self/statm", encoding="ascii") as statm:
            pages = int(statm.read().split()[1])
        return pages * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):  # not Linux: ru_maxrss (KB on Linux/BSD)
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def stage_names(scene: Scene) -> list[str]:
    """The stages this scene needs, in order."""
    names = ["mesh", "modes", "derivatives", "basis", "cubature"]
    if scene.material.model == "stvk" and scene.reduced.forces != "cubature":
        names.append("forces")
    if scene.has_local_examples:
        names += ["lb", "regions"]
    elif scene.has_examples:
        names += ["lb", "examples", "projections", "target-table", "lb-cubature"]
    if scene.is_free:
        names.append("frame")
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
        :class:`Precomputed` on rank 0 (serial: always), ``None`` on the other ranks.
    """
    comm = MPI.COMM_SELF if comm is None else comm
    root = comm.rank == 0
    key = scene_cache_key(scene)
    # concurrent jobs on one scene compute it once; only the rank that saves locks, the
    # others stay in step with its collective solves
    lock = artifact_lock(scene.name, key) if save and root else contextlib.nullcontext()
    with lock:
        cached = None if force else compute_on_root(
            comm, lambda: load_artifact(scene.name, key, required=_required_arrays(scene)),
            share=False)
        if comm.bcast(cached is not None, root=0):
            return _from_arrays(scene, key, *cached) if root else None
        stages = _Stages(stage_names(scene), show=progress and root)
        arrays, meta = _compute(scene, stages, comm)
        peaks = comm.gather(stages.peak_mb, root=0)
        if not root:
            return None
        meta["stage_seconds"] = stages.seconds
        meta["stage_peak_mb"] = {name: float(sum(peak.get(name, 0.0) for peak in peaks))
                                 for name in stages.peak_mb}
        if save:
            save_artifact(scene.name, key, arrays, meta)
    return _from_arrays(scene, key, arrays, meta, from_cache=False)


def _required_arrays(scene: Scene) -> tuple[str, ...]:
    """The arrays a cached artifact of ``scene`` must hold."""
    required = _REQUIRED + (_REQUIRED_EXAMPLES if scene.has_examples else ())
    if scene.has_local_examples:
        required = _REQUIRED + ("eigenvalues", "eigenvectors") \
            + LocalShapeSpace.required_arrays(len(scene.regions))
    if scene.is_free:
        required = required + _REQUIRED_FRAME
    return required


class _Ranks:
    """Which stages ran over all ranks of ``comm`` and which on rank 0 alone."""

    def __init__(self, comm: MPI.Comm, stages: _Stages):
        self.comm, self.stages = comm, stages
        self.count: dict[str, int] = {}

    def distributed(self, name: str, compute):
        """``compute()`` on every rank (a collective solver stage)."""
        with self.stages.stage(name):
            value = compute()
        self.count[name] = self.comm.size
        return value

    def on_root(self, name: str, compute, *, share: bool = False):
        """``compute()`` on rank 0 only; ``None`` on the other ranks unless ``share``."""
        with self.stages.stage(name):
            value = compute_on_root(self.comm, compute, share=share)
        self.count[name] = 1
        return value


def _compute(scene: Scene, stages: _Stages, comm: MPI.Comm) -> tuple[dict | None, dict | None]:
    """Every stage; (arrays, meta) on rank 0, (None, None) on the other ranks."""
    material, reduced = scene.material, scene.reduced
    ranks = _Ranks(comm, stages)

    def read_mesh():
        mesh = build_mesh(scene.object)
        fixed = (np.empty(0, dtype=np.int64) if scene.fixed is None
                 else selected_vertices(scene.fixed, mesh, what="fixed region"))
        _check_sizes(scene, mesh, fixed)
        return mesh, fixed

    mesh, fixed = ranks.on_root("mesh", read_mesh, share=True)
    count = reduced.linear_modes or default_linear_modes(reduced.r)
    modes = ranks.distributed("modes", lambda: linear_modes(
        mesh, material, count, fixed_vertices=fixed if fixed.size else None, comm=comm))
    def derivatives_stage():  # with the static responses, one factorisation of K
        def loads_on_root():
            mass = mass_matrix(mesh, material.density)
            return mass, response_loads(scene, mesh, mass, fixed)

        mass, loads = compute_on_root(comm, loads_on_root, share=False) or (None, None)
        return mass, modal_derivatives(mesh, material, modes, static_loads=loads, comm=comm)

    mass, derivatives = ranks.distributed("derivatives", derivatives_stage)
    basis = ranks.on_root("basis", lambda: nonlinear_basis(
        modes, derivatives, mass, reduced.r, responses=derivatives.static_responses))

    def cubature_stage():  # every rank: the element passes are split across the ranks
        U, omega2 = compute_on_root(comm, lambda: (basis.U, np.asarray(basis.omega2)))
        return U, train_cubature(
            mesh, material, U, rng=np.random.default_rng(PRECOMPUTE_SEED),
            scales=inverse_frequency_scales(omega2),
            max_elements=reduced.s, tol=reduced.cubature_tolerance,
            n_train=CUBATURE_TRAINING_POSES, n_holdout=CUBATURE_TRAINING_POSES // 2,
            comm=comm)

    U, cubature = ranks.distributed("cubature", cubature_stage)
    polynomial = None
    if "forces" in stages.names:
        polynomial = ranks.distributed("forces", lambda: _polynomial_forces(
            scene, mesh, U, comm))
    if scene.has_local_examples:
        local, eigen = _local_space(scene, mesh, U, fixed, ranks)
    elif scene.has_examples:
        shape_space = _shape_space_arrays(scene, mesh, U, fixed, ranks)
    frame = (ranks.on_root("frame", lambda: frame_tensors(mesh.points, mesh.tets, mass, U))
             if scene.is_free else None)
    if comm.rank != 0:
        return None, None
    arrays = {
        **_group_arrays(mesh),
        "points": mesh.points, "tets": mesh.tets, "fixed": fixed, "U": U,
        "omega2": np.asarray(modes.omega2), "cub_elements": cubature.elements,
        "cub_weights": cubature.weights,
        **({} if polynomial is None else {
            "poly_K": polynomial.K, "poly_cubic": polynomial.pair_cubic,
            "poly_quartic": polynomial.pair_quartic}),
    }
    meta = {"scene": scene.name, "cubature_errors": {
        "train": cubature.train_error, "holdout": cubature.holdout_error,
        "tolerance": cubature.tol, "reached_tolerance": bool(cubature.reached_tol)},
        "stage_ranks": ranks.count}
    if scene.has_local_examples:
        arrays.update(local.arrays())
        arrays.update(eigen)
        meta["example_names"] = [_example_label(p) for p in scene.examples.poses]
        meta["local_regions"] = [reg.name for reg in scene.regions]
        meta["local_representation_errors"] = local.representation_errors
    elif scene.has_examples:
        arrays.update(shape_space)
        meta["example_names"] = [_example_label(p) for p in scene.examples.poses]
    if frame is not None:
        arrays.update({f"frame_{name}": np.asarray(getattr(frame, name))
                       for name in _FRAME_FIELDS})
    return arrays, meta


def _polynomial_forces(scene: Scene, mesh: TetMesh, U: np.ndarray,
                       comm: MPI.Comm) -> PolynomialForceModel | None:
    """The ``forces`` stage: the polynomial force model when ``reduced.forces`` resolves
    to ``polynomial`` for this mesh (element chunks split across the ranks), else None."""
    chosen = resolve_force_model(scene.reduced.forces, scene.material.model,
                                 mesh.n_tets, U.shape[1])
    if chosen != "polynomial":
        log.info("reduced forces: the cubature (the polynomial build is too large for "
                 "%d tetrahedra at r = %d)", mesh.n_tets, U.shape[1])
        return None
    return PolynomialForceModel(mesh.points, mesh.tets, scene.material, U, comm=comm)


def _local_space(scene: Scene, mesh: TetMesh, U: np.ndarray | None, fixed: np.ndarray,
                 ranks: _Ranks):
    """The ``lb`` (distributed) and ``regions`` (rank 0) stages of a scene with local
    examples; (None, None) on the other ranks."""

    m = scene.reduced.m
    spectrum = ranks.distributed("lb", lambda: lb_spectrum(mesh, m, comm=ranks.comm))
    poses = scene.examples.poses
    meshes: dict[int, tuple[TetMesh, TetMesh]] = {}  # example -> (rest, posed)
    build = functools.cache(build_mesh)  # examples often pose one mesh

    def example(k: int) -> tuple[TetMesh, TetMesh]:
        if k not in meshes:
            try:
                meshes[k] = example_meshes(poses[k], mesh, build=build)
            except LbshapeError as exc:
                raise LbshapeError(f"example {k} ({_example_label(poses[k])}): {exc}") from None
        return meshes[k]

    def example_part(k: int, spec: RegionSpec):
        """The region's part of example k's rest mesh and its posed positions."""
        rest, posed = example(k)
        what = f"region '{spec.name}' on example {k} ({_example_label(poses[k])})"
        cells = region_cells(rest, group=spec.group, region=spec.region, what=what)
        part, vertices = submesh(rest, cells, what=what)
        return part, posed_part(poses[k], part, vertices, posed)

    def object_pose(k: int, part: TetMesh, vertices: np.ndarray) -> np.ndarray:
        """Example k's pose on the object's own region (representation measurement)."""
        if poses[k].is_posed_file and poses[k].rest is not None:
            raise LbshapeError("a posed file with its own rest mesh has no pose on the "
                               "object's mesh")
        return posed_part(poses[k], part, vertices, example(k)[1])

    specs = [RegionSpec(reg.name, reg.selection.group, reg.selection.region, reg.examples)
             for reg in scene.regions]
    local = ranks.on_root("regions", lambda: build_local_space(
        mesh, scene.material, U, specs, example_part, m=m,
        object_pose=object_pose,
        global_eigenvectors=spectrum.eigenvectors, fixed_vertices=fixed))
    if local is None:
        return None, None
    return local, {"eigenvalues": spectrum.eigenvalues, "eigenvectors": spectrum.eigenvectors}


def _shape_space_arrays(scene: Scene, mesh: TetMesh, U: np.ndarray | None, fixed: np.ndarray,
                        ranks: _Ranks) -> dict | None:
    """The ``lb`` (distributed) to ``lb-cubature`` stages of a scene with examples; the
    arrays on rank 0, ``None`` on the other ranks."""
    m = scene.reduced.m
    spectrum = ranks.distributed("lb", lambda: lb_spectrum(mesh, m, comm=ranks.comm))
    embedded = ranks.on_root("examples", lambda: _embed_examples(scene, mesh, spectrum))
    projections = ranks.on_root("projections", lambda: _projections(
        scene, mesh, U, fixed, spectrum, *embedded))
    table = ranks.on_root("target-table", lambda: _target_table(
        scene, mesh, fixed, spectrum, *projections))
    lb_arrays = ranks.distributed("lb-cubature", lambda: _train_lb_cubatures(
        scene, mesh, *compute_on_root(ranks.comm, lambda: (
            table[3], spectrum.eigenvalues, projections[0].example_coefficients, table[1])),
        comm=ranks.comm))
    if ranks.comm.rank != 0:
        return None
    space, _, projection_clamped = projections
    target, _, clamped, _ = table
    return {
        **lb_arrays, **({} if target is None else target.to_arrays()),
        "projection_clamped": projection_clamped,
        "target_clamped": np.array([int(clamped)], dtype=np.int64),
        "eigenvalues": space.eigenvalues, "eigenvectors": spectrum.eigenvectors,
        "example_coefficients": space.example_coefficients, "projection": space.projection,
        "alignment_residuals": space.alignment_residuals,
    }


def _embed_examples(scene: Scene, mesh: TetMesh, spectrum) -> tuple[list, list]:
    """The ``examples`` stage: (coefficients (m, 3) per example, alignments)."""
    m = scene.reduced.m
    frame = body_frame(mesh)
    build = functools.cache(build_mesh)  # examples often pose one mesh
    coefficients, alignments = [], []
    for index, pose in enumerate(scene.examples.poses):
        label = f"example {index} ({_example_label(pose)})"
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
        log.info("%s: alignment residual %.3g", label, embedded.alignment.residual)
    return coefficients, alignments


def _projections(scene: Scene, mesh: TetMesh, U: np.ndarray, fixed: np.ndarray, spectrum,
                 coefficients: list, alignments: list):
    """The ``projections`` stage: (shape space, clamped Φ_F (n, m), clamped projection)."""
    space = make_shape_space(
        spectrum.eigenvalues, spectrum.eigenvectors, spectrum.mass, mesh.points,
        math.sqrt(scene.material.density) * U, coefficients, alignments,
        [_example_label(p) for p in scene.examples.poses],
    )
    phi_clamped = clamped_eigenvectors(spectrum.eigenvectors, fixed, mesh.points)
    projection_clamped = direct_projection(math.sqrt(scene.material.density) * U,
                                           phi_clamped, spectrum.mass)
    return space, phi_clamped, projection_clamped


def _target_table(scene: Scene, mesh: TetMesh, fixed: np.ndarray, spectrum, space,
                  phi_clamped: np.ndarray, _projection_clamped):
    """The ``target-table`` stage: (table or None, path (P, 3m), clamped?, Φ of the
    targets (n, m))."""
    clamped = CLAMPED_TARGETS and fixed.size > 0 and clamp_is_safe(
        mesh.points, mesh.tets, spectrum.eigenvectors, phi_clamped, space.example_coefficients)
    if CLAMPED_TARGETS and fixed.size and not clamped:
        log.warning("the clamped LB basis would flatten elements of the examples' rest "
                    "shapes: the target routes keep the free basis")
    phi_target = phi_clamped if clamped else spectrum.eigenvectors
    table, path, _ = tabulate_examples(mesh.points, mesh.tets, scene.material, phi_target,
                                       space.example_coefficients, mass=spectrum.mass)
    return table, path, clamped, phi_target


def _train_lb_cubatures(scene: Scene, mesh: TetMesh, eigenvectors, eigenvalues,
                        example_coefficients, path, *, comm: MPI.Comm) -> dict:
    """One cubature per example for the LB basis ``Φ ⊗ I₃`` (the one of the target
    routes) over the example energies' elements
    (:func:`~lbshape.shapespace.example_shapes.energy_elements`), trained on the
    example's rest shape along the path (P, 3m) of exact
    targets between the examples (:func:`lbshape.elastic.cubature.train_example_cubatures`,
    its element passes split across the ranks of ``comm``); arrays (k, s) padded."""
    k = example_coefficients.shape[0]
    rests = example_rest_shapes(mesh.points, eigenvectors, example_coefficients)
    kept = energy_elements(mesh.points, mesh.tets, rests)  # the example energies' elements
    rules = train_example_cubatures(
        rests, mesh.tets[kept], scene.material, block_basis(eigenvectors),
        example_coefficients.reshape(k, -1), path,
        rng=np.random.default_rng(PRECOMPUTE_SEED + 1),
        scales=inverse_frequency_scales(np.repeat(eigenvalues, 3)),
        max_elements=scene.reduced.s, tol=scene.reduced.cubature_tolerance, comm=comm,
    )
    width = max(rule.size for rule in rules)
    elements = np.full((k, width), -1, dtype=np.int64)
    weights = np.zeros((k, width))
    for index, rule in enumerate(rules):
        elements[index, :rule.size] = kept[rule.elements]
        weights[index, :rule.size] = rule.weights
    return {"lb_cub_elements": elements, "lb_cub_weights": weights,
            "lb_cub_errors": np.array([max(r.train_error for r in rules),
                                       max(r.holdout_error for r in rules)])}


def _example_label(pose) -> str:
    source = pose.source.label
    return f"{source}:{pose.pose}" if pose.pose else str(source)


def _group_arrays(mesh: TetMesh) -> dict[str, np.ndarray]:
    """The mesh's physical groups as artifact arrays (loads may name them at run time)."""
    out = {f"cgroup__{name}": np.asarray(v, dtype=np.int64) for name, v in mesh.cell_groups.items()}
    out.update({f"vgroup__{name}": np.asarray(v, dtype=np.int64)
                for name, v in mesh.vertex_groups.items()})
    return out


def _groups_from_arrays(arrays: dict) -> tuple[dict, dict]:
    """Inverse of :func:`_group_arrays`: (cell groups, vertex groups)."""
    cells = {k[len("cgroup__"):]: np.asarray(v, dtype=np.int64) for k, v in arrays.items()
             if k.startswith("cgroup__")}
    vertices = {k[len("vgroup__"):]: np.asarray(v, dtype=np.int64) for k, v in arrays.items()
                if k.startswith("vgroup__")}
    return cells, vertices


def _check_sizes(scene: Scene, mesh: TetMesh, fixed: np.ndarray) -> None:
    free_dofs = 3 * (mesh.n_vertices - fixed.size) - (0 if fixed.size else 6)
    r, s, m = scene.reduced.r, scene.reduced.s, scene.reduced.m
    if r > free_dofs:
        raise LbshapeError(f"reduced.r={r} is larger than the mesh's {free_dofs} free DOFs")
    if s > mesh.n_tets:
        raise LbshapeError(f"reduced.s={s} is larger than the mesh's {mesh.n_tets} tetrahedra")
    if scene.has_examples and m + 1 >= mesh.n_vertices:
        raise LbshapeError(f"reduced.m={m} is too large for a mesh with {mesh.n_vertices} vertices")


def _from_arrays(scene: Scene, key: str, arrays: dict, meta: dict, *,
                 from_cache: bool = True) -> Precomputed:
    mesh = TetMesh(np.asarray(arrays["points"]), np.asarray(arrays["tets"]),
                   *_groups_from_arrays(arrays))
    has_examples = "example_coefficients" in arrays
    return Precomputed(
        scene=scene.name, key=key, mesh=mesh, material=scene.material,
        fixed_vertices=np.asarray(arrays["fixed"], dtype=np.int64),
        U=np.asarray(arrays["U"]), omega2=np.asarray(arrays["omega2"]),
        cubature_elements=np.asarray(arrays["cub_elements"], dtype=np.int64),
        cubature_weights=np.asarray(arrays["cub_weights"]),
        cubature_errors=meta.get("cubature_errors", {}),
        eigenvalues=arrays.get("eigenvalues"),
        eigenvectors=arrays.get("eigenvectors"),
        example_coefficients=arrays.get("example_coefficients") if has_examples else None,
        projection=arrays.get("projection") if has_examples else None,
        alignment_residuals=arrays.get("alignment_residuals") if has_examples else None,
        lb_cubature_elements=(np.asarray(arrays["lb_cub_elements"], dtype=np.int64)
                              if has_examples else None),
        lb_cubature_weights=arrays.get("lb_cub_weights") if has_examples else None,
        lb_cubature_errors=({"train": float(arrays["lb_cub_errors"][0]),
                             "holdout": float(arrays["lb_cub_errors"][1])}
                            if has_examples else {}),
        projection_clamped=arrays.get("projection_clamped") if has_examples else None,
        target_table=_table(arrays) if has_examples else None,
        target_boundary=("clamped" if has_examples and int(np.asarray(
            arrays.get("target_clamped", [0]))[0]) else "free"),
        example_names=tuple(meta.get("example_names", ())),
        local=(LocalShapeSpace.from_arrays(meta["local_regions"], arrays,
                                           meta.get("local_representation_errors", {}))
               if "local_regions" in meta else None),
        frame=(FrameTensors(**{name: (float(arrays[f"frame_{name}"]) if name == "mass"
                                      else np.asarray(arrays[f"frame_{name}"]))
                               for name in _FRAME_FIELDS})
               if "frame_G" in arrays else None),
        stage_seconds=dict(meta.get("stage_seconds", {})),
        stage_peak_mb=dict(meta.get("stage_peak_mb", {})),
        stage_ranks=dict(meta.get("stage_ranks", {})),
        from_cache=from_cache,
        force_model="polynomial" if "poly_K" in arrays else "cubature",
        force_coefficients=((np.asarray(arrays["poly_K"]), np.asarray(arrays["poly_cubic"]),
                             np.asarray(arrays["poly_quartic"]))
                            if "poly_K" in arrays else None),
    )


def _table(arrays):
    return TargetTable.from_arrays(arrays)
