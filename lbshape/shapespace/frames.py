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
nearest-neighbour distance (``cKDTree``), and the smallest wins. With well-defined
axes only signs are chosen, unrefined, so that a copy of the object lands exactly
on it.

**Degenerate moments.** Inside a degenerate eigenspace the axes from ``eigh`` are
an arbitrary basis (another LAPACK returns another one), so candidates built on
them alone may all start in a wrong basin of ICP. The search therefore also scores
start rotations that do not depend on that basis: the identity (the example as
given); *anchor* rotations, the Kabsch rotations taking two example vertices far
from the centre with rarely shared radii onto object vertices at matching radius
and mutual distance (:func:`_anchor_rotations`; these contain the exact rotation
of a rotated copy); and ``GLOBAL_ROTATIONS`` rotations spread deterministically over
SO(3). All starts are scored cheaply on subsamples of at most ``SCORE_SAMPLES``
points; the ``REFINED_STARTS`` best that are at least ``START_SEPARATION`` apart,
and the identity, are refined by rigid, rotation-only ICP about the common centre
of mass (on subsamples of at most ``ICP_SAMPLES`` points; the winner is then
refined on all points). Candidates within ``TIE_RTOL`` times the object's RMS
radius of the best one are geometrically equivalent (a symmetric shape); among
those, the rotation of smallest angle is taken, so **an example keeps its own
orientation whenever its geometry cannot tell** (a remeshed copy in place stays in
place). Rotated and scaled copies of cubes, balls, square-section boxes and
cylinders land on the original to round-off. The procedure is deterministic.

**Residual.** With ``reference_points`` the alignment reports ``icp_rms``, the
symmetric RMS nearest-neighbour distance between the aligned example's vertices and
the object's (m), and ``relative_rms = icp_rms / R`` with R the RMS radius of the
object's vertices about its centre of mass. An alignment with ``relative_rms`` above
``MAX_RELATIVE_RMS = 0.2`` is refused with a one-line :class:`LbshapeError` naming
the example (``name``, or the caller's prefix: the precompute pipeline's
``example k (shape:pose)``). The measure is vertex based, so it includes the
resolution mismatch of the two meshes as well as their difference in shape.
Measured (default sizes): legitimate pairs of different topology or resolution
0.121 (demo-bar vs demo-cylinder), 0.086 (bar-cuboid vs bar-cylinder), 0.075
(structured 4×4×16 bar vs gmsh cylinder), 0.131 (structured 5×5×5 cube vs gmsh
cube, h = 0.15 m), 0.036 / 0.073 / 0.093 (cross, car, teddy vs their finer
examples); refused: a cube for a bar 0.26–0.31 (demo-bar vs cube 0.264), a
0.2×0.4×0.5 m box for the 0.2×0.2×1 m bar 0.255, and an exact copy of a cube
left in a wrong ICP minimum 0.23 (the failure the anchor and global starts remove).
"""

from __future__ import annotations

import functools
import itertools
import logging
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation
from scipy.stats import qmc

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
#: refuse an alignment whose RMS residual exceeds this fraction of the object's RMS radius
MAX_RELATIVE_RMS = 0.2
#: rotations of the deterministic global search over SO(3)
GLOBAL_ROTATIONS = 512
#: start rotations are scored on at most this many points of each set
SCORE_SAMPLES = 256
#: the best-scoring starts refined by ICP (besides the identity)
REFINED_STARTS = 6
#: a start within this angle (rad) of a better refined one is skipped
START_SEPARATION = 0.2
#: target vertices tried as the match of each anchor vertex
ANCHOR_MATCHES = 12
#: anchors lie at least this fraction of the largest radius from the centre
ANCHOR_MIN_RADIUS = 0.5
#: the two anchors' directions make an angle with at least this sine
ANCHOR_MIN_SINE = 0.5
#: radii within this fraction of the largest one count as shared when choosing anchors
ANCHOR_RTOL = 1e-3
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
        icp_rms: symmetric RMS nearest-neighbour distance between the aligned
            points and the reference points (m), ICP-refined when the principal
            moments are degenerate; ``None`` without reference points.
        relative_rms: ``icp_rms`` divided by the reference points' RMS radius
            about the object's centre of mass (dimensionless), the residual
            checked against :data:`MAX_RELATIVE_RMS`; ``None`` without reference
            points.
        candidates: number of principal-frame candidates G (1 when unambiguous).
        starts: number of start rotations scored (the frame candidates, plus the
            identity, anchor and global-search rotations when moments are
            degenerate).
    """

    points: np.ndarray
    scale: float
    rotation: np.ndarray
    translation: np.ndarray
    frame: BodyFrame
    icp_rms: float | None
    relative_rms: float | None
    candidates: int
    starts: int

    def apply(self, points: np.ndarray) -> np.ndarray:
        """The same similarity transform applied to other points (n, 3), e.g. poses."""
        return self.scale * np.asarray(points, dtype=float) @ self.rotation.T + self.translation


