"""Aligning an example's LB eigenfunctions with the object's (paper step 3): the overlay.

This is one of two methods; :mod:`lbshape.shapespace.basis_choice` runs it next to the
intrinsic map of :mod:`lbshape.shapespace.functional_map` and keeps, per example, the
one with the smaller residual on normalised coordinates (the overlay on a tie). The
threshold below is this function's own, used when it is called directly.

Approach. After :func:`lbshape.shapespace.frames.align_to_object`, the example's rest mesh
overlaps the object's rest mesh geometrically (same volume, same centre of mass,
principal axes matched). The object's eigenfunctions are then *transferred* to the
example's vertices by P1 interpolation: each example vertex is located in the
object's tetrahedra (vectorised: candidate tets from a ``cKDTree`` ball query on
tet centroids with the largest circumradius about a centroid, barycentric
coordinates for all candidates at once); vertices slightly outside the object are
projected to the nearest point of its boundary surface and interpolated there.
This gives ``F = Φ_obj→ex`` (n_e, m). The least-squares map with
``Φ_ex C ≈ F`` in the example's mass inner product is ``C = Φ_exᵀ M_ex F``
(Φ_ex is M_ex-orthonormal); it is projected to the nearest orthogonal matrix
(polar factor ``U Vᵀ`` of its SVD ``U S Vᵀ``). This absorbs sign flips, order swaps
and rotations inside (near-)degenerate eigenspaces in one step. Optional
landmark pairs (object vertex, example vertex) add
``w (V/p) Σ ‖Φ_ex[j_e] C − Φ_obj[j_o]‖²`` to the least-squares problem (V the
object's volume, p the number of pairs, w = ``landmark_weight``).

Quality. ``residual = ‖Φ_ex C − F‖_M / ‖F‖_M`` (Frobenius, M = M_ex) and the same
per column. A residual above ``max_residual`` (default :data:`MAX_RESIDUAL` = 0.5:
more than half of the transferred eigenfunctions' norm is not represented by the
example's basis) means the shapes do not correspond and alignment is meaningless;
:class:`~lbshape.errors.LbshapeError` is raised.

Scale. The example spectrum must be that of the example *as aligned* (its volume
equal to the object's); :func:`scaled_spectrum` rescales a spectrum computed on
the raw example analytically (λ/s², Φ s^(-3/2), M s³, K s), since rotations and
translations leave it unchanged.

Posed examples. For a posed example with the same connectivity as its rest mesh,
:func:`pose_basis_map` gives the orthogonal ``C_pose ≈ Φ_poseᵀ M_pose Φ_rest`` (same
vertices, no transfer needed), and :func:`compose` chains it with the rest mesh's
alignment so that the posed spectrum can be used as the paper does:
``Φ_pose C_pose C ≈ Φ_obj→ex``.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh
from lbshape.spectral.spectrum import LBSpectrum

log = logging.getLogger(__name__)

#: default largest accepted alignment residual (see the module docstring)
MAX_RESIDUAL = 0.5
#: extra example eigenfunctions offered to the alignment beyond the object's m: an
#: object mode may match a slightly higher example mode (e.g. a cuboid's
#: cross-section mode against a cylinder's), so C is (m + extra) x m
EXAMPLE_EXTRA_MODES = 4
#: a vertex is inside a tet when all barycentric coordinates are ≥ −INSIDE_TOL
INSIDE_TOL = 1e-10
#: relative tolerance of the volume check between object and aligned example
VOLUME_RTOL = 1e-6
#: boundary faces examined per outside point (nearest by centroid)
_FACE_CANDIDATES = 8


@dataclass(frozen=True)
class BasisAlignment:
    """An orthogonal map from the example's eigenbasis to the object's.

    Attributes:
        C: (m, m) orthogonal; ``Φ_ex C ≈ Φ_obj`` on the example's vertices, so an
            example coefficient block a (m, 3) is ``Cᵀ a`` in the object's basis.
        residual: ``‖Φ_ex C − F‖_M / ‖F‖_M`` (dimensionless).
        per_mode_residual: (m,) the same per object eigenfunction.
        outside_fraction: fraction of example vertices outside the object, mapped
            to its boundary (0 for posed-basis maps).
        method: how C was found: ``"overlay"`` (this module) or ``"intrinsic"``
            (:mod:`lbshape.shapespace.functional_map`); :mod:`lbshape.shapespace.basis_choice`
            sets it and then measures ``residual`` on normalised coordinates.
        distortion: the map's spectral distortion (``basis_choice``; 0 when unmeasured).
        stretch: (3, 3) the linear map D taking the example's displacements (m) to the
            object's (the intrinsic map's normalised-coordinate correspondence, with
            ``D = A diag(σ_obj / σ_ex) Aᵀ``), or None for the identity (overlay).
    """

    C: np.ndarray
    residual: float
    per_mode_residual: np.ndarray
    outside_fraction: float = 0.0
    method: str = "overlay"
    distortion: float = 0.0
    stretch: np.ndarray | None = None


def scaled_spectrum(spectrum: LBSpectrum, factor: float) -> LBSpectrum:
    """The exact spectrum of the mesh scaled by ``factor`` (> 0) about any point."""
    s = float(factor)
    if not s > 0.0:
        raise LbshapeError(f"scale factor must be positive, got {factor!r}")
    changes = {
        "eigenvalues": spectrum.eigenvalues / s**2,
        "eigenvectors": spectrum.eigenvectors * s**-1.5,
        "mass": spectrum.mass * s**3,
        "stiffness": spectrum.stiffness * s,
        "target": spectrum.target / s**2,
    }
    if hasattr(spectrum, "zero_eigenvalue"):
        changes["zero_eigenvalue"] = spectrum.zero_eigenvalue / s**2
    return dataclasses.replace(spectrum, **changes)


def interpolation_matrix(
    mesh: TetMesh, query: np.ndarray
) -> tuple[sp.csr_matrix, np.ndarray]:
    """P1 interpolation from ``mesh`` vertices to ``query`` points.

    Args:
        mesh: the source mesh with n vertices.
        query: (q, 3) points in metres.

    Returns:
        (W (q, n) CSR with rows summing to 1, outside (q,) bool): points outside
        the mesh are interpolated at the nearest point of its boundary surface.
    """
    query = np.asarray(query, dtype=float)
    points, tets = mesh.points, mesh.tets
    q = query.shape[0]
    corners = points[tets]  # (t, 4, 3)
    centroids = corners.mean(axis=1)
    radii = np.linalg.norm(corners - centroids[:, None, :], axis=2).max(axis=1)
    edges = np.transpose(corners[:, 1:] - corners[:, :1], (0, 2, 1))  # (t, 3, 3) columns
    inverse = np.linalg.inv(edges)

    candidates = cKDTree(centroids).query_ball_point(query, r=float(radii.max()) * (1 + 1e-9))
    counts = np.fromiter((len(c) for c in candidates), dtype=np.int64, count=q)
    pair_point = np.repeat(np.arange(q), counts)
    pair_tet = np.fromiter((t for c in candidates for t in c), dtype=np.int64,
                           count=int(counts.sum()))
    local = np.einsum("pij,pj->pi", inverse[pair_tet], query[pair_point] - corners[pair_tet, 0])
    bary = np.column_stack([1.0 - local.sum(axis=1), local])
    score = bary.min(axis=1)
    # per point, the candidate with the largest smallest barycentric coordinate
    order = np.lexsort((-score, pair_point))
    first = np.searchsorted(pair_point[order], np.arange(q))
    has = counts > 0
    best = np.full(q, -1, dtype=np.int64)
    best[has] = order[first[has]]
    inside = np.zeros(q, dtype=bool)
    inside[has] = score[best[has]] >= -INSIDE_TOL

    rows = np.repeat(np.arange(q), 4)
    cols = np.empty((q, 4), dtype=np.int64)
    vals = np.empty((q, 4))
    cols[inside] = tets[pair_tet[best[inside]]]
    vals[inside] = bary[best[inside]]
    outside = ~inside
    if outside.any():
        face_cols, face_vals = _nearest_boundary_weights(mesh, query[outside])
        cols[outside, :3], vals[outside, :3] = face_cols, face_vals
        cols[outside, 3], vals[outside, 3] = face_cols[:, 0], 0.0
    W = sp.csr_matrix((vals.ravel(), (rows, cols.ravel())), shape=(q, points.shape[0]))
    W.sum_duplicates()
    return W, outside


def _nearest_boundary_weights(mesh: TetMesh, query: np.ndarray):
    """(vertex ids (q, 3), barycentric weights (q, 3)) of the closest boundary points."""
    faces = mesh.boundary_faces()
    tri = mesh.points[faces]  # (f, 3, 3)
    k = min(_FACE_CANDIDATES, faces.shape[0])
    _, near = cKDTree(tri.mean(axis=1)).query(query, k=k)
    near = near.reshape(query.shape[0], k)
    weights = _closest_on_triangles(query[:, None, :], tri[near])  # (q, k, 3)
    closest = np.einsum("qki,qkij->qkj", weights, tri[near])
    dist = np.linalg.norm(closest - query[:, None, :], axis=2)
    pick = np.argmin(dist, axis=1)
    rows = np.arange(query.shape[0])
    return faces[near[rows, pick]], weights[rows, pick]


def _closest_on_triangles(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Barycentric weights (..., 3) of the closest point to p (..., 3) on tri (..., 3, 3).

    Minimises over the triangle by checking the interior projection, then the
    three edges (clamped segment projections), and keeping the nearest.
    """
    a, b, c = tri[..., 0, :], tri[..., 1, :], tri[..., 2, :]
    ab, ac, ap = b - a, c - a, p - a
    d00, d01, d11 = (ab * ab).sum(-1), (ab * ac).sum(-1), (ac * ac).sum(-1)
    d20, d21 = (ap * ab).sum(-1), (ap * ac).sum(-1)
    den = d00 * d11 - d01 * d01
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    options = [np.stack([1.0 - v - w, v, w], axis=-1)]
    valid = [(v >= 0) & (w >= 0) & (v + w <= 1)]
    for i, j in ((0, 1), (1, 2), (2, 0)):
        e = tri[..., j, :] - tri[..., i, :]
        t = np.clip(((p - tri[..., i, :]) * e).sum(-1) / (e * e).sum(-1), 0.0, 1.0)
        bary = np.zeros(t.shape + (3,))
        bary[..., i], bary[..., j] = 1.0 - t, t
        options.append(bary)
        valid.append(np.ones_like(t, dtype=bool))
    best = options[0]
    best_d = np.where(valid[0], _dist(p, tri, options[0]), np.inf)
    for bary in options[1:]:
        d = _dist(p, tri, bary)
        better = d < best_d
        best = np.where(better[..., None], bary, best)
        best_d = np.where(better, d, best_d)
    return best


