"""LB shape space: descriptors, displacement coefficients, reconstruction, projections.

Conventions (Φ (n, m) the object's M-orthonormal eigenvectors, λ (m,) its
eigenvalues, constant mode excluded):

* **Coefficients are primary.** The LB coefficients of a field f (n, 3) are
  ``a = Φᵀ M f`` (m, 3); the descriptor of paper eq. 3 is ``l = λ a``
  (``l_i = λ_i ⟨p, φ_i⟩_M``). Reconstruction ``Σ l_i/λ_i φ_i = Φ a`` uses the
  **object's** λ in both directions, so λ cancels and a copy of the object
  round-trips exactly; the examples' own eigenvalues are never used (after
  volume normalisation they only differ from the object's by the shapes'
  difference). Constants (translations) are M-orthogonal to Φ, so coefficients
  are translation invariant.
* **Displacements.** Shapes are compared as displacements from a rest shape, so
  that truncating to m modes never smooths the rest shape itself:
  ``p = p_rest + Φ c`` on the object's mesh. For an example with a known rest
  mesh, ``c = Cᵀ Φ_exᵀ M_ex (p_pose − p_rest)`` — its *own* rest is subtracted in
  the aligned basis, so that e.g. a cylinder's cross-section differing from a
  cuboid's does not appear as a deformation. For an example given only as a
  posed shape, ``c = Cᵀ Φ_exᵀ M_ex p_pose − Φᵀ M p_rest,obj`` (the object's rest
  coefficients are subtracted). C is the :class:`~lbshape.shapespace.alignment.BasisAlignment`
  map of the example to the object.
* **Block layout.** A coefficient block c (m, 3) flattens row-major to (3m,),
  ``c_flat[3 i + k]`` (mode i, component k), matching node-major fields
  ``u[3 j + k]``; the block eigenfunction matrix is ``L = Φ ⊗ I₃`` (3n, 3m) with
  ``u = L c_flat`` and ``Lᵀ M₃ L = I`` (``M₃ = M ⊗ I₃``).
* **Direct projections** (paper §4.2 (3)). :func:`direct_projection` is the
  geometric product ``Uᵀ M₃ L`` (r, 3m) for any basis U. Neither L nor any 3n × 3n
  matrix is formed.
* **Density: one convention.** The elastic basis U (3n, r) is orthonormal in the
  elastic mass ``M = ρ M₃`` (kg), the LB eigenvectors in the volume mass M₃ (m³).
  Every map between the two spaces is stored and used in the reduced coordinates of
  the dynamics (:func:`reduced_projection`): ``T = Uᵀ M L = ρ Uᵀ M₃ L`` (r, 3m), so
  ``q = T c`` is the M-projection of ``L c`` onto span U (``U T c = P_U(L c)``), and
  the LB coefficients of ``U q`` are ``Lᵀ M₃ U q = Tᵀ q / ρ``
  (:func:`descriptor_matrix`, with the λ weights of the descriptor). These two
  functions are the only places where ρ enters the shape space's maps; the
  precompute stores T as they give it (global and per-region alike).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh
from lbshape.shapespace.alignment import (
    EXAMPLE_EXTRA_MODES,
    BasisAlignment,
)
from lbshape.shapespace.basis_choice import (
    MAX_RESIDUAL,
    MAX_TRANSFER_DIFFERENCE,
    choose_alignment,
    reference_transfer,
    transfer_difference,
)
from lbshape.shapespace.frames import (
    MAX_RELATIVE_RMS,
    AlignedShape,
    BodyFrame,
    align_to_object,
    body_frame,
)
from lbshape.spectral.spectrum import LBSpectrum, lb_spectrum


def lb_coefficients(field: np.ndarray, eigenvectors: np.ndarray, mass: sp.spmatrix) -> np.ndarray:
    """``Φᵀ M f``: coefficients (m, 3) of a vector field f (n, 3) on Φ (n, m), M (n, n)."""
    field = _field(field, eigenvectors.shape[0])
    return eigenvectors.T @ (mass @ field)


def descriptors(points: np.ndarray, eigenvalues: np.ndarray, eigenvectors: np.ndarray,
                mass: sp.spmatrix) -> np.ndarray:
    """Paper eq. 3: ``l_i = λ_i ⟨p, φ_i⟩_M``, an (m, 3) array.

    Args:
        points: (n, 3) positions in metres, in the object's frame.
        eigenvalues: (m,) λ in 1/m².
        eigenvectors: (n, m) Φ, M-orthonormal.
        mass: (n, n) consistent mass in m³.

    Returns:
        (m, 3) descriptors ``λ ⊙ Φᵀ M p`` in m^(1/2) (coefficients ``Φᵀ M p`` are
        in m^(5/2): Φ in m^(-3/2), M in m³, p in m).
    """
    return np.asarray(eigenvalues, dtype=float)[:, None] * lb_coefficients(points, eigenvectors,
                                                                          mass)


def reconstruct(rest_points: np.ndarray, coefficients: np.ndarray,
                eigenvectors: np.ndarray) -> np.ndarray:
    """``p = p_rest + Φ c``: positions (n, 3) on the object's mesh from c (m, 3)."""
    rest = _field(rest_points, eigenvectors.shape[0])
    c = np.asarray(coefficients, dtype=float)
    if c.shape != (eigenvectors.shape[1], 3):
        raise LbshapeError(
            f"coefficients must have shape ({eigenvectors.shape[1]}, 3), got {c.shape}"
        )
    return rest + eigenvectors @ c


