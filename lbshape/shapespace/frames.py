"""Body frames (centre of mass, principal axes) and aligning examples to the object.

**Body frame.** For a uniform density, the centre of mass c, the volume V and the
second-moment tensor ``S = ∫ (x − c)(x − c)ᵀ dV`` (m⁵) are integrated exactly over
the linear tetrahedra; the inertia tensor per unit density is ``tr(S) I − S``.
The principal axes are the eigenvectors of S, as columns, ordered by
**decreasing** second moment (the first axis is the direction of largest spread —
a bar's long axis — i.e. increasing principal moment of inertia).

**Sign rule.** Axis k is oriented so that the third moment
``μ₃ₖ = ∫ ((x − c)·aₖ)³ dV`` is positive. A sign is *ambiguous* when the skewness
``|μ₃ₖ| / (V σₖ³) ≤ SIGN_RTOL`` (σₖ² the variance along aₖ), e.g. for shapes
symmetric under a reflection. If the three axes are then left-handed, the last
ambiguous axis is reversed (or, when none is ambiguous, the least skewed one), so
the frame is right-handed and a rotated copy gets the rotated frame. Two principal
moments are *degenerate* when neighbours differ by less than ``DEGENERACY_RTOL``
times the larger one (a square bar, a cube); the axes inside a degenerate cluster
are arbitrary.

**Alignment convention.** Examples are brought into the object's rest placement
in world coordinates: ``x' = s R (x − c_e) + c_o`` with c_e, c_o the centres of
mass. The scale ``s = (V_o / V_e)^(1/3)`` normalises the example's volume to the
object's rest volume: **shapes are compared at equal volume in the object's
frame, and the object itself is never moved or rescaled.** The rotation maps the
example's principal axes on the object's, ``R = A_o G A_eᵀ``. G is the identity
unless the frame is ambiguous (see above); then a small set of candidate G
(proper sign flips of ambiguous axes; 12 rotations about the distinct axis of a
degenerate plane, with its flip if ambiguous; the 24 cube rotations for an
isotropic shape) is scored against ``reference_points`` by the symmetric RMS
nearest-neighbour distance (``cKDTree``), and the smallest wins. With degenerate
moments each candidate is first refined by rigid, rotation-only ICP about the
common centre of mass (on deterministic subsamples of at most ``ICP_SAMPLES``
points; the winner is then refined on all points). With well-defined axes only
signs are chosen, unrefined, so that a copy of the object lands exactly on it.
Candidates within ``TIE_RTOL`` times the object's RMS radius of the best one are
geometrically equivalent (a symmetric shape); among those, the rotation of
smallest angle is taken, so **an example keeps its own orientation whenever its
geometry cannot tell** (a remeshed copy in place stays in place). The procedure is
deterministic.
"""

from __future__ import annotations

import itertools
import logging
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh, signed_volumes

log = logging.getLogger(__name__)

#: relative gap of principal second moments below which they count as degenerate
DEGENERACY_RTOL = 1e-2
#: |μ₃| ≤ SIGN_RTOL · V σ³ makes an axis sign ambiguous
SIGN_RTOL = 1e-2
#: candidates whose ICP RMS distance is within TIE_RTOL · (RMS radius) of the best tie
TIE_RTOL = 1e-2
#: ICP stops when the rotation changes by less than this angle (rad)
ICP_ANGLE_TOL = 1e-10
#: the same while scoring candidates (only their ranking matters)
CANDIDATE_ANGLE_TOL = 1e-5
#: at most this many ICP iterations per candidate
ICP_MAX_ITERATIONS = 60
#: candidate rotations are refined on at most this many points of each set
ICP_SAMPLES = 1000
#: start angles (rad) inside a 2-fold degenerate plane
_PLANAR_STARTS = np.arange(12) * (np.pi / 6.0)