def align_to_object(
    example_points: np.ndarray,
    example_tets: np.ndarray,
    object_frame: BodyFrame,
    *,
    reference_points: np.ndarray | None = None,
    name: str | None = None,
    max_relative_rms: float | None = MAX_RELATIVE_RMS,
) -> AlignedShape:
    """Move an example into the object's frame at the object's volume.

    Args:
        example_points: (n, 3) example vertex positions in metres.
        example_tets: (t, 4) example tetrahedra.
        object_frame: :func:`body_frame` of the object's rest mesh.
        reference_points: (p, 3) the object's rest points in metres, used to
            resolve an ambiguous frame and to measure the residual; without them
            an ambiguous frame is resolved by the smallest-rotation rule alone (a
            warning is logged) and no residual is checked.
        name: how error messages name the example, e.g. ``"example 2 (cube)"``.
        max_relative_rms: refuse an alignment whose relative RMS residual exceeds
            this (``None``: report it, never refuse).

    Returns:
        :class:`AlignedShape` (see the module docstring for the convention).

    Raises:
        LbshapeError: the relative RMS residual exceeds ``max_relative_rms``.
    """
    example_points = np.asarray(example_points, dtype=float)
    frame = frame_of(example_points, example_tets)
    scale = float(np.cbrt(object_frame.volume / frame.volume))
    centred = scale * (example_points - frame.origin)
    candidates = _candidate_rotations(frame, object_frame)
    starts = len(candidates)
    rms = relative = None
    if reference_points is None:
        rotation = candidates[0]
        if len(candidates) > 1:
            log.warning("example frame is ambiguous (symmetric shape) and no reference points "
                        "were given; keeping the smallest rotation of %d candidates",
                        len(candidates))
            rotation = min(candidates, key=_rotation_angle)
    else:
        reference = np.asarray(reference_points, dtype=float) - object_frame.origin
        radius = float(np.sqrt(np.mean(np.sum(reference**2, axis=1))))
        if frame.degenerate.max() < 2 or object_frame.degenerate.max() < 2:
            rotation, rms, starts = _search_rotation(centred, reference, candidates, radius)
        else:  # principal axes are well defined: only choose among the sign flips
            costs = [_rms_distance(centred @ R.T, reference) for R in candidates]
            best = _smallest_of_ties(candidates, costs, radius)
            rotation, rms = candidates[best], float(costs[best])
        relative = rms / radius
        log.debug("frame alignment: %d starts, RMS %.3e m, relative %.3e",
                  starts, rms, relative)
        if max_relative_rms is not None and not relative <= max_relative_rms:
            prefix = f"{name}: " if name else ""
            raise LbshapeError(
                f"{prefix}example does not correspond to the object: frame alignment residual "
                f"{relative:.3f} exceeds {max_relative_rms:g} (RMS vertex distance {rms:.3g} m, "
                f"object RMS radius {radius:.3g} m)"
            )
    translation = object_frame.origin - scale * rotation @ frame.origin
    return AlignedShape(
        points=centred @ rotation.T + object_frame.origin,
        scale=scale,
        rotation=rotation,
        translation=translation,
        frame=frame,
        icp_rms=rms,
        relative_rms=relative,
        candidates=len(candidates),
        starts=starts,
    )