def example_displacement_coefficients(
    posed_points: np.ndarray,
    example_eigenvectors: np.ndarray,
    example_mass: sp.spmatrix,
    alignment: BasisAlignment,
    *,
    rest_points: np.ndarray | None = None,
    object_rest_coefficients: np.ndarray | None = None,
) -> np.ndarray:
    """An example's displacement coefficients (m, 3) in the object's basis.

    Args:
        posed_points: (n_e, 3) the posed example in the object's frame (aligned
            with the same similarity transform as its rest mesh).
        example_eigenvectors: (n_e, ≥m) Φ_ex of the basis the map C starts from
            (the aligned rest mesh's, or the posed mesh's with a composed map).
        example_mass: (n_e, n_e) the mass matrix of that same mesh.
        alignment: the map C (m, m) from that basis to the object's.
        rest_points: (n_e, 3) the example's aligned rest vertices, when known.
        object_rest_coefficients: (m, 3) ``Φᵀ M p_rest`` of the object; required
            when ``rest_points`` is None.

    Returns:
        (m, 3) displacement coefficients c (see the module docstring).
    """
    m_ex, m = alignment.C.shape
    phi = np.asarray(example_eigenvectors)[:, :m_ex]
    if phi.shape[1] != m_ex:
        raise LbshapeError(
            f"example basis has {phi.shape[1]} eigenfunctions, the map needs {m_ex}")
    posed = _field(posed_points, phi.shape[0])
    if rest_points is not None:
        field = posed - _field(rest_points, phi.shape[0])
        return alignment.C.T @ lb_coefficients(field, phi, example_mass)
    if object_rest_coefficients is None:
        raise LbshapeError(
            "an example without a rest mesh needs the object's rest coefficients"
        )
    rest_c = np.asarray(object_rest_coefficients, dtype=float)
    if rest_c.shape != (m, 3):
        raise LbshapeError(f"object rest coefficients must be ({m}, 3), got {rest_c.shape}")
    return alignment.C.T @ lb_coefficients(posed, phi, example_mass) - rest_c


