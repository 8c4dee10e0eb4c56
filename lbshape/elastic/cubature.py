"""Optimized cubature for reduced elastic forces (An, Kim & James 2008).

The reduced internal force of a basis U (3n, r) is a sum over all E elements,
``f(q) = Σ_e U_eᵀ f_e(U_e q)``. A cubature replaces it by a weighted sum over a few
elements, ``Σ_{e∈S} w_e U_eᵀ f_e(U_e q)`` with ``w_e ≥ 0``, fitted to the exact force
on random training poses:

1. **Training poses** (:func:`training_poses`): reduced coordinates
   ``q_i = σ_i z_i``, ``z ~ N(0, 1)``, with per-coordinate scales σ — inverse
   frequency ``σ_i ∝ 1/ω_i`` for modal coordinates (:func:`inverse_frequency_scales`)
   — and one global factor so that the largest vertex displacement over all poses
   is ``magnitude × object size`` (object size: the largest edge of the rest
   bounding box).
2. **Exact reduced forces** (:func:`exact_pose_forces`): ``b (P·r,)``, the stacked
   exact reduced forces ``Uᵀ f(U q_p)``, summed over **chunks of elements** whose
   temporary arrays stay below ``max_bytes`` (and, with an MPI communicator, over
   each rank's share of the chunks, then summed over the ranks). The matrix
   ``A (P·r, E)`` whose column e stacks element e's reduced forces
   (:func:`force_contribution_matrix`, ``b = A @ 1``) is never held: its columns are
   computed when needed. Each pose block of A and b is divided by that pose's exact
   force norm (per-pose normalisation), so that every pose counts equally whatever
   its amplitude.
3. **Greedy selection + NNLS** (:func:`train_cubature`): at each step draw a random
   batch of candidate elements, compute their columns, add the one whose column is
   best aligned with the current residual (largest ``A_eᵀ res / ‖A_e‖``; scores equal to within
   :data:`TIE_RTOL` go to the lowest element index, not to round-off), solve the
   non-negative least squares problem on the selected columns, drop elements whose
   weight became zero, and stop when the relative training error
   ``‖A w − b‖ / ‖b‖`` reaches ``tol`` or s elements are selected. Each NNLS solve
   is optimal on its set, so the error never increases. Only when no candidate of a
   batch helps is a wider set scanned (in chunks): every element when at most
   :data:`FALLBACK_ELEMENTS` remain (every built-in scene but the 100k-vertex one),
   else that many drawn at random (a full scan of a large mesh costs tens of seconds,
   ``docs/architecture.md``). The greedy steps are the
   same on every rank (same seed, same draws); memory is O(P·r·(s + batch)) besides
   one chunk.

The training works for **any basis matrix** U (3n, k): the nonlinear elastic basis,
or the displacement subspace of Laplace-Beltrami eigenfunctions used by the shape
interpolation. Only the scales of the training poses depend on what the columns
mean; the magnitude is always measured on the full-space displacement.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.optimize import nnls

from lbshape.elastic.materials import Material
from lbshape.elastic.reduced_forces import ReducedForceModel
from lbshape.errors import LbshapeError, SolverError
from lbshape.fem.mpi import rank_share, sum_over_ranks
from lbshape.geometry.mesh import TetMesh

log = logging.getLogger(__name__)

#: default bound (bytes) on the temporary arrays of one chunk of elements or poses
DEFAULT_MAX_BYTES = 512 * 2**20
#: elements scanned when no candidate of a batch helps: all of them up to this many,
#: else this many drawn at random
FALLBACK_ELEMENTS = 8192
#: greedy scores within this share of the best are a tie, broken by the lowest element
#: index, so round-off (e.g. the BLAS thread count) never decides between elements whose
#: scores differ only by it
TIE_RTOL = 1e-9
#: path targets used by :func:`train_example_cubatures` at most (evenly spaced); a
#: target table of N = 32 intervals has 33 nodes, finer tables are subsampled to it
MAX_PATH_POSES = 33


@dataclass(frozen=True)
class Cubature:
    """A trained cubature rule.

    Attributes:
        elements: (s,) int64 indices of the selected tetrahedra (into ``mesh.tets``).
        weights: (s,) float64 non-negative weights (dimensionless).
        train_error: relative force error ``‖A w − b‖ / ‖b‖`` on the training poses
            (after per-pose normalisation: the RMS over poses of the relative error).
        holdout_error: the same on the held-out poses (not used for fitting).
        errors_by_size: (k, 3) history, one row per greedy step:
            ``[number of elements, train error, holdout error]``.
        tol: the requested training tolerance.
        reached_tol: whether ``train_error <= tol`` (else the size limit stopped it).
        n_train: number of training poses.
        n_holdout: number of held-out poses.
    """

    elements: np.ndarray
    weights: np.ndarray
    train_error: float
    holdout_error: float
    errors_by_size: np.ndarray
    tol: float
    reached_tol: bool
    n_train: int
    n_holdout: int

    @property
    def size(self) -> int:
        """s, the number of cubature elements."""
        return int(self.elements.size)


def inverse_frequency_scales(omega2: np.ndarray) -> np.ndarray:
    """Per-coordinate pose scales ``σ_i = ω_1 / ω_i`` (r,) from squared frequencies.

    Args:
        omega2: (r,) eigenvalues ``ω_i²`` (rad²/s²), all > 0.

    Returns:
        (r,) scales in (0, 1], the lowest frequency having scale 1.
    """
    omega2 = np.asarray(omega2, dtype=np.float64)
    if omega2.ndim != 1 or omega2.size == 0:
        raise LbshapeError(f"omega2 must be a non-empty 1-D array, got shape {omega2.shape}")
    if not np.isfinite(omega2).all() or (omega2 <= 0).any():
        raise LbshapeError("omega2 must be finite and > 0 (remove rigid modes first)")
    omega = np.sqrt(omega2)
    return omega.min() / omega


def training_poses(
    U: np.ndarray,
    scales: np.ndarray,
    *,
    count: int,
    magnitude: float,
    object_size: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """Random reduced coordinates for cubature training (An et al. 2008).

    ``q_p = c · σ ⊙ z_p`` with ``z_p ~ N(0, I)``; the single factor c makes the largest
    vertex displacement ``max_p max_v ‖(U q_p)_v‖`` equal ``magnitude · object_size``,
    so the poses span amplitudes from small up to that size.

    Args:
        U: (3n, r) basis, node-major rows.
        scales: (r,) non-negative per-coordinate scales σ (e.g.
            :func:`inverse_frequency_scales`), not all zero.
        count: number of poses P >= 1.
        magnitude: largest displacement as a fraction of the object size, > 0.
        object_size: a length of the object in metres, > 0.
        rng: the random generator.

    Returns:
        (P, r) reduced coordinates.
    """
    U = _check_basis(U)
    r = U.shape[1]
    scales = np.asarray(scales, dtype=np.float64)
    if scales.shape != (r,):
        raise LbshapeError(f"scales must have shape ({r},), one per column, got {scales.shape}")
    if not np.isfinite(scales).all() or (scales < 0).any() or not (scales > 0).any():
        raise LbshapeError("scales must be finite, >= 0 and not all zero")
    _check_int("count", count, minimum=1)
    _check_positive("magnitude", magnitude)
    _check_positive("object_size", object_size)
    if not isinstance(rng, np.random.Generator):
        raise LbshapeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    Q = rng.standard_normal((count, r)) * scales
    largest = np.linalg.norm((Q @ U.T).reshape(count, -1, 3), axis=2).max()
    if not largest > 0:
        raise LbshapeError("the basis columns with non-zero scale are all zero")
    return Q * (magnitude * object_size / largest)


def force_contribution_matrix(
    model: ReducedForceModel, poses: np.ndarray, *, max_bytes: int = DEFAULT_MAX_BYTES
) -> np.ndarray:
    """Per-element reduced forces of many poses, ``A (P·r, s)``.

    ``A[p·r + i, e]`` is component i of element e's reduced force ``U_eᵀ f_e(U_e q_p)``
    (the weights of ``model`` are not applied); with ``model`` over all elements of a
    mesh, ``A @ 1`` stacks the exact reduced forces ``Uᵀ f(U q_p)``. Evaluated
    vectorised over elements and over chunks of poses.

    Args:
        model: the elements and basis (usually all elements, unit weights).
        poses: (P, r) reduced coordinates.
        max_bytes: bound on the temporary arrays of one chunk (bytes).

    Returns:
        (P·r, s) float64 array in Fortran order (columns contiguous).
    """
    poses = np.asarray(poses, dtype=np.float64)
    r, s = model.n_coordinates, model.n_elements
    if poses.ndim != 2 or poses.shape[1] != r:
        raise LbshapeError(f"poses must have shape (P, {r}), got {poses.shape}")
    n_poses = poses.shape[0]
    per_pose = 8 * s * (2 * r + 9 * 12)  # output + transposed copy + stress temporaries
    chunk = int(max(1, min(n_poses, max_bytes // per_pose)))
    A = np.empty((n_poses * r, s), order="F")
    for start in range(0, n_poses, chunk):
        stop = min(n_poses, start + chunk)
        A[start * r : stop * r] = model.element_forces(poses[start:stop].T).reshape(-1, s)
    return A


def element_chunks(count: int, per_element_bytes: int, max_bytes: int, *,
                   parts: int = 1) -> list[range]:
    """Consecutive blocks of ``range(count)`` whose temporaries stay below ``max_bytes``.

    Args:
        count: number of elements.
        per_element_bytes: temporary bytes one element needs (> 0).
        max_bytes: the bound (bytes); at least one element per block whatever it is.
        parts: at least this many blocks when ``count`` allows (e.g. the number of MPI
            ranks sharing them, so that every rank gets work).

    Returns:
        The blocks in order (their concatenation is ``range(count)``).
    """
    size = int(max(1, min(max_bytes // max(1, per_element_bytes), -(-count // parts))))
    return [range(start, min(count, start + size)) for start in range(0, count, size)]


def exact_pose_forces(
    rest_points: np.ndarray,
    tets: np.ndarray,
    material: Material,
    U: np.ndarray,
    poses: np.ndarray,
    *,
    max_bytes: int = DEFAULT_MAX_BYTES,
    comm=None,
) -> tuple[np.ndarray, np.ndarray]:
    """Exact reduced forces and largest strains of many poses, streamed over elements.

    ``forces[p] = Uᵀ f(U q_p) = Σ_e U_eᵀ f_e(U_e q_p)`` over all tetrahedra, summed chunk
    by chunk (:func:`element_chunks`, :meth:`ReducedForceModel.pose_forces`) so memory is
    bounded by ``max_bytes`` whatever the mesh size. With ``comm`` (an MPI
    communicator) each rank sums its share of the chunks
    (:func:`lbshape.fem.mpi.rank_share`) and the parts are summed over the ranks; every
    rank gets the totals.

    Args:
        rest_points: (n, 3) rest shape in metres.
        tets: (t, 4) tetrahedra.
        material: the hyperelastic material.
        U: (3n, r) basis, node-major rows.
        poses: (P, r) reduced coordinates.
        max_bytes: bound on one chunk's arrays (bytes).
        comm: MPI communicator, or None (serial).

    Returns:
        (forces (P, r) in N per unit of q, strains (P,) the largest ``‖F_e − I‖_F``
        over the elements, dimensionless).
    """
    poses = np.atleast_2d(np.asarray(poses, dtype=np.float64))
    r = U.shape[1]
    if poses.ndim != 2 or poses.shape[1] != r:
        raise LbshapeError(f"poses must have shape (P, {r}), got {poses.shape}")
    n_poses = poses.shape[0]
    # model (element rows, BU three times, kernel) + gradients, stresses, strains
    per_element = 8 * (39 * r + 260 + 21 * n_poses)
    chunks = element_chunks(tets.shape[0], per_element, max_bytes,
                            parts=1 if comm is None else comm.size)
    forces, strains = np.zeros((n_poses, r)), np.zeros(n_poses)
    for index in rank_share(comm, len(chunks)):
        chunk = chunks[index]
        model = ReducedForceModel(rest_points, tets, material, U,
                                  np.arange(chunk.start, chunk.stop), np.ones(len(chunk)),
                                  tangent=False)
        part, strain = model.pose_forces(poses.T)
        forces += part
        np.maximum(strains, strain, out=strains)
    return sum_over_ranks(comm, forces), _max_over_ranks(comm, strains)


def train_cubature(
    mesh: TetMesh,
    material: Material,
    U: np.ndarray,
    *,
    rng: np.random.Generator,
    scales: np.ndarray | None = None,
    max_elements: int = 60,
    tol: float = 0.01,
    n_train: int = 100,
    n_holdout: int = 50,
    candidates_per_iter: int = 100,
    magnitude: float = 0.1,
    max_bytes: int = DEFAULT_MAX_BYTES,
    progress: bool = False,
    comm=None,
) -> Cubature:
    """Select cubature elements and weights for the reduced force of a basis U.

    Args:
        mesh: the object's mesh; its points are the rest shape.
        material: the hyperelastic material.
        U: (3n, k) any basis, node-major rows, mapping coordinates to metres.
        rng: the random generator (poses and candidate batches); same seed, same
            result.
        scales: (k,) per-coordinate pose scales (default: all 1); see
            :func:`training_poses`.
        max_elements: s, the largest number of elements (1 <= s <= number of tets).
        tol: relative training error at which to stop (>= 0; 0: use all s elements).
        n_train: number of training poses (>= 1).
        n_holdout: number of held-out poses for the reported error (>= 1).
        candidates_per_iter: elements drawn per greedy step (>= 1).
        magnitude: largest training displacement as a fraction of the object size
            (largest edge of the bounding box), > 0.
        max_bytes: bound (bytes) on the arrays of one chunk of elements (the exact
            forces are summed chunk by chunk; same result for any bound).
        progress: show a progress bar.
        comm: MPI communicator: the passes over all elements are split across its
            ranks (every rank returns the same rule); None: serial.

    Returns:
        The :class:`Cubature`.

    Raises:
        LbshapeError: bad parameters, or a basis producing no elastic force.
        SolverError: the NNLS solver failed.
    """
    if not isinstance(mesh, TetMesh):
        raise LbshapeError(f"mesh must be a TetMesh, got {type(mesh).__name__}")
    U = _check_basis(U, n_vertices=mesh.n_vertices)
    _check_max_elements(max_elements, mesh.n_tets)
    if isinstance(tol, bool) or not isinstance(tol, int | float) or not 0 <= tol < np.inf:
        raise LbshapeError(f"tol must be a finite number >= 0, got {tol!r}")
    _check_int("n_train", n_train, minimum=1)
    _check_int("n_holdout", n_holdout, minimum=1)
    _check_int("candidates_per_iter", candidates_per_iter, minimum=1)
    if scales is None:
        scales = np.ones(U.shape[1])
    size = float(np.ptp(mesh.points, axis=0).max())

    poses = training_poses(
        U, scales, count=n_train + n_holdout, magnitude=magnitude, object_size=size, rng=rng
    )
    return train_cubature_on_poses(
        mesh.points, mesh.tets, material, U, train=poses[:n_train], holdout=poses[n_train:],
        rng=rng, max_elements=max_elements, tol=tol, candidates_per_iter=candidates_per_iter,
        max_bytes=max_bytes, progress=progress, peak_strain=magnitude, comm=comm,
    )


def train_cubature_on_poses(
    rest_points: np.ndarray,
    tets: np.ndarray,
    material: Material,
    U: np.ndarray,
    *,
    train: np.ndarray,
    holdout: np.ndarray,
    rng: np.random.Generator,
    max_elements: int = 60,
    tol: float = 0.01,
    candidates_per_iter: int = 100,
    max_bytes: int = DEFAULT_MAX_BYTES,
    progress: bool = False,
    peak_strain: float | None = None,
    comm=None,
    drop_forceless: bool = False,
) -> Cubature:
    """Greedy + NNLS cubature fitted to given training poses on a given rest shape.

    The core of :func:`train_cubature`, for callers that know which poses matter: e.g.
    the LB route's per-example cubature, trained on example k's rest shape X_k
    (reconstructed on the object's mesh) with poses along the path between the
    examples' targets plus small perturbations.

    Args:
        rest_points: (n, 3) rest shape in metres (the object's mesh points or X_k).
        tets: (t, 4) the mesh's tetrahedra.
        material: the hyperelastic material.
        U: (3n, k) basis, node-major rows, mapping coordinates to metres.
        train: (P, k) training poses (coordinates relative to the rest shape).
        holdout: (P', k) held-out poses (reported error only).
        rng: generator of the candidate batches.
        max_elements, tol, candidates_per_iter, max_bytes, progress, comm: as in
            :func:`train_cubature`.
        peak_strain: the poses' largest expected strain, for the rigid-pose check
            (default: measured on the poses).
        drop_forceless: leave out (and log) poses without a finite, non-negligible exact
            force instead of refusing them (an error only when no training or held-out
            pose remains); e.g. example path targets from an exact solve that did not
            converge.

    Returns:
        The :class:`Cubature` (``n_train``/``n_holdout`` the pose counts).
    """
    rest_points = np.asarray(rest_points, dtype=np.float64)
    tets = np.asarray(tets)
    U = _check_basis(U, n_vertices=rest_points.shape[0])
    n_tets = tets.shape[0]
    _check_max_elements(max_elements, n_tets)
    train, holdout = _checked_poses(train, holdout, U.shape[1])
    forces, strains = exact_pose_forces(rest_points, tets, material, U,
                                        np.concatenate([train, holdout]),
                                        max_bytes=max_bytes, comm=comm)
    poses = _PoseForces(train, holdout, forces, strains)
    if drop_forceless:
        poses = _drop_forceless(poses)
    _check_strains(poses.strains, peak_strain)
    n_train = poses.train.shape[0]
    b, factor = _normalised_forces(poses.forces[:n_train])
    b_hold, factor_hold = _normalised_forces(poses.forces[n_train:])
    columns = _Columns(rest_points, tets, material, U, poses.train, factor, max_bytes=max_bytes)
    hold_columns = _Columns(rest_points, tets, material, U, poses.holdout, factor_hold,
                            max_bytes=max_bytes)
    elements, weights, history = _greedy_nnls(
        columns, b, hold_columns, b_hold, n_elements=n_tets, s=max_elements, tol=float(tol),
        candidates=candidates_per_iter, rng=rng, progress=progress, comm=comm,
    )
    return _rule(elements, weights, history, tol=float(tol), n_tets=n_tets, poses=poses)


def train_example_cubatures(
    rest_points: list[np.ndarray],
    tets: np.ndarray,
    material: Material,
    basis: np.ndarray,
    offsets: np.ndarray,
    path: np.ndarray,
    *,
    rng: np.random.Generator,
    scales: np.ndarray | None = None,
    perturbation: float = 0.01,
    copies: int = 4,
    max_elements: int = 60,
    tol: float = 0.01,
    max_bytes: int = DEFAULT_MAX_BYTES,
    comm=None,
    max_path: int = MAX_PATH_POSES,
) -> list[Cubature]:
    """One cubature per example, trained where the target search evaluates it.

    The target energy of example k is evaluated on its own rest shape X_k (n, 3) at
    ``y = z − z_k`` for targets z between the examples. Training on the object's rest
    shape with random poses (:func:`train_cubature`) fits the wrong integrand; here
    example k's cubature is fitted on X_k to the poses ``y = z_j − z_k`` for the path
    targets z_j (exact targets at weights spread over the simplex) plus ``copies``
    random perturbations of each, of RMS size ``perturbation × separation``
    (separation ``max_ij ‖z_i − z_j‖``) with per-coordinate ``scales``. Every other
    path pose and its perturbations are held out.

    Args:
        rest_points: k arrays (n, 3), the examples' rest shapes on the object's mesh.
        tets: (t, 4) tetrahedra.
        material: the hyperelastic material.
        basis: (3n, p) the coordinates' basis B (node-major rows).
        offsets: (k, p) the examples' own coordinates z_k.
        path: (P, p) exact targets along the example path (P >= 4).
        rng: generator of the perturbations and candidate batches.
        scales: (p,) per-coordinate perturbation scales (default all 1).
        perturbation: RMS perturbation size as a share of the separation (the default
            and ``copies`` measured in docs/architecture.md, "Interpolation routes").
        copies: perturbations per path pose.
        max_elements, tol, max_bytes, comm: as in :func:`train_cubature`.
        max_path: at most this many path targets are used, evenly spaced along the path
            (first and last kept): every pose costs one pass over all elements, and a
            table refined to N = 256 intervals (257 nodes) on a fine mesh would make
            the training 8 times as long as the N = 32 nodes it then uses.

    Returns:
        k :class:`Cubature` rules (element indices into ``tets``).
    """
    offsets = np.atleast_2d(np.asarray(offsets, dtype=np.float64))
    path = np.atleast_2d(np.asarray(path, dtype=np.float64))
    k, p = offsets.shape
    if len(rest_points) != k or path.shape[1] != p or path.shape[0] < 4:
        raise LbshapeError(f"need {k} rest shapes and a path of >= 4 targets with {p} "
                           f"coordinates, got {len(rest_points)} and {path.shape}")
    _check_int("max_path", max_path, minimum=4)
    path = _path_targets(path, max_path)
    spread = _separation(offsets)
    scales = np.ones(p) if scales is None else np.asarray(scales, dtype=np.float64)
    unit = scales / np.sqrt(np.mean(scales**2) * p)  # E|δ|² = 1 for δ = unit ⊙ N(0, I)
    rules = []
    for index in range(k):
        train, holdout = _example_poses(path - offsets[index], copies=copies, unit=unit,
                                        size=perturbation * spread, spread=spread, rng=rng)
        rules.append(train_cubature_on_poses(
            rest_points[index], tets, material, basis, train=train, holdout=holdout, rng=rng,
            max_elements=max_elements, tol=tol, max_bytes=max_bytes, comm=comm,
            drop_forceless=True))
    return rules


def _path_targets(path: np.ndarray, max_path: int) -> np.ndarray:
    """The finite path targets (P, p), at most ``max_path`` of them evenly spaced (first
    and last kept)."""
    finite = np.isfinite(path).all(axis=1)
    if not finite.all():
        log.warning("example cubature: %d non-finite path targets left out",
                    int((~finite).sum()))
        path = path[finite]
    if path.shape[0] > max_path:
        path = path[np.unique(np.round(np.linspace(0, path.shape[0] - 1, max_path)).astype(int))]
    return path


def _separation(offsets: np.ndarray) -> float:
    """``max_ij ‖z_i − z_j‖`` of the examples' coordinates (k, p); for one example its
    norm, and 1 when that is zero too."""
    k = offsets.shape[0]
    spread = max((float(np.linalg.norm(offsets[i] - offsets[j]))
                  for i in range(k) for j in range(i + 1, k)), default=0.0)
    return spread or float(np.linalg.norm(offsets, axis=1).max()) or 1.0


def _example_poses(base: np.ndarray, *, copies: int, unit: np.ndarray, size: float,
                   spread: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(training, held-out) poses of one example: the path poses ``base`` (P, p) and
    ``copies`` perturbations of each (``unit`` (p,) per-coordinate scales of RMS 1 over
    the coordinates, times ``size``); every other path pose and its perturbations are
    held out, the rest pose left out."""
    p = base.shape[1]
    perturbations = rng.standard_normal((copies * base.shape[0], p)) * unit * size
    poses = np.concatenate([base, np.repeat(base, copies, axis=0) + perturbations])
    owner = np.concatenate([np.arange(base.shape[0]),
                            np.repeat(np.arange(base.shape[0]), copies)])
    moving = np.linalg.norm(poses, axis=1) > 1e-12 * spread  # drop the rest pose
    held = (owner % 2 == 1) & moving
    return poses[~held & moving], poses[held]


# -- internals ---------------------------------------------------------------------------
class _PoseForces(NamedTuple):
    """Training and held-out poses with the exact forces and strains of both (training
    rows first)."""

    train: np.ndarray  #: (P, k)
    holdout: np.ndarray  #: (P', k)
    forces: np.ndarray  #: (P + P', k) exact reduced forces
    strains: np.ndarray  #: (P + P',) largest element strain of each pose


def _checked_poses(train, holdout, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The training and held-out poses as (P >= 1, k) arrays."""
    train = np.atleast_2d(np.asarray(train, dtype=np.float64))
    holdout = np.atleast_2d(np.asarray(holdout, dtype=np.float64))
    for name, poses in (("train", train), ("holdout", holdout)):
        if poses.ndim != 2 or poses.shape[1] != k or poses.shape[0] < 1:
            raise LbshapeError(f"{name} poses must have shape (P >= 1, {k}), "
                               f"got {poses.shape}")
    return train, holdout


def _drop_forceless(poses: _PoseForces) -> _PoseForces:
    """The poses with a finite, non-negligible exact force (logged when some are left
    out); an error when no training or held-out pose remains."""
    forces, strains = poses.forces, poses.strains
    n_train = poses.train.shape[0]
    norms = np.linalg.norm(forces, axis=1)
    finite = np.isfinite(norms) & np.isfinite(strains)
    largest = norms[finite].max(initial=0.0)
    keep = finite & (norms > 1e-12 * largest) & (strains > 1e-9 * strains[finite].max(
        initial=0.0))
    if not keep.all():
        log.warning("cubature: %d of %d poses without a finite elastic force left out",
                    int((~keep).sum()), keep.size)
    if not keep[:n_train].any() or not keep[n_train:].any():
        raise LbshapeError("no training or held-out pose has an elastic force")
    return _PoseForces(poses.train[keep[:n_train]], poses.holdout[keep[n_train:]],
                       forces[keep], strains[keep])


def _check_strains(strains: np.ndarray, peak_strain: float | None) -> None:
    """Refuse a pose that only moves the mesh rigidly (strain ≤ 1e-9 of the peak;
    default peak: the largest of ``strains``)."""
    if peak_strain is None:
        peak_strain = float(strains.max())
    if (strains <= 1e-9 * peak_strain).any():
        raise LbshapeError(
            "a training pose has no elastic force: the basis only translates the "
            "mesh rigidly (or not at all) for some poses"
        )


def _rule(elements: np.ndarray, weights: np.ndarray, history: np.ndarray, *, tol: float,
          n_tets: int, poses: _PoseForces) -> Cubature:
    """The trained :class:`Cubature` (logged; its arrays read-only)."""
    train_error, holdout_error = (float(v) for v in history[-1, 1:])
    reached = train_error <= tol
    log.info(
        "cubature: %d of %d elements, training error %.3g (tol %.3g%s), held-out error %.3g",
        elements.size, n_tets, train_error, tol, "" if reached else ", not reached",
        holdout_error,
    )
    for array in (elements, weights, history):
        array.setflags(write=False)
    return Cubature(
        elements=elements,
        weights=weights,
        train_error=train_error,
        holdout_error=holdout_error,
        errors_by_size=history,
        tol=tol,
        reached_tol=bool(reached),
        n_train=int(poses.train.shape[0]),
        n_holdout=int(poses.holdout.shape[0]),
    )


def _normalised_forces(forces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Stacked exact forces (P, r) divided per pose by their norm: (b (P·r,), factor (P·r,)),
    the factor dividing every pose block of A and b."""
    norms = np.linalg.norm(forces, axis=1)
    if not norms.max() > 0 or (norms <= 1e-12 * norms.max()).any():
        raise LbshapeError(
            "a training pose has no elastic force: the basis moves the mesh rigidly "
            "(or not at all) for some poses"
        )
    factor = np.repeat(1.0 / norms, forces.shape[1])
    return forces.reshape(-1) * factor, factor


class _Columns:
    """Normalised columns of A (P·r, E) computed on demand, in element chunks."""

    def __init__(self, rest_points, tets, material, U, poses, factor, *, max_bytes):
        self._args = (rest_points, tets, material, U)
        self._poses = poses
        self._factor = factor
        r = U.shape[1]
        self._per_element = 8 * (39 * r + 260 + poses.shape[0] * (2 * r + 9 * 12))
        self._max_bytes = max_bytes

    def __call__(self, elements: np.ndarray) -> np.ndarray:
        """(P·r, k) columns of ``elements`` (k,), Fortran order (at most one chunk)."""
        model = ReducedForceModel(*self._args, elements, np.ones(elements.size),
                                  tangent=False)
        A = force_contribution_matrix(model, self._poses, max_bytes=self._max_bytes)
        A *= self._factor[:, None]
        return A

    def chunks(self, elements: np.ndarray, *, parts: int = 1) -> list[np.ndarray]:
        """``elements`` split into blocks (at least ``parts``) whose columns fit the
        memory bound."""
        return [elements[block.start:block.stop] for block in
                element_chunks(elements.size, self._per_element, self._max_bytes,
                               parts=parts)]


def _greedy_nnls(columns, b, hold_columns, b_hold, *, n_elements, s, tol, candidates, rng,
                 progress, comm):
    """Greedy candidate selection + NNLS; returns (elements, weights, history)."""
    b_norm, b_hold_norm = np.linalg.norm(b), np.linalg.norm(b_hold)
    selected = np.zeros(0, dtype=np.int64)
    weights = np.zeros(0)
    chosen = np.zeros((b.size, 0), order="F")  # columns of the selected elements
    chosen_hold = np.zeros((b_hold.size, 0), order="F")
    residual = b.copy()
    error = 1.0
    history = []
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=s, desc="cubature", unit="elt")
    try:
        for _ in range(10 * s):  # every step lowers the error; the cap is a safeguard
            if selected.size >= s or error <= tol:
                break
            pool = np.setdiff1d(np.arange(n_elements), selected, assume_unique=True)
            if pool.size == 0:
                break
            batch = rng.choice(pool, size=min(candidates, pool.size), replace=False)
            column = _best_aligned(columns, residual, batch)
            if column is None:  # nothing in the batch helps: look at (many) more elements
                wider = pool if pool.size <= FALLBACK_ELEMENTS else np.sort(
                    rng.choice(pool, size=FALLBACK_ELEMENTS, replace=False))
                column = _best_aligned_in_chunks(columns, residual, wider, comm)
                if column is None:
                    log.info("cubature: no remaining element reduces the error %.3g", error)
                    break
            best, A_best = column
            trial = np.append(selected, best)
            A_trial = np.column_stack([chosen, A_best])
            try:
                w, _ = nnls(A_trial, b)
            except RuntimeError as exc:
                raise SolverError(
                    f"cubature NNLS failed with {trial.size} elements: {exc}"
                ) from None
            keep = w > 0
            hold_trial = np.column_stack([chosen_hold, hold_columns(np.array([best]))])
            selected, weights = trial[keep], w[keep]
            chosen = np.asfortranarray(A_trial[:, keep])
            chosen_hold = np.asfortranarray(hold_trial[:, keep])
            residual = b - chosen @ weights
            error = float(np.linalg.norm(residual) / b_norm)
            holdout = float(np.linalg.norm(chosen_hold @ weights - b_hold) / b_hold_norm)
            history.append((selected.size, error, holdout))
            if bar is not None:
                bar.n = selected.size
                bar.set_postfix(train=f"{error:.2e}", holdout=f"{holdout:.2e}")
    finally:
        if bar is not None:
            bar.close()
    if not history:
        raise LbshapeError("cubature: no element reduces the training error")
    return selected.astype(np.int64), weights.astype(np.float64), np.asarray(history, dtype=float)


def _scores(A: np.ndarray, residual: np.ndarray) -> np.ndarray:
    """``A_eᵀ res / ‖A_e‖`` per column (0 for a zero column)."""
    norms = np.linalg.norm(A, axis=0)
    inv = np.divide(1.0, norms, out=np.zeros_like(norms), where=norms > 0)
    return (residual @ A) * inv


def _near_best(scores: np.ndarray) -> np.ndarray:
    """Mask of the scores within :data:`TIE_RTOL` of the largest (its near-ties)."""
    best = scores.max()
    return scores >= best - TIE_RTOL * abs(best)


def _best_aligned(columns, residual, candidates) -> tuple[int, np.ndarray] | None:
    """(element, column) of the candidate with the largest positive score, or None;
    of near-equal best scores (:data:`TIE_RTOL`) the lowest element index."""
    A = columns(candidates)
    scores = _scores(A, residual)
    near = np.flatnonzero(_near_best(scores))
    i = int(near[np.argmin(candidates[near])])
    return (int(candidates[i]), A[:, i].copy()) if scores.max() > 0 else None


def _best_aligned_in_chunks(columns, residual, pool, comm) -> tuple[int, np.ndarray] | None:
    """:func:`_best_aligned` over every element of ``pool``, chunk by chunk (split across
    the ranks of ``comm``): the same element for any chunking and rank count."""
    blocks = columns.chunks(pool, parts=1 if comm is None else comm.size)
    scores, elements = [np.zeros(0)], [np.zeros(0, dtype=np.int64)]
    for index in rank_share(comm, len(blocks)):
        block = _scores(columns(blocks[index]), residual)
        near = _near_best(block)  # a near-tie of the overall best is one of its block's
        scores.append(block[near])
        elements.append(np.asarray(blocks[index])[near])
    scores, elements = np.concatenate(scores), np.concatenate(elements)
    if comm is not None and comm.size > 1:
        gathered = comm.allgather((scores, elements))
        scores = np.concatenate([part[0] for part in gathered])
        elements = np.concatenate([part[1] for part in gathered])
    if scores.size == 0 or not scores.max() > 0:
        return None
    best_element = int(elements[_near_best(scores)].min())
    return best_element, columns(np.array([best_element]))[:, 0].copy()


def _max_over_ranks(comm, value: np.ndarray) -> np.ndarray:
    """Elementwise maximum of ``value`` over the ranks (itself without ``comm``)."""
    if comm is None or comm.size == 1:
        return value
    return np.max(comm.allgather(np.asarray(value)), axis=0)


def _check_basis(U: np.ndarray, *, n_vertices: int | None = None) -> np.ndarray:
    U = np.asarray(U, dtype=np.float64)
    rows = "3n" if n_vertices is None else str(3 * n_vertices)
    if U.ndim != 2 or U.shape[1] < 1 or U.shape[0] % 3 or U.shape[0] == 0:
        raise LbshapeError(f"basis U must have shape ({rows}, k) with k >= 1, got {U.shape}")
    if n_vertices is not None and U.shape[0] != 3 * n_vertices:
        raise LbshapeError(f"basis U must have shape ({rows}, k) for this mesh, got {U.shape}")
    if not np.isfinite(U).all():
        raise LbshapeError("basis U contains NaN or infinite entries")
    return U


def _check_max_elements(max_elements, n_tets: int) -> None:
    _check_int("max_elements", max_elements, minimum=1)
    if max_elements > n_tets:
        raise LbshapeError(
            f"max_elements (s = {max_elements}) exceeds the number of tetrahedra ({n_tets})"
        )


def _check_int(name: str, value, *, minimum: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < minimum:
        raise LbshapeError(f"{name} must be an integer >= {minimum}, got {value!r}")


def _check_positive(name: str, value) -> None:
    if isinstance(value, bool) or not isinstance(value, int | float | np.floating):
        raise LbshapeError(f"{name} must be a number, got {value!r}")
    if not 0 < value < np.inf:
        raise LbshapeError(f"{name} must be finite and > 0, got {value}")