def _search_rotation(source: np.ndarray, target: np.ndarray, candidates: list[np.ndarray],
                     radius: float) -> tuple[np.ndarray, float, int]:
    """The rotation of centred ``source`` (n, 3) onto centred ``target`` (p, 3) when
    principal moments are degenerate: score all starts, refine the best few by ICP.

    Returns (R (3, 3), RMS distance in m, number of starts scored).
    """
    identity = np.eye(3)
    starts = np.concatenate([np.asarray(candidates), identity[None],
                             _anchor_rotations(source, target), _global_rotations()])
    scores = _scores(source, target, starts)
    chosen: list[int] = []
    for i in np.argsort(scores, kind="stable"):
        if len(chosen) == REFINED_STARTS:
            break
        if all(_rotation_angle(starts[i] @ starts[j].T) > START_SEPARATION for j in chosen):
            chosen.append(int(i))
    if len(candidates) not in chosen:  # the identity: the example's own orientation
        chosen.append(len(candidates))
    src, dst = _subsample(source, ICP_SAMPLES), _subsample(target, ICP_SAMPLES)
    refined = [_icp_rotation(src, dst, starts[i], tol=CANDIDATE_ANGLE_TOL) for i in chosen]
    costs = [cost for _, cost in refined]
    best = _smallest_of_ties([R for R, _ in refined], costs, radius)
    rotation, rms = _icp_rotation(source, target, refined[best][0])
    log.debug("rotation search: %d starts scored, %d refined, best start %.3e m",
              len(starts), len(chosen), min(costs))
    return rotation, rms, len(starts)


def _smallest_of_ties(rotations, costs, radius: float) -> int:
    """Index of the smallest rotation among those within TIE_RTOL · radius of the best cost."""
    costs = np.asarray(costs, dtype=float)
    ties = np.flatnonzero(costs <= costs.min() + TIE_RTOL * radius)
    return int(min(ties, key=lambda i: _rotation_angle(rotations[i])))