def example_coefficients_via_posed_basis(
    posed_points: np.ndarray,
    posed_eigenvectors: np.ndarray,
    posed_mass: sp.spmatrix,
    rest_points: np.ndarray,
    rest_eigenvectors: np.ndarray,
    rest_mass: sp.spmatrix,
    pose_map: BasisAlignment,
    alignment: BasisAlignment,
) -> np.ndarray:
    """Displacement coefficients (m, 3) with the posed shape in its own basis (paper).

    ``c = (C_pose C)ᵀ Φ_poseᵀ M_pose p_pose − Cᵀ Φ_restᵀ M_rest p_rest``, with
    ``pose_map`` from :func:`lbshape.shapespace.alignment.pose_basis_map` and ``alignment``
    the rest mesh's map to the object. Equals
    :func:`example_displacement_coefficients` up to the pose map's residual.
    """
    m = alignment.C.shape[0]
    posed = alignment.C.T @ (pose_map.C.T @ lb_coefficients(
        posed_points, np.asarray(posed_eigenvectors)[:, :m], posed_mass))
    rest = alignment.C.T @ lb_coefficients(rest_points, np.asarray(rest_eigenvectors)[:, :m],
                                           rest_mass)
    return posed - rest


#: a pose whose largest displacement is below this share of the example's bounding-box
#: diagonal is at rest (its transfer difference is 0: round-off has no shape)
AT_REST = 1e-9


@dataclass(frozen=True)
class EmbeddedExample:
    """An example brought into the object's shape space.

    Attributes:
        aligned: the similarity transform of its rest mesh into the object's frame.
        alignment: its basis map to the object's eigenbasis.
        coefficients: (p, m, 3) displacement coefficients of its p poses.
        transfer_differences: (p,) how unlike its source each pose's displacement reached
            the object (:func:`lbshape.shapespace.basis_choice.transfer_difference`).
    """

    aligned: AlignedShape
    alignment: BasisAlignment
    coefficients: np.ndarray
    transfer_differences: np.ndarray = dataclasses.field(
        default_factory=lambda: np.zeros(0))


def embed_example(
    object_mesh: TetMesh,
    object_spectrum: LBSpectrum,
    example_rest: TetMesh,
    poses: Sequence[np.ndarray],
    *,
    object_frame: BodyFrame | None = None,
    landmarks: np.ndarray | None = None,
    max_residual: float = MAX_RESIDUAL,
    name: str | None = None,
    max_frame_rms: float | None = MAX_RELATIVE_RMS,
    max_transfer_difference: float = MAX_TRANSFER_DIFFERENCE,
) -> EmbeddedExample:
    """Frame alignment, example spectrum, basis alignment and coefficients in one go.

    Args:
        object_mesh: the object's rest mesh.
        object_spectrum: its m eigenpairs.
        example_rest: the example's rest mesh, in its own coordinates.
        poses: p arrays (n_e, 3) of posed vertex positions, same connectivity and
            coordinates as ``example_rest`` (e.g. from :func:`lbshape.geometry.poses.apply_pose`).
        object_frame: :func:`lbshape.shapespace.frames.body_frame` of the object (computed
            when omitted).
        landmarks: optional (q, 2) pairs (object vertex, example vertex), used by the
            overlay.
        max_residual: largest accepted basis alignment residual (on normalised
            coordinates, :mod:`lbshape.shapespace.basis_choice`).
        name: how a refusal names the example (e.g. ``"example 2 (cube)"``); callers
            that prefix their own label to every error, as the precompute pipeline
            does, leave it out.
        max_frame_rms: largest relative RMS residual of the frame alignment at which
            the overlay is a candidate (above it the shapes do not overlap and only the
            intrinsic map is tried); None: always a candidate.
        max_transfer_difference: largest accepted
            :func:`~lbshape.shapespace.basis_choice.transfer_difference` of a pose's
            displacement (its source against what reached the object).

    The basis map is :func:`lbshape.shapespace.basis_choice.choose_alignment`'s: the
    overlay or the intrinsic map, whichever has the smaller residual; with the intrinsic
    map the example's displacements are mapped by its ``stretch`` D before their
    coefficients are taken.

    Raises:
        LbshapeError: the example does not correspond to the object (the chosen map's
            residual above ``max_residual`` or its spectral distortion above
            :data:`~lbshape.shapespace.basis_choice.MAX_DISTORTION`; the message names
            the frame residual when it ruled the overlay out), or a pose whose
            displacement reached the object unlike itself (transfer difference above
            ``max_transfer_difference``).
    """
    m = object_spectrum.eigenvalues.shape[0]
    frame = body_frame(object_mesh) if object_frame is None else object_frame
    aligned = align_to_object(example_rest.points, example_rest.tets, frame,
                              reference_points=object_mesh.points, name=name,
                              max_relative_rms=None)
    overlaps = max_frame_rms is None or aligned.relative_rms <= max_frame_rms
    rest = example_rest.with_points(aligned.points)
    try:
        alignment, spectrum = choose_alignment(
            object_spectrum, object_mesh, frame, rest,
            lambda count: offered_spectrum(rest, count),
            overlay_refusal=None if overlaps else (
                f"frame alignment residual {aligned.relative_rms:.3f} exceeds {max_frame_rms:g}"),
            landmarks=landmarks, max_residual=max_residual)
    except LbshapeError as exc:
        raise LbshapeError(f"{name}: {exc}" if name else str(exc)) from None
    posed = [aligned.apply(_field(p, example_rest.n_vertices)) for p in poses]
    if alignment.stretch is not None:  # the intrinsic map's displacement correspondence
        posed = [aligned.points + (p - aligned.points) @ alignment.stretch.T for p in posed]
    coefficients = np.array([
        example_displacement_coefficients(p,
                                          spectrum.eigenvectors, spectrum.mass, alignment,
                                          rest_points=aligned.points)
        for p in posed
    ]).reshape(len(poses), m, 3)
    differences = _checked_transfer(object_mesh, object_spectrum, frame, rest, spectrum,
                                    alignment, coefficients, posed, max_transfer_difference,
                                    name)
    return EmbeddedExample(aligned, alignment, coefficients, differences)


