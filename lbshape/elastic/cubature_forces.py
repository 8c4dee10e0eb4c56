"""The exact reduced forces of the cubature's training poses, streamed over chunks of
elements (:mod:`lbshape.elastic.cubature`).

**Exact reduced forces** (:func:`exact_pose_forces`): ``b (P·r,)``, the stacked
exact reduced forces ``Uᵀ f(U q_p)``, summed over **chunks of elements** whose
temporary arrays stay below ``max_bytes`` (and, with an MPI communicator, over
each rank's share of the chunks, then summed over the ranks). The matrix
``A (P·r, E)`` whose column e stacks element e's reduced forces
(:func:`force_contribution_matrix`, ``b = A @ 1``) is never held: its columns are
computed when needed. Each pose block of A and b is divided by that pose's exact
force norm (per-pose normalisation), so that every pose counts equally whatever
its amplitude.
"""

from __future__ import annotations

import logging
from typing import NamedTuple

import numpy as np

from lbshape.elastic.materials import Material
from lbshape.elastic.reduced_forces import ReducedForceModel
from lbshape.errors import LbshapeError
from lbshape.fem.mpi import rank_share, sum_over_ranks

log = logging.getLogger(__name__)

#: default bound (bytes) on the temporary arrays of one chunk of elements or poses
DEFAULT_MAX_BYTES = 512 * 2**20


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


class PoseForces(NamedTuple):
    """Training and held-out poses with the exact forces and strains of both (training
    rows first)."""

    train: np.ndarray  #: (P, k)
    holdout: np.ndarray  #: (P', k)
    forces: np.ndarray  #: (P + P', k) exact reduced forces
    strains: np.ndarray  #: (P + P',) largest element strain of each pose


def without_forceless(poses: PoseForces) -> PoseForces:
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
    return PoseForces(poses.train[keep[:n_train]], poses.holdout[keep[n_train:]],
                       forces[keep], strains[keep])


def check_strains(strains: np.ndarray, peak_strain: float | None) -> None:
    """Refuse a pose that only moves the mesh rigidly (strain ≤ 1e-9 of the peak;
    default peak: the largest of ``strains``)."""
    if peak_strain is None:
        peak_strain = float(strains.max())
    if (strains <= 1e-9 * peak_strain).any():
        raise LbshapeError(
            "a training pose has no elastic force: the basis only translates the "
            "mesh rigidly (or not at all) for some poses"
        )


def normalised_forces(forces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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


class ElementColumns:
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


def _max_over_ranks(comm, value: np.ndarray) -> np.ndarray:
    """Elementwise maximum of ``value`` over the ranks (itself without ``comm``)."""
    if comm is None or comm.size == 1:
        return value
    return np.max(comm.allgather(np.asarray(value)), axis=0)
