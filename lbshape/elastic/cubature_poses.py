"""Training poses of the cubature (An, Kim & James 2008): where the exact reduced
force is fitted (:mod:`lbshape.elastic.cubature`).

**Training poses** (:func:`training_poses`): reduced coordinates
``q_i = σ_i z_i``, ``z ~ N(0, 1)``, with per-coordinate scales σ — inverse
frequency ``σ_i ∝ 1/ω_i`` for modal coordinates (:func:`inverse_frequency_scales`)
— and one global factor so that the largest vertex displacement over all poses
is ``magnitude × object size`` (object size: the largest edge of the rest
bounding box).

The example cubatures (:func:`lbshape.elastic.cubature.train_example_cubatures`) train
instead on the poses along the path between the examples' targets plus small
perturbations (:func:`path_targets`, :func:`example_poses`).
"""

from __future__ import annotations

import logging

import numpy as np

from lbshape.errors import LbshapeError

log = logging.getLogger(__name__)

#: path targets used by :func:`~lbshape.elastic.cubature.train_example_cubatures` at most
#: (evenly spaced); a target table of N = 32 intervals has 33 nodes, finer tables are
#: subsampled to it
MAX_PATH_POSES = 33


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
    U = check_basis(U)
    r = U.shape[1]
    scales = np.asarray(scales, dtype=np.float64)
    if scales.shape != (r,):
        raise LbshapeError(f"scales must have shape ({r},), one per column, got {scales.shape}")
    if not np.isfinite(scales).all() or (scales < 0).any() or not (scales > 0).any():
        raise LbshapeError("scales must be finite, >= 0 and not all zero")
    check_int("count", count, minimum=1)
    _check_positive("magnitude", magnitude)
    _check_positive("object_size", object_size)
    if not isinstance(rng, np.random.Generator):
        raise LbshapeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    Q = rng.standard_normal((count, r)) * scales
    largest = np.linalg.norm((Q @ U.T).reshape(count, -1, 3), axis=2).max()
    if not largest > 0:
        raise LbshapeError("the basis columns with non-zero scale are all zero")
    return Q * (magnitude * object_size / largest)


def path_targets(path: np.ndarray, max_path: int) -> np.ndarray:
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


def example_separation(offsets: np.ndarray) -> float:
    """``max_ij ‖z_i − z_j‖`` of the examples' coordinates (k, p); for one example its
    norm, and 1 when that is zero too."""
    k = offsets.shape[0]
    spread = max((float(np.linalg.norm(offsets[i] - offsets[j]))
                  for i in range(k) for j in range(i + 1, k)), default=0.0)
    return spread or float(np.linalg.norm(offsets, axis=1).max()) or 1.0


def example_poses(base: np.ndarray, *, copies: int, unit: np.ndarray, size: float,
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


def checked_poses(train, holdout, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The training and held-out poses as (P >= 1, k) arrays."""
    train = np.atleast_2d(np.asarray(train, dtype=np.float64))
    holdout = np.atleast_2d(np.asarray(holdout, dtype=np.float64))
    for name, poses in (("train", train), ("holdout", holdout)):
        if poses.ndim != 2 or poses.shape[1] != k or poses.shape[0] < 1:
            raise LbshapeError(f"{name} poses must have shape (P >= 1, {k}), "
                               f"got {poses.shape}")
    return train, holdout


def check_basis(U: np.ndarray, *, n_vertices: int | None = None) -> np.ndarray:
    """U as a finite float64 (3n, k >= 1) array (3n rows for a mesh of ``n_vertices``)."""
    U = np.asarray(U, dtype=np.float64)
    rows = "3n" if n_vertices is None else str(3 * n_vertices)
    if U.ndim != 2 or U.shape[1] < 1 or U.shape[0] % 3 or U.shape[0] == 0:
        raise LbshapeError(f"basis U must have shape ({rows}, k) with k >= 1, got {U.shape}")
    if n_vertices is not None and U.shape[0] != 3 * n_vertices:
        raise LbshapeError(f"basis U must have shape ({rows}, k) for this mesh, got {U.shape}")
    if not np.isfinite(U).all():
        raise LbshapeError("basis U contains NaN or infinite entries")
    return U


def check_int(name: str, value, *, minimum: int) -> None:
    """Refuse a ``value`` that is not an integer >= ``minimum`` (message naming ``name``)."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < minimum:
        raise LbshapeError(f"{name} must be an integer >= {minimum}, got {value!r}")


def _check_positive(name: str, value) -> None:
    if isinstance(value, bool) or not isinstance(value, int | float | np.floating):
        raise LbshapeError(f"{name} must be a number, got {value!r}")
    if not 0 < value < np.inf:
        raise LbshapeError(f"{name} must be finite and > 0, got {value}")