def _checked_transfer(object_mesh: TetMesh, object_spectrum: LBSpectrum, frame: BodyFrame,
                      rest: TetMesh, spectrum: LBSpectrum, alignment: BasisAlignment,
                      coefficients: np.ndarray, posed: list[np.ndarray], limit: float,
                      name: str | None) -> np.ndarray:
    """Each pose's :func:`~lbshape.shapespace.basis_choice.transfer_difference` (p,), its
    source (``posed`` − ``rest`` on the aligned example) against what reached the object
    (``coefficients``); a pose at rest to round-off measures 0.

    Raises:
        LbshapeError: a difference above ``limit`` (one line naming the measure).
    """
    reference = reference_transfer(object_mesh, frame, object_spectrum.eigenvectors, rest)
    still = AT_REST * float(np.linalg.norm(np.ptp(rest.points, axis=0)))
    differences = np.array([
        transfer_difference(reference, spectrum.mass, c, p - rest.points)
        if np.abs(p - rest.points).max() > still else 0.0
        for c, p in zip(coefficients, posed, strict=True)])
    if differences.size and differences.max() > limit:
        worst = int(np.argmax(differences))
        pose = f" (pose {worst})" if len(posed) > 1 else ""
        message = (f"the displacement transferred by the {alignment.method} map does not "
                   f"resemble the example{pose}: transfer difference "
                   f"{differences[worst]:.3f} (limit {limit:g}; alignment residual "
                   f"{alignment.residual:.3f}); give a finer example or landmarks")
        raise LbshapeError(f"{name}: {message}" if name else message)
    return differences