def _dist(p, tri, bary):
    return np.linalg.norm(np.einsum("...i,...ij->...j", bary, tri) - p, axis=-1)


def align_bases(
    object_spectrum: LBSpectrum,
    object_mesh: TetMesh,
    example_spectrum: LBSpectrum,
    example_rest_points: np.ndarray,
    *,
    landmarks: np.ndarray | None = None,
    landmark_weight: float = 1.0,
    max_residual: float = MAX_RESIDUAL,
) -> BasisAlignment:
    """The orthogonal map C with ``Φ_ex C ≈ Φ_obj`` (see the module docstring).

    Args:
        object_spectrum: the object's m eigenpairs (on ``object_mesh``).
        object_mesh: the object's rest mesh (n_o vertices).
        example_spectrum: the example's eigenpairs, computed on the example as
            aligned (volume equal to the object's), with at least m pairs; the
            first m are used.
        example_rest_points: (n_e, 3) the example's rest vertices in the object's
            frame (:attr:`lbshape.shapespace.frames.AlignedShape.points`).
        landmarks: optional (p, 2) int pairs (object vertex, example vertex).
        landmark_weight: w ≥ 0 of the landmark term.
        max_residual: largest accepted residual.

    Raises:
        LbshapeError: mismatched sizes, too few example modes, an example
            spectrum not at the object's volume, bad landmarks, or a residual above
            ``max_residual``.
    """
    phi_obj = object_spectrum.eigenvectors
    m = phi_obj.shape[1]
    phi_ex_all = example_spectrum.eigenvectors
    points = np.asarray(example_rest_points, dtype=float)
    n_e = points.shape[0]
    if phi_obj.shape[0] != object_mesh.n_vertices:
        raise LbshapeError(
            f"object spectrum has {phi_obj.shape[0]} vertices but the object mesh "
            f"{object_mesh.n_vertices}"
        )
    if phi_ex_all.shape[0] != n_e:
        raise LbshapeError(
            f"example spectrum has {phi_ex_all.shape[0]} vertices but {n_e} example points "
            "were given"
        )
    if phi_ex_all.shape[1] < m:
        raise LbshapeError(
            f"example spectrum has {phi_ex_all.shape[1]} eigenfunctions but the object uses "
            f"m={m}; compute at least m on the example (needs m + 1 < {n_e} vertices)"
        )
    v_obj = float(object_spectrum.mass.sum())
    v_ex = float(example_spectrum.mass.sum())
    if abs(v_ex - v_obj) > VOLUME_RTOL * v_obj:
        raise LbshapeError(
            f"example spectrum is of a shape with volume {v_ex:.6g} m^3, the object has "
            f"{v_obj:.6g} m^3: compute it on the aligned example (or use scaled_spectrum)"
        )
    phi_ex = phi_ex_all  # all offered modes: C is (m_ex, m) with orthonormal columns
    M_ex = example_spectrum.mass
    W, outside = interpolation_matrix(object_mesh, points)
    F = W @ phi_obj
    A = phi_ex.T @ (M_ex @ F)
    if landmarks is not None:
        A = _add_landmarks(A, phi_obj, phi_ex, landmarks, landmark_weight, v_obj)
    C = polar(A)
    alignment = transfer_quality(phi_ex, F, M_ex, C, float(outside.mean()))
    log.info("basis alignment: m=%d residual %.3e (worst mode %d: %.3e), %.1f%% outside",
             m, alignment.residual, int(np.argmax(alignment.per_mode_residual)) + 1,
             alignment.per_mode_residual.max(), 100 * alignment.outside_fraction)
    if not alignment.residual <= max_residual:
        raise LbshapeError(
            f"example does not correspond to the object: LB basis alignment residual "
            f"{alignment.residual:.3f} exceeds {max_residual:g} (worst mode "
            f"{int(np.argmax(alignment.per_mode_residual)) + 1}: "
            f"{alignment.per_mode_residual.max():.3f})"
        )
    return alignment


