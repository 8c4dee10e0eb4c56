"""Analytic example poses: vertex maps ``(n, 3) -> (n, 3)`` applied to any bar-like mesh.

Every pose acts along an ``axis`` (``"x"``, ``"y"`` or ``"z"``, default ``"z"``);
the bar's extent is taken from the points themselves: its length ``L`` is the
extent along the axis and its centreline passes through the centre of the
bounding box of the cross-section. The **anchor** end (``"min"`` by default, the
end with the smallest axial coordinate) is left exactly in place; the pose grows
towards the other end.

* :func:`twist` rotates each cross-section about the centreline by ``θ(t)`` with
  ``t ∈ [0, 1]`` the normalised distance from the anchor: ``θ = angle·t``
  (``profile="linear"``) or ``θ = angle·(3t² − 2t³)`` (``"smooth"``). The map
  preserves volume exactly; fibres at radius r stretch by ``√(1 + (r θ')²)``.
* :func:`arc` and :func:`s_bend` bend the centreline in the (axis, ``direction``)
  plane. The centreline is parametrised by arc length s with tangent angle ψ(s):
  ``C(s) = ∫₀ˢ (cos ψ, sin ψ) ds``, so it is mapped **isometrically**, and each
  cross-section moves rigidly with the local frame (tangent, normal, binormal).
  The Jacobian determinant is ``1 − d ψ'(s)`` (d the lateral offset towards
  ``direction``), so the map is locally invertible while ``|d κ| < 1``.

  - arc: constant curvature, ψ = angle·s/L (total turning ``angle`` in rad,
    positive bends towards ``+direction``).
  - s-bend: ψ = ψ_max sin(π s/L): tangents are axial at both ends and the
    curvature changes sign in the middle (an S). ``amplitude`` is the lateral
    offset of the far end in metres; ψ_max is solved for it
    (``|amplitude| ≤ 0.7 L``, the offset reached at ψ_max ≈ 1.36 rad).

:data:`POSES` is the one registry of poses (scenes validate against it, with
:data:`POSE_PARAMETERS` and :data:`POSE_CHOICES`); :func:`apply_pose` validates names
and parameters against it and rejects a pose that inverts tetrahedra of the mesh.
:func:`pose_parts` poses parts of a mesh each on its own (a character's limbs), the
rest of the mesh following harmonically.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Mapping, Sequence
from types import MappingProxyType

import numpy as np
from scipy.optimize import brentq
from scipy.sparse import coo_matrix, diags
from scipy.sparse.csgraph import connected_components
from scipy.sparse.linalg import splu

from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh, signed_volumes

_AXES = {"x": 0, "y": 1, "z": 2}
_ANCHORS = ("min", "max")
_PROFILES = ("linear", "smooth")
#: samples of the numerically integrated centreline of :func:`s_bend`
_CENTRELINE_SAMPLES = 8193
#: largest accepted |amplitude| / L of :func:`s_bend`
S_BEND_MAX_RATIO = 0.7


def twist(
    points: np.ndarray,
    *,
    angle: float,
    axis: str = "z",
    profile: str = "linear",
    anchor: str = "min",
) -> np.ndarray:
    """Twist a bar about its centreline.

    Args:
        points: (n, 3) vertex positions in metres.
        angle: twist of the far end relative to the anchor end, in rad
            (right-handed about ``+axis``).
        axis: the bar's axis, ``"x"``, ``"y"`` or ``"z"``.
        profile: ``"linear"`` (θ ∝ t) or ``"smooth"`` (θ ∝ 3t² − 2t³).
        anchor: the end left in place, ``"min"`` or ``"max"``.

    Returns:
        (n, 3) twisted positions.
    """
    points = _as_points(points)
    k = _axis_index(axis)
    _choice("profile", profile, _PROFILES)
    t, _ = _axial_parameter(points, k, anchor)
    if profile == "smooth":
        t = t * t * (3.0 - 2.0 * t)
    theta = float(angle) * t
    i, j = (k + 1) % 3, (k + 2) % 3  # (i, j, k) is a cyclic, right-handed triple
    centre = _cross_section_centre(points, k)
    a, b = points[:, i] - centre[i], points[:, j] - centre[j]
    cos, sin = np.cos(theta), np.sin(theta)
    out = points.copy()
    out[:, i] = centre[i] + cos * a - sin * b
    out[:, j] = centre[j] + sin * a + cos * b
    return out


def arc(
    points: np.ndarray,
    *,
    angle: float,
    direction: str = "x",
    axis: str = "z",
    anchor: str = "min",
) -> np.ndarray:
    """Bend a bar into a circular arc of total turning ``angle`` (rad).

    Args:
        points: (n, 3) vertex positions in metres.
        angle: total turning angle of the centreline in rad; positive bends the
            far end towards ``+direction``.
        direction: the lateral axis of the bend, different from ``axis``.
        axis: the bar's axis.
        anchor: the end left in place, ``"min"`` or ``"max"``.

    Returns:
        (n, 3) bent positions; the centreline keeps its length.
    """
    angle = float(angle)

    def psi(s, length):
        return angle * s / length

    return _bend(points, psi, direction=direction, axis=axis, anchor=anchor)


def s_bend(
    points: np.ndarray,
    *,
    amplitude: float,
    direction: str = "x",
    axis: str = "z",
    anchor: str = "min",
) -> np.ndarray:
    """Bend a bar into an S: the far end is offset laterally by ``amplitude``.

    ``direction="x"`` or ``"y"`` chooses a horizontal or vertical S-bend of a
    bar along z.

    Args:
        points: (n, 3) vertex positions in metres.
        amplitude: lateral offset of the far end along ``direction``, in metres,
            with ``|amplitude| ≤ 0.7 L``.
        direction: the lateral axis of the bend, different from ``axis``.
        axis: the bar's axis.
        anchor: the end left in place, ``"min"`` or ``"max"``.

    Returns:
        (n, 3) bent positions; the centreline keeps its length.
    """
    points = _as_points(points)
    length = _axial_parameter(points, _axis_index(axis), anchor)[1]
    psi_max = _s_bend_psi_max(float(amplitude), length)

    def psi(s, length):
        return psi_max * np.sin(np.pi * s / length)

    return _bend(points, psi, direction=direction, axis=axis, anchor=anchor)


def _s_bend_psi_max(amplitude: float, length: float) -> float:
    """ψ_max with ``L ∫₀¹ sin(ψ_max sin(πu)) du = amplitude``."""
    if not math.isfinite(amplitude) or abs(amplitude) > S_BEND_MAX_RATIO * length:
        raise LbshapeError(
            f"s-bend amplitude {amplitude!r} m is out of range: |amplitude| must be at most "
            f"{S_BEND_MAX_RATIO} x the bar length ({S_BEND_MAX_RATIO * length:.4g} m)"
        )
    if amplitude == 0.0:
        return 0.0
    u = (np.arange(2048) + 0.5) / 2048.0  # midpoint rule: spectrally accurate here

    def offset(psi_max):
        return length * np.mean(np.sin(psi_max * np.sin(np.pi * u))) - abs(amplitude)

    return math.copysign(brentq(offset, 0.0, 1.5, xtol=1e-14), amplitude)


def _bend(points, psi: Callable, *, direction: str, axis: str, anchor: str) -> np.ndarray:
    """Move cross-sections rigidly along the centreline of tangent angle ψ(s)."""
    points = _as_points(points)
    k = _axis_index(axis)
    if direction not in _AXES:
        raise LbshapeError(f"direction must be one of {sorted(_AXES)}, got {direction!r}")
    d_index = _AXES[direction]
    if d_index == k:
        raise LbshapeError(f"bend direction {direction!r} must differ from the axis {axis!r}")
    t, length = _axial_parameter(points, k, anchor)
    sign = 1.0 if anchor == "min" else -1.0  # the axial unit vector points away from the anchor
    centre = _cross_section_centre(points, k)
    s = t * length
    d = points[:, d_index] - centre[d_index]

    grid = np.linspace(0.0, length, _CENTRELINE_SAMPLES)
    angles = psi(grid, length)
    h = grid[1] - grid[0]
    ca = np.concatenate([[0.0], np.cumsum(0.5 * h * (np.cos(angles[1:]) + np.cos(angles[:-1])))])
    cd = np.concatenate([[0.0], np.cumsum(0.5 * h * (np.sin(angles[1:]) + np.sin(angles[:-1])))])
    along, lateral = np.interp(s, grid, ca), np.interp(s, grid, cd)
    angle = psi(s, length)

    out = points.copy()
    anchor_coordinate = points[:, k].min() if anchor == "min" else points[:, k].max()
    out[:, k] = anchor_coordinate + sign * (along - d * np.sin(angle))
    out[:, d_index] = centre[d_index] + lateral + d * np.cos(angle)
    return out


#: pose name -> vertex map ``f(points, **params) -> points``
POSES: dict[str, Callable[..., np.ndarray]] = {"twist": twist, "s-bend": s_bend, "arc": arc}
#: string-valued pose parameters and their choices; every other parameter is a number
POSE_CHOICES: Mapping[str, tuple[str, ...]] = MappingProxyType({
    "axis": tuple(_AXES),
    "direction": tuple(_AXES),
    "anchor": _ANCHORS,
    "profile": _PROFILES,
})


def _keyword_parameters(pose: Callable[..., np.ndarray]) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(required, optional) keyword-only parameters of a vertex map, in signature order."""
    params = [p for p in inspect.signature(pose).parameters.values() if p.kind is p.KEYWORD_ONLY]
    required = tuple(p.name for p in params if p.default is p.empty)
    optional = tuple(p.name for p in params if p.default is not p.empty)
    return required, optional