@dataclass(frozen=True)
class BodyFrame:
    """The principal frame of a solid with uniform density.

    Attributes:
        origin: (3,) centre of mass in metres.
        axes: (3, 3) principal axes as columns, right-handed, ordered by
            decreasing second moment, signs by the module's sign rule.
        volume: volume in m³.
        second_moments: (3,) ``aₖᵀ S aₖ`` in m⁵, decreasing.
        third_moments: (3,) ``μ₃ₖ`` in m⁶ along each axis.
        ambiguous_signs: (3,) bool, axis sign not fixed by the third moment.
        degenerate: (3,) int cluster label of each axis (equal labels mean
            degenerate principal moments).
    """

    origin: np.ndarray
    axes: np.ndarray
    volume: float
    second_moments: np.ndarray
    third_moments: np.ndarray
    ambiguous_signs: np.ndarray
    degenerate: np.ndarray

    @property
    def inertia(self) -> np.ndarray:
        """(3, 3) inertia tensor per unit density about the centre of mass (m⁵)."""
        S = (self.axes * self.second_moments) @ self.axes.T
        return np.trace(S) * np.eye(3) - S

    @property
    def ambiguous(self) -> bool:
        """True when the axes are not fixed by the moments alone."""
        return bool(self.ambiguous_signs.any() or np.unique(self.degenerate).size < 3)

    def to_frame(self, points: np.ndarray) -> np.ndarray:
        """World points (n, 3) -> frame coordinates (n, 3): ``Aᵀ (x − c)``."""
        return (np.asarray(points, dtype=float) - self.origin) @ self.axes

    def from_frame(self, coordinates: np.ndarray) -> np.ndarray:
        """Frame coordinates (n, 3) -> world points (n, 3): ``A y + c``."""
        return np.asarray(coordinates, dtype=float) @ self.axes.T + self.origin