def _add_landmarks(A, phi_obj, phi_ex, landmarks, weight, volume) -> np.ndarray:
    """Normal equations of the Frobenius term with the landmark rows added."""
    pairs = np.asarray(landmarks)
    if pairs.ndim != 2 or pairs.shape[1] != 2 or pairs.shape[0] == 0 \
            or not np.issubdtype(pairs.dtype, np.integer):
        raise LbshapeError(f"landmarks must be a (p, 2) integer array, got shape {pairs.shape}")
    if (pairs < 0).any() or (pairs[:, 0] >= phi_obj.shape[0]).any() \
            or (pairs[:, 1] >= phi_ex.shape[0]).any():
        raise LbshapeError("landmark vertex index out of range")
    if not (np.isfinite(weight) and weight >= 0.0):
        raise LbshapeError(f"landmark_weight must be >= 0, got {weight!r}")
    w = float(weight) * volume / pairs.shape[0]
    rows_ex, rows_obj = phi_ex[pairs[:, 1]], phi_obj[pairs[:, 0]]
    normal = np.eye(A.shape[0]) + w * rows_ex.T @ rows_ex
    return np.linalg.solve(normal, A + w * rows_ex.T @ rows_obj)


def polar(A: np.ndarray) -> np.ndarray:
    """Nearest matrix with orthonormal columns (Frobenius) to A (p, m), p ≥ m:
    ``U Vᵀ`` from the thin SVD ``A = U S Vᵀ``."""
    u, _, vt = np.linalg.svd(A, full_matrices=False)
    return u @ vt


