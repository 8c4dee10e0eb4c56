"""Optimized cubature for reduced elastic forces (An, Kim & James 2008).

The reduced internal force of a basis U (3n, r) is a sum over all E elements,
``f(q) = Σ_e U_eᵀ f_e(U_e q)``. A cubature replaces it by a weighted sum over a few
elements, ``Σ_{e∈S} w_e U_eᵀ f_e(U_e q)`` with ``w_e ≥ 0``, fitted to the exact force
on training poses, in three steps:

1. **Training poses** (:mod:`lbshape.elastic.cubature_poses`): random reduced
   coordinates with per-coordinate scales and one global amplitude
   (:func:`train_cubature`), or the poses along the example path
   (:func:`train_example_cubatures`).
2. **Exact reduced forces** (:mod:`lbshape.elastic.cubature_forces`): the stacked
   exact reduced forces b of the poses, summed over chunks of elements (and MPI
   ranks); the columns of A, one per element, computed when needed; each pose
   normalised by its exact force norm.
3. **Greedy selection + NNLS** (:mod:`lbshape.elastic.cubature_greedy`): elements
   added one at a time, best aligned with the residual, weights by non-negative
   least squares, until the relative training error ``‖A w − b‖ / ‖b‖`` reaches
   ``tol`` or s elements are selected.

The training works for **any basis matrix** U (3n, k): the nonlinear elastic basis,
or the displacement subspace of Laplace-Beltrami eigenfunctions used by the shape
interpolation. Only the scales of the training poses depend on what the columns
mean; the magnitude is always measured on the full-space displacement.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from lbshape.elastic.cubature_forces import (
    DEFAULT_MAX_BYTES,
    ElementColumns,
    PoseForces,
    check_strains,
    exact_pose_forces,
    normalised_forces,
    without_forceless,
)
from lbshape.elastic.cubature_greedy import greedy_nnls
from lbshape.elastic.cubature_poses import (
    MAX_PATH_POSES,
    check_basis,
    check_int,
    checked_poses,
    example_poses,
    example_separation,
    path_targets,
    training_poses,
)
from lbshape.elastic.materials import Material
from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh

log = logging.getLogger(__name__)


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
            :func:`~lbshape.elastic.cubature_poses.training_poses`.
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
    U = check_basis(U, n_vertices=mesh.n_vertices)
    _check_max_elements(max_elements, mesh.n_tets)
    if isinstance(tol, bool) or not isinstance(tol, int | float) or not 0 <= tol < np.inf:
        raise LbshapeError(f"tol must be a finite number >= 0, got {tol!r}")
    check_int("n_train", n_train, minimum=1)
    check_int("n_holdout", n_holdout, minimum=1)
    check_int("candidates_per_iter", candidates_per_iter, minimum=1)
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
    U = check_basis(U, n_vertices=rest_points.shape[0])
    n_tets = tets.shape[0]
    _check_max_elements(max_elements, n_tets)
    train, holdout = checked_poses(train, holdout, U.shape[1])
    forces, strains = exact_pose_forces(rest_points, tets, material, U,
                                        np.concatenate([train, holdout]),
                                        max_bytes=max_bytes, comm=comm)
    poses = PoseForces(train, holdout, forces, strains)
    if drop_forceless:
        poses = without_forceless(poses)
    check_strains(poses.strains, peak_strain)
    n_train = poses.train.shape[0]
    b, factor = normalised_forces(poses.forces[:n_train])
    b_hold, factor_hold = normalised_forces(poses.forces[n_train:])
    columns = ElementColumns(rest_points, tets, material, U, poses.train, factor,
                             max_bytes=max_bytes)
    hold_columns = ElementColumns(rest_points, tets, material, U, poses.holdout, factor_hold,
                                  max_bytes=max_bytes)
    elements, weights, history = greedy_nnls(
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
            and ``copies`` measured in docs/decisions.md, "Interpolation routes").
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
    check_int("max_path", max_path, minimum=4)
    path = path_targets(path, max_path)
    spread = example_separation(offsets)
    scales = np.ones(p) if scales is None else np.asarray(scales, dtype=np.float64)
    unit = scales / np.sqrt(np.mean(scales**2) * p)  # E|δ|² = 1 for δ = unit ⊙ N(0, I)
    rules = []
    for index in range(k):
        train, holdout = example_poses(path - offsets[index], copies=copies, unit=unit,
                                        size=perturbation * spread, spread=spread, rng=rng)
        rules.append(train_cubature_on_poses(
            rest_points[index], tets, material, basis, train=train, holdout=holdout, rng=rng,
            max_elements=max_elements, tol=tol, max_bytes=max_bytes, comm=comm,
            drop_forceless=True))
    return rules


def _rule(elements: np.ndarray, weights: np.ndarray, history: np.ndarray, *, tol: float,
          n_tets: int, poses: PoseForces) -> Cubature:
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


def _check_max_elements(max_elements, n_tets: int) -> None:
    check_int("max_elements", max_elements, minimum=1)
    if max_elements > n_tets:
        raise LbshapeError(
            f"max_elements (s = {max_elements}) exceeds the number of tetrahedra ({n_tets})"
        )