#: pose name -> its keyword parameters, the required one first (from the signatures)
POSE_PARAMETERS: Mapping[str, tuple[str, ...]] = MappingProxyType(
    {name: sum(_keyword_parameters(pose), ()) for name, pose in POSES.items()}
)


def pose_parameters(name: str) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(required, optional) keyword parameters of pose ``name``."""
    return _keyword_parameters(_pose(name))


def apply_pose(mesh: TetMesh, name: str, **params) -> TetMesh:
    """The mesh posed by ``POSES[name](mesh.points, **params)``, same connectivity.

    Args:
        mesh: the rest mesh (positively oriented tets).
        name: a key of :data:`POSES`.
        **params: the pose's keyword parameters (see :func:`pose_parameters`).

    Raises:
        LbshapeError: unknown pose or parameter, missing or non-finite parameter,
            or a pose that inverts (or flattens) tetrahedra of this mesh.
    """
    _check_parameters(name, params)
    posed = POSES[name](mesh.points, **params)
    shown = ", ".join(f"{k}={v}" for k, v in params.items())
    _check_orientation(mesh, posed, f"pose {name!r} ({shown})")
    return mesh.with_points(posed)


def pose_parts(mesh: TetMesh, parts: Sequence[tuple[np.ndarray, str, Mapping]],
               held: np.ndarray | Sequence[int] = ()) -> TetMesh:
    """The mesh posed part by part (a character's limbs, say), the rest following smoothly.

    Each part's vertices move as ``POSES[name]`` maps the part's own points: the
    pose's bar is the part (its extent along the pose axis, its anchor end), as for
    a local example's part. The ``held`` vertices stay in place. Every other vertex
    moves by the discrete harmonic extension of those displacements: the graph
    Laplacian of the mesh's edges, weighted by 1 / edge length, is zero at it. A
    connected piece of the mesh without a part or a held vertex stays in place.

    Args:
        mesh: the rest mesh (positively oriented tets).
        parts: (vertices (k,) int, pose name, pose parameters) per part.
        held: (h,) int vertices kept at rest.

    Returns:
        The posed mesh, same connectivity.

    Raises:
        LbshapeError: a bad pose or parameter, parts that share vertices with each
            other or with ``held``, or a result that inverts (or flattens) tetrahedra.
    """
    n = mesh.n_vertices
    owner = np.full(n, -1, dtype=np.int64)
    owner[np.asarray(held, dtype=np.int64)] = len(parts)
    displacement = np.zeros((n, 3))
    for k, (vertices, name, params) in enumerate(parts):
        vertices = np.asarray(vertices, dtype=np.int64)
        taken = owner[vertices] >= 0
        if taken.any():
            other = owner[vertices[taken][0]]
            what = "the held vertices" if other == len(parts) else f"part {other}"
            raise LbshapeError(f"part {k} of the pose shares {int(taken.sum())} vertices "
                               f"with {what}; parts and held vertices must be disjoint")
        _check_parameters(name, params)
        points = mesh.points[vertices]
        displacement[vertices] = POSES[name](points, **params) - points
        owner[vertices] = k
    displacement = _harmonic_extension(mesh, displacement, known=owner >= 0)
    posed = mesh.points + displacement
    _check_orientation(mesh, posed, f"the pose of {len(parts)} parts")
    return mesh.with_points(posed)


def _harmonic_extension(mesh: TetMesh, values: np.ndarray, known: np.ndarray) -> np.ndarray:
    """(n, 3) ``values`` at the ``known`` vertices, harmonic (1 / length edge weights)
    at the others; pieces of the mesh without a known vertex keep their ``values``."""
    n = mesh.n_vertices
    edges = np.unique(np.sort(np.vstack([mesh.tets[:, [i, j]] for i in range(4)
                                         for j in range(i + 1, 4)]), axis=1), axis=0)
    weights = 1.0 / np.linalg.norm(mesh.points[edges[:, 0]] - mesh.points[edges[:, 1]], axis=1)
    adjacency = coo_matrix((np.concatenate([weights, weights]),
                            (np.concatenate([edges[:, 0], edges[:, 1]]),
                             np.concatenate([edges[:, 1], edges[:, 0]]))), shape=(n, n)).tocsr()
    _, piece = connected_components(adjacency, directed=False)
    known = known | ~np.isin(piece, piece[known])
    free = ~known
    if not free.any():
        return values
    laplacian = (diags(np.asarray(adjacency.sum(axis=1)).ravel()) - adjacency).tocsr()
    out = values.copy()
    out[free] = splu(laplacian[free][:, free].tocsc()).solve(
        -(laplacian[free][:, known] @ values[known]))
    return out


def _check_parameters(name: str, params: Mapping) -> None:
    """Raise LbshapeError unless ``params`` are valid keyword parameters of pose ``name``."""
    required, optional = pose_parameters(name)
    allowed = required + optional
    unknown = sorted(set(params) - set(allowed))
    if unknown:
        raise LbshapeError(
            f"pose {name!r} has no parameter(s) {', '.join(unknown)}; "
            f"valid: {', '.join(allowed)}"
        )
    missing = [p for p in required if p not in params]
    if missing:
        raise LbshapeError(f"pose {name!r} needs parameter(s) {', '.join(missing)}")
    for key, value in params.items():
        if key in POSE_CHOICES:
            if not isinstance(value, str):
                raise LbshapeError(f"pose {name!r}: {key} must be a string, got {value!r}")
        elif isinstance(value, bool) or not isinstance(value, int | float | np.number) \
                or not math.isfinite(float(value)):
            raise LbshapeError(f"pose {name!r}: {key} must be a finite number, got {value!r}")


def _check_orientation(mesh: TetMesh, posed: np.ndarray, what: str) -> None:
    """Raise LbshapeError if ``posed`` (n, 3) inverts or flattens tetrahedra of ``mesh``."""
    volumes = signed_volumes(posed, mesh.tets)
    rest = np.abs(signed_volumes(mesh.points, mesh.tets))
    inverted = volumes <= 1e-9 * rest
    if inverted.any():
        raise LbshapeError(
            f"{what} inverts {int(inverted.sum())} of {mesh.n_tets} "
            f"tetrahedra of this mesh; use gentler parameters or a finer mesh"
        )


def _pose(name: str) -> Callable[..., np.ndarray]:
    try:
        return POSES[name]
    except (KeyError, TypeError):
        raise LbshapeError(
            f"unknown pose {name!r}; valid poses: {', '.join(sorted(POSES))}"
        ) from None


def _as_points(points) -> np.ndarray:
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or points.shape[0] == 0:
        raise LbshapeError(f"points must be a non-empty (n, 3) array, got shape {points.shape}")
    return points


def _axis_index(axis) -> int:
    if axis not in _AXES:
        raise LbshapeError(f"axis must be one of {sorted(_AXES)}, got {axis!r}")
    return _AXES[axis]


def _choice(label: str, value, valid: tuple[str, ...]) -> None:
    if value not in valid:
        raise LbshapeError(f"{label} must be one of {', '.join(valid)}, got {value!r}")


def _axial_parameter(points: np.ndarray, k: int, anchor: str) -> tuple[np.ndarray, float]:
    """(t (n,) in [0, 1] from the anchor end, bar length L in metres)."""
    _choice("anchor", anchor, _ANCHORS)
    lo, hi = float(points[:, k].min()), float(points[:, k].max())
    length = hi - lo
    if not length > 0.0:
        raise LbshapeError("the points have zero extent along the pose axis")
    t = (points[:, k] - lo) / length if anchor == "min" else (hi - points[:, k]) / length
    return t, length


def _cross_section_centre(points: np.ndarray, k: int) -> np.ndarray:
    """(3,) centre of the bounding box (its axial coordinate is irrelevant)."""
    return 0.5 * (points.min(axis=0) + points.max(axis=0))