def offered_spectrum(example: TetMesh, m: int, *, cluster_rtol: float = 1e-3) -> LBSpectrum:
    """The example eigenpairs offered to the basis alignment: m plus up to
    :data:`~lbshape.shapespace.alignment.EXAMPLE_EXTRA_MODES` more, never cutting through a
    cluster of (near-)equal eigenvalues — a cut would offer an arbitrary half of a
    degenerate eigenspace, chosen by the eigensolver's random start."""
    wanted = min(m + EXAMPLE_EXTRA_MODES, example.n_vertices - 3)
    spectrum = lb_spectrum(example, max(wanted, m) + 1)
    values = spectrum.eigenvalues
    count = max(wanted, m)
    while count > m and values[count] - values[count - 1] <= cluster_rtol * values[count]:
        count -= 1
    return dataclasses.replace(spectrum, eigenvalues=values[:count],
                               eigenvectors=spectrum.eigenvectors[:, :count],
                               residuals=spectrum.residuals[:count])


def direct_projection(basis: np.ndarray, eigenvectors: np.ndarray,
                      mass: sp.spmatrix) -> np.ndarray:
    """``T = Uᵀ M₃ L`` (r, 3m) without forming L or M₃.

    Args:
        basis: (3n, r) U, node-major rows (``U[3 j + k]``), ``Uᵀ M₃ U = I``.
        eigenvectors: (n, m) Φ.
        mass: (n, n) M.
    """
    U = np.asarray(basis, dtype=float)
    n, m = eigenvectors.shape
    if U.ndim != 2 or U.shape[0] != 3 * n:
        raise LbshapeError(f"basis must have shape (3n={3 * n}, r), got {U.shape}")
    r = U.shape[1]
    MU = (mass @ U.reshape(n, 3 * r)).reshape(n, 3, r)  # M₃ U, node-major
    return np.einsum("jkr,ji->rik", MU, eigenvectors).reshape(r, 3 * m)


def reduced_projection(basis: np.ndarray, eigenvectors: np.ndarray, volume_mass: sp.spmatrix,
                       density: float) -> np.ndarray:
    """``T = Uᵀ M L = ρ Uᵀ M₃ L`` (r, 3m): LB displacement coefficients c (3m,) to the
    reduced coordinates ``q = T c`` of the M-projection of ``L c`` onto span U.

    Args:
        basis: (3n, r) U, node-major rows, ``Uᵀ M U = I`` with ``M = ρ M₃`` (kg).
        eigenvectors: (n, m) Φ (or the clamped Φ_F).
        volume_mass: (n, n) M₁ in m³ (``M₃ = M₁ ⊗ I₃``).
        density: ρ in kg/m³.
    """
    return density * direct_projection(basis, eigenvectors, volume_mass)


def descriptor_matrix(eigenvalues: np.ndarray, projection: np.ndarray,
                      density: float) -> np.ndarray:
    """(3m, r) ``D = diag(λ ⊗ 1₃) Tᵀ / ρ``: the descriptor (λ-weighted LB coefficients)
    of the displacement ``U q`` is ``D q``, for T of :func:`reduced_projection`."""
    return np.repeat(eigenvalues, 3)[:, None] * np.asarray(projection).T / density


def example_descriptors(eigenvalues: np.ndarray, coefficients: np.ndarray) -> np.ndarray:
    """(k, 3m) λ-weighted example displacement coefficients (k, m, 3), flattened row-major."""
    k = coefficients.shape[0]
    return coefficients.reshape(k, -1) * np.repeat(eigenvalues, 3)


def block_basis(eigenvectors: np.ndarray) -> np.ndarray:
    """Dense ``L = Φ ⊗ I₃`` (3n, 3m), node-major rows, column ``3i + c`` (the one builder
    of the block basis)."""
    n, m = eigenvectors.shape
    L = np.zeros((n, 3, m, 3))
    for c in range(3):
        L[:, c, :, c] = eigenvectors
    return L.reshape(3 * n, 3 * m)