def _scores(source: np.ndarray, target: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """(k,) symmetric RMS nearest-neighbour distances (m) of subsamples of at most
    SCORE_SAMPLES points of each set, for rotations (k, 3, 3) of ``source``.

    Distances are rotation invariant, so the target subsample is rotated back onto
    the unmoved source and both k-d trees are built once.
    """
    src, dst = _subsample(source, SCORE_SAMPLES), _subsample(target, SCORE_SAMPLES)
    k = rotations.shape[0]
    d1, _ = cKDTree(target).query(np.einsum("kij,nj->kni", rotations, src).reshape(-1, 3))
    d2, _ = cKDTree(source).query(np.einsum("kji,nj->kni", rotations, dst).reshape(-1, 3))
    total = (d1.reshape(k, -1) ** 2).sum(axis=1) + (d2.reshape(k, -1) ** 2).sum(axis=1)
    return np.sqrt(total / (src.shape[0] + dst.shape[0]))


def _anchor_rotations(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(k, 3, 3) rotations taking two anchor vertices of centred ``source`` (n, 3) onto
    pairs of vertices of centred ``target`` (p, 3) at matching radius and separation.

    The first anchor a₁ is the vertex at a radius of at least ANCHOR_MIN_RADIUS
    times the largest whose radius is shared by the fewest vertices (within
    ANCHOR_RTOL of the largest radius; the farther wins a tie); the second a₂ is
    chosen the same way among the vertices at an angle to a₁ with sine at least
    ANCHOR_MIN_SINE (the larger ``|a₁ × a₂|`` wins a tie). Each of the
    ANCHOR_MATCHES target vertices b₁ closest to ``|a₁|`` in radius is paired with
    the ANCHOR_MATCHES vertices b₂ closest to ``(|a₂|, |a₂ − a₁|)`` in radius and
    distance to b₁; the rotation is the Kabsch solution of ``(a₁, a₂) → (b₁, b₂)``.
    Nothing here depends on an eigensolver; an exact copy contributes its exact
    rotation whenever its anchors' radii are shared by at most ANCHOR_MATCHES vertices.
    """
    rs, rt = np.linalg.norm(source, axis=1), np.linalg.norm(target, axis=1)
    order = np.sort(rs)
    tol = ANCHOR_RTOL * order[-1]
    shared = np.searchsorted(order, rs + tol, side="right") - np.searchsorted(order, rs - tol)
    far = rs >= ANCHOR_MIN_RADIUS * order[-1]
    first = _fewest_shared(far, shared, -rs)
    a1 = source[first]
    spread = np.linalg.norm(np.cross(a1, source), axis=1)  # |a₁ × a| = |a₁| |a| sin θ
    apart = far & (spread >= ANCHOR_MIN_SINE * rs[first] * rs)
    if not apart.any():  # a needle: no vertex far from a₁'s line; take the farthest from it
        apart = spread >= spread.max()
    second = _fewest_shared(apart, shared, -spread)
    a2 = source[second]
    k = min(ANCHOR_MATCHES, target.shape[0])
    anchors = np.array([a1, a2])
    rotations = []
    for j in np.argsort(np.abs(rt - rs[first]), kind="stable")[:k]:
        mismatch = ((rt - rs[second]) ** 2
                    + (np.linalg.norm(target - target[j], axis=1) - np.linalg.norm(a2 - a1)) ** 2)
        mismatch[j] = np.inf
        for i in np.argsort(mismatch, kind="stable")[:k]:
            rotations.append(_kabsch(anchors, target[[j, i]]))
    return np.array(rotations).reshape(-1, 3, 3)


def _fewest_shared(mask: np.ndarray, shared: np.ndarray, tiebreak: np.ndarray) -> int:
    """Index among ``mask`` of the smallest ``shared``, then smallest ``tiebreak``, then index."""
    idx = np.flatnonzero(mask)
    return int(idx[np.lexsort((idx, tiebreak[idx], shared[idx]))[0]])


def _kabsch(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The proper rotation R minimising ``Σ |R sᵢ − tᵢ|²`` about the origin, (k, 3) pairs."""
    u, _, vt = np.linalg.svd(source.T @ target)
    d = np.sign(np.linalg.det(vt.T @ u.T))  # ±1: u and vt are orthogonal
    return vt.T @ np.diag([1.0, 1.0, d]) @ u.T


@functools.cache
def _global_rotations() -> np.ndarray:
    """(GLOBAL_ROTATIONS, 3, 3) rotations spread over SO(3): an unscrambled Halton
    sequence through Shoemake's uniform map to unit quaternions (deterministic)."""
    u = qmc.Halton(d=3, scramble=False).random(GLOBAL_ROTATIONS + 1)[1:]
    a, b = np.sqrt(1.0 - u[:, 0]), np.sqrt(u[:, 0])
    quat = np.column_stack([a * np.sin(2 * np.pi * u[:, 1]), a * np.cos(2 * np.pi * u[:, 1]),
                            b * np.sin(2 * np.pi * u[:, 2]), b * np.cos(2 * np.pi * u[:, 2])])
    return Rotation.from_quat(quat).as_matrix()


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
        R_new = _kabsch(src, dst)
        change = _rotation_angle(R_new @ R.T)
        R = R_new
        if change < tol:
            break
    return R, _rms_distance(source @ R.T, target)


def _subsample(points: np.ndarray, count: int) -> np.ndarray:
    """Every k-th point of (n, 3), k chosen so that at most ``count`` remain (deterministic)."""
    step = -(-points.shape[0] // count)
    return points[::step]


def _rms_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Symmetric RMS nearest-neighbour distance between point sets a (n,3), b (p,3)."""
    d1, _ = cKDTree(b).query(a)
    d2, _ = cKDTree(a).query(b)
    return float(np.sqrt((np.sum(d1**2) + np.sum(d2**2)) / (d1.size + d2.size)))