def volume_moments(points: np.ndarray, tets: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Exact volume (m³), first moment ``∫x`` (3,) (m⁴) and ``∫x xᵀ`` (3, 3) (m⁵).

    Uses ``∫_T x xᵀ = V/20 (Σ vᵢvᵢᵀ + (Σvᵢ)(Σvᵢ)ᵀ)`` for a linear tetrahedron.
    """
    p = np.asarray(points, dtype=float)[np.asarray(tets)]
    vol = np.abs(signed_volumes(np.asarray(points, dtype=float), np.asarray(tets)))
    total = float(vol.sum())
    vsum = p.sum(axis=1)
    first = (vol[:, None] * vsum).sum(axis=0) / 4.0
    second = np.einsum("t,tki,tkj->ij", vol, p, p) + np.einsum("t,ti,tj->ij", vol, vsum, vsum)
    return total, first, second / 20.0


def _third_moments(points: np.ndarray, tets: np.ndarray, origin, axes) -> np.ndarray:
    """(3,) ``∫ ((x − c)·aₖ)³ dV``, exact: ``V/20 h₃(f₁..f₄)`` per tetrahedron."""
    vol = np.abs(signed_volumes(points, tets))
    f = ((points - origin) @ axes)[tets]  # (t, 4, 3) values at the vertices
    p1, p2, p3 = f.sum(axis=1), (f**2).sum(axis=1), (f**3).sum(axis=1)
    h3 = (p1**3 + 3.0 * p1 * p2 + 2.0 * p3) / 6.0
    return (vol[:, None] * h3).sum(axis=0) / 20.0


def body_frame(mesh: TetMesh) -> BodyFrame:
    """The principal frame of ``mesh`` (uniform density), exact for linear tets.

    Raises:
        LbshapeError: a mesh without volume.
    """
    return frame_of(mesh.points, mesh.tets)


def frame_of(points: np.ndarray, tets: np.ndarray) -> BodyFrame:
    """:func:`body_frame` for raw arrays ``points (n, 3)``, ``tets (t, 4)``."""
    points = np.asarray(points, dtype=float)
    tets = np.asarray(tets, dtype=np.int64)
    volume, first, second = volume_moments(points, tets)
    if not volume > 0.0:
        raise LbshapeError("the shape has zero volume; it has no body frame")
    origin = first / volume
    S = second - volume * np.outer(origin, origin)
    S = 0.5 * (S + S.T)
    values, vectors = np.linalg.eigh(S)
    values, vectors = values[::-1], vectors[:, ::-1]
    third = _third_moments(points, tets, origin, vectors)
    sigma = np.sqrt(np.maximum(values, 0.0) / volume)
    skewness = np.abs(third) / np.maximum(volume * sigma**3, 1e-300)
    ambiguous = skewness <= SIGN_RTOL
    vectors = vectors * np.where(third < 0.0, -1.0, 1.0)
    if np.linalg.det(vectors) < 0.0:
        # flip the last ambiguous axis, else the least skewed one
        k = int(np.flatnonzero(ambiguous)[-1]) if ambiguous.any() else int(np.argmin(skewness))
        vectors[:, k] = -vectors[:, k]
        third[k] = -third[k]
    return BodyFrame(origin, vectors, volume, values, third, ambiguous, _clusters(values))


def _clusters(values: np.ndarray) -> np.ndarray:
    """Labels (3,) of decreasing ``values``: neighbours within DEGENERACY_RTOL share one."""
    labels = np.zeros(3, dtype=np.int64)
    for k in (1, 2):
        close = values[k - 1] - values[k] <= DEGENERACY_RTOL * values[k - 1]
        labels[k] = labels[k - 1] if close else labels[k - 1] + 1
    return labels


@dataclass(frozen=True)
class AlignedShape:
    """An example moved into the object's frame: ``x' = scale · R x + translation``.

    Attributes:
        points: (n, 3) aligned vertex positions in metres.
        scale: uniform scale factor (object volume / example volume)^(1/3).
        rotation: (3, 3) proper rotation R.
        translation: (3,) translation in metres.
        frame: the example's own :class:`BodyFrame` before alignment.
        icp_rms: RMS symmetric nearest-neighbour distance to the reference points
            after refinement (m), or ``None`` when no ICP ran.
        candidates: number of candidate rotations tried (1 when unambiguous).
    """

    points: np.ndarray
    scale: float
    rotation: np.ndarray
    translation: np.ndarray
    frame: BodyFrame
    icp_rms: float | None
    candidates: int

    def apply(self, points: np.ndarray) -> np.ndarray:
        """The same similarity transform applied to other points (n, 3), e.g. poses."""
        return self.scale * np.asarray(points, dtype=float) @ self.rotation.T + self.translation


def align_to_object(
    example_points: np.ndarray,
    example_tets: np.ndarray,
    object_frame: BodyFrame,
    *,
    reference_points: np.ndarray | None = None,
) -> AlignedShape:
    """Move an example into the object's frame at the object's volume.

    Args:
        example_points: (n, 3) example vertex positions in metres.
        example_tets: (t, 4) example tetrahedra.
        object_frame: :func:`body_frame` of the object's rest mesh.
        reference_points: (p, 3) the object's rest points, used to resolve an
            ambiguous frame by ICP; without them an ambiguous frame is resolved by
            the smallest-rotation rule alone (and a warning is logged).

    Returns:
        :class:`AlignedShape` (see the module docstring for the convention).
    """
    example_points = np.asarray(example_points, dtype=float)
    frame = frame_of(example_points, example_tets)
    scale = float(np.cbrt(object_frame.volume / frame.volume))
    centred = scale * (example_points - frame.origin)
    candidates = _candidate_rotations(frame, object_frame)
    ambiguous = len(candidates) > 1
    rms = None
    if ambiguous and reference_points is None:
        log.warning("example frame is ambiguous (symmetric shape) and no reference points "
                    "were given; keeping the smallest rotation of %d candidates",
                    len(candidates))
        rotation = min(candidates, key=_rotation_angle)
    elif ambiguous:
        reference = np.asarray(reference_points, dtype=float) - object_frame.origin
        refine = not (frame.degenerate.max() == 2 and object_frame.degenerate.max() == 2)
        if refine:  # candidates refined on subsamples, the winner on all points
            src, dst = _subsample(centred), _subsample(reference)
            refined = [_icp_rotation(src, dst, R, tol=CANDIDATE_ANGLE_TOL) for R in candidates]
        else:  # principal axes are well defined: only choose among the sign flips
            refined = [(R, _rms_distance(centred @ R.T, reference)) for R in candidates]
        costs = np.array([cost for _, cost in refined])
        radius = float(np.sqrt(np.mean(np.sum(reference**2, axis=1))))
        ties = np.flatnonzero(costs <= costs.min() + TIE_RTOL * radius)
        best = min(ties, key=lambda i: _rotation_angle(refined[i][0]))
        rotation, rms = refined[best][0], float(costs[best])
        if refine:
            rotation, rms = _icp_rotation(centred, reference, rotation)
        log.debug("frame alignment: %d candidates, RMS %.3e m (best %.3e m), %d ties",
                  len(candidates), rms, costs.min(), ties.size)
    else:
        rotation = candidates[0]
    translation = object_frame.origin - scale * rotation @ frame.origin
    return AlignedShape(
        points=centred @ rotation.T + object_frame.origin,
        scale=scale,
        rotation=rotation,
        translation=translation,
        frame=frame,
        icp_rms=rms,
        candidates=len(candidates),
    )


def _candidate_rotations(example: BodyFrame, obj: BodyFrame) -> list[np.ndarray]:
    """Rotations ``A_o G A_eᵀ`` for the admissible G (see the module docstring)."""
    # the more degenerate of the two frames decides the candidate set
    frame = example if np.unique(example.degenerate).size <= np.unique(obj.degenerate).size \
        else obj
    n_clusters = np.unique(frame.degenerate).size
    if n_clusters == 1:  # isotropic: the 24 rotations of the cube
        gs = _cube_rotations()
    elif n_clusters == 2:  # one degenerate plane: rotations about the distinct axis
        single = 0 if frame.degenerate[1] == frame.degenerate[2] else 2
        axis = np.zeros(3)
        axis[single] = 1.0
        gs = [Rotation.from_rotvec(a * axis).as_matrix() for a in _PLANAR_STARTS]
        if example.ambiguous_signs[single] or obj.ambiguous_signs[single]:
            # reverse the distinct axis and one in-plane axis (a proper rotation)
            flip = np.ones(3)
            flip[[single, 1]] = -1.0
            gs = gs + [g @ np.diag(flip) for g in gs]
    else:
        ambiguous = example.ambiguous_signs | obj.ambiguous_signs
        gs = []
        for signs in itertools.product((1.0, -1.0), repeat=3):
            signs = np.array(signs)
            if np.prod(signs) < 0 or (signs[~ambiguous] < 0).any():
                continue
            gs.append(np.diag(signs))
    return [obj.axes @ g @ example.axes.T for g in gs]


def _cube_rotations() -> list[np.ndarray]:
    """The 24 proper signed permutation matrices."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            g = np.zeros((3, 3))
            g[np.arange(3), perm] = signs
            if np.linalg.det(g) > 0:
                out.append(g)
    return out


def _rotation_angle(R: np.ndarray) -> float:
    return float(np.arccos(np.clip(0.5 * (np.trace(R) - 1.0), -1.0, 1.0)))


def _icp_rotation(source: np.ndarray, target: np.ndarray, start: np.ndarray, *,
                  tol: float = ICP_ANGLE_TOL):
    """Rotation-only ICP of centred ``source`` (n,3) onto centred ``target`` (p,3).

    Matches are symmetric (each source point to its nearest target point and each
    target point to its nearest rotated source point); the rotation is the Kabsch
    solution about the origin. Returns (R (3, 3), RMS distance in m).
    """
    target_tree = cKDTree(target)
    R = start
    for _ in range(ICP_MAX_ITERATIONS):
        moved = source @ R.T
        _, to_target = target_tree.query(moved)
        _, to_source = cKDTree(moved).query(target)
        # pairs (source point, target point)
        src = np.concatenate([source, source[to_source]])
        dst = np.concatenate([target[to_target], target])
        H = src.T @ dst
        u, _, vt = np.linalg.svd(H)
        d = np.sign(np.linalg.det(vt.T @ u.T))
        R_new = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
        change = _rotation_angle(R_new @ R.T)
        R = R_new
        if change < tol:
            break
    return R, _rms_distance(source @ R.T, target)


def _subsample(points: np.ndarray) -> np.ndarray:
    """Every k-th point, k chosen so that at most ICP_SAMPLES remain (deterministic)."""
    step = -(-points.shape[0] // ICP_SAMPLES)
    return points[::step]


def _rms_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Symmetric RMS nearest-neighbour distance between point sets a (n,3), b (p,3)."""
    d1, _ = cKDTree(b).query(a)
    d2, _ = cKDTree(a).query(b)
    return float(np.sqrt((np.sum(d1**2) + np.sum(d2**2)) / (d1.size + d2.size)))