@dataclass(frozen=True)
class ShapeSpace:
    """What the runtime needs of the LB shape space; small arrays only.

    Attributes:
        eigenvalues: (m,) the object's λ in 1/m².
        example_coefficients: (k, m, 3) example displacement coefficients c_k in
            the object's basis.
        projection: (r, 3m) ``T = Uᵀ M L`` (:func:`reduced_projection`).
        rest_coefficients: (m, 3) ``Φᵀ M₃ p_rest`` of the object.
        alignment_residuals: (k,) each example's basis alignment residual.
        names: (k,) example names.
        density: ρ (kg/m³) of the elastic mass ``M = ρ M₃`` U is orthonormal in.
        alignment_methods: (k,) how each example's basis was aligned
            (:data:`lbshape.shapespace.basis_choice.METHODS`).
    """

    eigenvalues: np.ndarray
    example_coefficients: np.ndarray
    projection: np.ndarray
    rest_coefficients: np.ndarray
    alignment_residuals: np.ndarray
    names: tuple[str, ...]
    density: float
    alignment_methods: tuple[str, ...] = ()

    def __post_init__(self):
        m = self.eigenvalues.shape[0]
        k = self.example_coefficients.shape[0]
        if self.example_coefficients.shape != (k, m, 3):
            raise LbshapeError(
                f"example coefficients must be (k, {m}, 3), got {self.example_coefficients.shape}"
            )
        if self.projection.ndim != 2 or self.projection.shape[1] != 3 * m:
            raise LbshapeError(f"projection must be (r, {3 * m}), got {self.projection.shape}")
        if len(self.names) != k or self.alignment_residuals.shape != (k,):
            raise LbshapeError(f"need {k} example names and alignment residuals")

    @property
    def m(self) -> int:
        return int(self.eigenvalues.shape[0])

    @property
    def r(self) -> int:
        return int(self.projection.shape[0])

    @property
    def descriptor_matrix(self) -> np.ndarray:
        """(3m, r) ``D``: the descriptor of ``U q`` is ``D q`` (:func:`descriptor_matrix`)."""
        return descriptor_matrix(self.eigenvalues, self.projection, self.density)

    @property
    def example_descriptors(self) -> np.ndarray:
        """(k, 3m) flattened λ-weighted displacement coefficients of the examples."""
        return example_descriptors(self.eigenvalues, self.example_coefficients)

    @property
    def example_reduced(self) -> np.ndarray:
        """(k, r) reduced coordinates ``q_k = T c_k`` of the examples."""
        k = self.example_coefficients.shape[0]
        return self.example_coefficients.reshape(k, -1) @ self.projection.T


def make_shape_space(
    eigenvalues: np.ndarray,
    eigenvectors: np.ndarray,
    mass: sp.spmatrix,
    rest_points: np.ndarray,
    basis: np.ndarray,
    example_coefficients: Sequence[np.ndarray],
    alignments: Sequence[BasisAlignment],
    names: Sequence[str],
    *,
    density: float,
) -> ShapeSpace:
    """Assemble a :class:`ShapeSpace` from the object's spectrum (``mass``: its volume
    mass M₁, m³) and the elastic basis U (3n, r), ``Uᵀ M U = I`` with ``M = ρ M₃``."""
    coefficients = np.asarray(example_coefficients, dtype=float)
    m = eigenvectors.shape[1]
    coefficients = coefficients.reshape(len(names), m, 3) if coefficients.size \
        else np.zeros((0, m, 3))
    return ShapeSpace(
        eigenvalues=np.asarray(eigenvalues, dtype=float).copy(),
        example_coefficients=coefficients,
        projection=reduced_projection(basis, eigenvectors, mass, density),
        rest_coefficients=lb_coefficients(rest_points, eigenvectors, mass),
        alignment_residuals=np.array([a.residual for a in alignments], dtype=float),
        alignment_methods=tuple(a.method for a in alignments),
        names=tuple(names),
        density=float(density),
    )


def _field(values, n: int) -> np.ndarray:
    values = np.asarray(values, dtype=float)
    if values.shape != (n, 3):
        raise LbshapeError(f"expected an ({n}, 3) array of positions or vectors, got "
                           f"{values.shape}")
    return values