def transfer_quality(phi, F, M, C, outside_fraction: float = 0.0) -> BasisAlignment:
    """The map C (m_ex, m) with its residual ``‖Φ C − F‖_M / ‖F‖_M`` (and per column)
    against transferred functions F (n_e, m); Φ (n_e, m_ex), M (n_e, n_e)."""
    diff = phi @ C - F
    num = np.einsum("ij,ij->j", diff, M @ diff)
    den = np.einsum("ij,ij->j", F, M @ F)
    residual = float(np.sqrt(num.sum() / den.sum()))
    per_mode = np.sqrt(num / np.maximum(den, 1e-300))
    return BasisAlignment(C, residual, per_mode, outside_fraction)


def pose_basis_map(
    posed_spectrum: LBSpectrum, rest_eigenvectors: np.ndarray, *,
    max_residual: float = MAX_RESIDUAL,
) -> BasisAlignment:
    """Orthogonal ``C_pose`` with ``Φ_pose C_pose ≈ Φ_rest`` on the same vertices.

    Args:
        posed_spectrum: eigenpairs of the posed example (same connectivity as its
            rest mesh), at least m of them.
        rest_eigenvectors: (n, m) the rest mesh's eigenvectors.
        max_residual: largest accepted residual (measured in ``M_pose``).
    """
    rest = np.asarray(rest_eigenvectors, dtype=float)
    phi = posed_spectrum.eigenvectors
    if phi.shape[0] != rest.shape[0]:
        raise LbshapeError(
            f"posed spectrum has {phi.shape[0]} vertices, the rest eigenvectors {rest.shape[0]}"
        )
    m = rest.shape[1]
    if phi.shape[1] < m:
        raise LbshapeError(f"posed spectrum has {phi.shape[1]} eigenfunctions, need m={m}")
    phi = phi[:, :m]
    M = posed_spectrum.mass
    C = polar(phi.T @ (M @ rest))
    alignment = transfer_quality(phi, rest, M, C, 0.0)
    if not alignment.residual <= max_residual:
        raise LbshapeError(
            f"posed eigenbasis does not match the rest basis: residual "
            f"{alignment.residual:.3f} exceeds {max_residual:g}"
        )
    return alignment


def compose(first: BasisAlignment, second: BasisAlignment) -> BasisAlignment:
    """The chained map ``C = C₁ C₂`` (e.g. posed → rest, then rest → object).

    The residual is the triangle-inequality estimate ``r₁ + r₂``.
    """
    if first.C.shape[1] != second.C.shape[0]:
        raise LbshapeError(f"cannot compose maps of shapes {first.C.shape} and {second.C.shape}")
    return BasisAlignment(
        C=first.C @ second.C,
        residual=first.residual + second.residual,
        per_mode_residual=first.per_mode_residual @ np.abs(second.C) + second.per_mode_residual,
        outside_fraction=max(first.outside_fraction, second.outside_fraction),
    )
