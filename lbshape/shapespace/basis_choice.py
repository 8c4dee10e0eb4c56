"""Choosing, per example, how its LB basis is aligned with the object's.

Two methods give the orthonormal map C (``Φ_ex C ≈ Φ_obj``):

* ``overlay`` (:func:`lbshape.shapespace.alignment.align_bases`): the object's
  eigenfunctions interpolated at the example's vertices after the frame alignment.
  It needs the two shapes to overlap (frame residual ≤
  :data:`lbshape.shapespace.frames.MAX_RELATIVE_RMS`); it is only tried then.
* ``intrinsic`` (:func:`lbshape.shapespace.functional_map.intrinsic_map`): each shape's
  own eigenpairs coupled through descriptor functions that need no overlap (heat-kernel
  signatures, normalised principal-axis coordinates). It is offered
  :data:`INTRINSIC_MODES` · m example eigenpairs (the object's m modes of a bar of
  other proportions sit further up the example's spectrum).

**One residual for both.** The reference correspondence is the one of normalised
principal-axis coordinates: an example point with coordinates ξ
(:func:`~lbshape.shapespace.functional_map.normalised_coordinates`) corresponds to the
object point with the same ξ (``x = c + A (σ_obj ⊙ ξ)``). Each method's C is scored by
the overlay-style residual ``‖Φ_ex C − F_ξ‖_M / ‖F_ξ‖_M`` with ``F_ξ`` the object's
eigenfunctions interpolated at those points (for shapes of the same proportions
``F_ξ`` is the overlay's own F, so the overlay's residual is unchanged there). The
smaller residual wins; a tie (within :data:`TIE`) keeps the overlay.

**Displacements.** The same correspondence maps the example's displacements: with the
intrinsic map, an example displacement u (m) counts as ``D u`` on the object,
``D = A diag(σ_obj / σ_ex) Aᵀ`` (``BasisAlignment.stretch``), so that a twist of a
thinner example is the same twist angle on the object (without it a 4:1 example's
twist reached the 5:1 object's end at 0.80 of the own-proportion example's angle; with
it 0.9–1.1, see ``results/alignment.md``). The overlay keeps displacements as they
are (D = I), so its results are those of before. The chosen map's ``residual``,
``method`` and ``distortion`` are reported.

**Refusal.** A genuinely different shape is refused in one line naming both numbers
when the chosen map's residual exceeds ``max_residual`` (:data:`MAX_RESIDUAL`) or its
spectral distortion (:func:`~lbshape.shapespace.functional_map.spectral_distortion`)
exceeds :data:`MAX_DISTORTION`. Normalising each axis makes a cube look like a bar, so
the residual alone cannot refuse it; the spectrum can (a bar's cross-section modes
are 25× its first eigenvalue where a cube's are 1×). Measured (m = 10; see
``results/alignment.md``): accepted pairs have distortion ≤ 0.98 (2× stretched copy,
8:1 and 2:1 cylinders against the 5:1 bar) and residual ≤ 0.27; refused pairs: cube for
the 5:1 bar distortion 1.88 (residual 0.50), ball for the L-beam 1.67 (residual 1.15).

**Transfer check.** A map can pass both bounds and still carry an example's displacement
to the object as a different shape (a coarse surface-only bend, 249 vertices, accepted
by the intrinsic map at residual 0.431, reached the object as a wave). Each
transferred displacement is therefore compared with its source on the same reference
correspondence (:func:`transfer_difference`): the object's reconstruction ``Φ_obj c``
read at the example's corresponding points, ``F_ξ c``, against the best the object's m
eigenfunctions can do there, ``F_ξ c*`` with c* the M-least-squares fit of the
example's own displacement u (``c* = (F_ξᵀ M F_ξ)⁻¹ F_ξᵀ M u``):
``d = ‖F_ξ (c − c*)‖_M / ‖F_ξ c*‖_M`` (the denominator at least :data:`HELD_FLOOR`
``‖u‖_M``). It compares the low-frequency content of the
two displacements only (the truncation to m modes is not an error of the map), is
linear in u in both terms (scaling the pose or the example changes nothing), and is 0
for a perfect map. Above :data:`MAX_TRANSFER_DIFFERENCE` the example is refused (one
line naming the measure); above :data:`WARN_TRANSFER_DIFFERENCE` the precompute warns.
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh
from lbshape.shapespace.alignment import (
    BasisAlignment,
    align_bases,
    interpolation_matrix,
    transfer_quality,
)
from lbshape.shapespace.frames import BodyFrame
from lbshape.shapespace.functional_map import (
    intrinsic_map,
    normalised_coordinates,
    principal_extent,
    spectral_distortion,
)
from lbshape.spectral.spectrum import LBSpectrum

log = logging.getLogger(__name__)

#: the alignment methods, in order of preference on a tie
METHODS = ("overlay", "intrinsic")
#: largest accepted residual on normalised coordinates (module docstring)
MAX_RESIDUAL = 0.5
#: largest accepted spectral distortion (module docstring)
MAX_DISTORTION = 1.5
#: the intrinsic map replaces the overlay only when its residual is smaller by more than this
TIE = 0.01
#: the intrinsic map is offered this many times m example eigenpairs
INTRINSIC_MODES = 5
#: largest accepted transfer difference of an example's displacement (module docstring)
MAX_TRANSFER_DIFFERENCE = 0.4
#: above this transfer difference the precompute warns that the transfer is doubtful
WARN_TRANSFER_DIFFERENCE = 0.25
#: the transfer difference is relative to the part of the example the object's m
#: eigenfunctions hold, but to no less than this share of the whole example: an example
#: they barely hold cannot be carried wrongly by much (the demo's twists at m = 4: 1 %
#: held, a difference of 0.44 of that 1 %)
HELD_FLOOR = 0.25


def warn_doubtful_transfer(label: str, embedded) -> None:
    """Warn (one line naming the example) when an accepted example's displacement reached
    the object near the refusal limit: a transfer difference above
    :data:`WARN_TRANSFER_DIFFERENCE` (``embedded``: an
    :class:`~lbshape.shapespace.projections.EmbeddedExample`)."""
    differences = np.asarray(embedded.transfer_differences, dtype=float)
    if differences.size and differences.max() > WARN_TRANSFER_DIFFERENCE:
        log.warning("%s: its displacement reached the object only roughly like itself: "
                    "transfer difference %.3f (warning above %g, refused above %g; "
                    "%s map, alignment residual %.3f); check its render, or give a finer "
                    "example or landmarks", label, differences.max(), WARN_TRANSFER_DIFFERENCE,
                    MAX_TRANSFER_DIFFERENCE, embedded.alignment.method,
                    embedded.alignment.residual)


def transfer_difference(reference: np.ndarray, mass, coefficients: np.ndarray,
                        displacement: np.ndarray) -> float:
    """How unlike its source an example's displacement reached the object (module docstring).

    Args:
        reference: ``F_ξ`` (n_e, m), the object's eigenfunctions at the example's
            corresponding points (:func:`reference_transfer`).
        mass: (n_e, n_e) the example's volume mass.
        coefficients: (m, 3) the transferred displacement coefficients c.
        displacement: (n_e, 3) the example's own displacement u (m), in the object's frame.

    Returns:
        ``‖F_ξ (c − c*)‖_M / max(‖F_ξ c*‖_M, HELD_FLOOR ‖u‖_M)`` (dimensionless; 0 for
        a perfect map or a zero displacement).
    """
    F = np.asarray(reference, dtype=float)
    u = np.asarray(displacement, dtype=float).reshape(F.shape[0], 3)
    MF = mass @ F
    best = np.linalg.lstsq(F.T @ MF, MF.T @ u, rcond=1e-12)[0]
    base = F @ best
    diff = F @ (np.asarray(coefficients, dtype=float).reshape(best.shape) - best)
    size = max(float(np.sum(base * (mass @ base))),
               HELD_FLOOR ** 2 * float(np.sum(u * (mass @ u))))
    if not size > 0:
        return 0.0
    return float(np.sqrt(np.sum(diff * (mass @ diff)) / size))


def reference_transfer(object_mesh: TetMesh, object_frame: BodyFrame, object_phi: np.ndarray,
                       example: TetMesh) -> np.ndarray:
    """``F_ξ`` (n_e, m): the object's eigenfunctions (n_o, m) at the object points with
    the example vertices' normalised coordinates (``example`` in the object's frame)."""
    xi = normalised_coordinates(example.points, example.tets, object_frame)
    centre, sigma = principal_extent(object_mesh.points, object_mesh.tets, object_frame)
    W, _ = interpolation_matrix(object_mesh, centre + (xi * sigma) @ object_frame.axes.T)
    return W @ object_phi


def candidate_alignments(
    object_spectrum: LBSpectrum,
    object_mesh: TetMesh,
    object_frame: BodyFrame,
    example: TetMesh,
    spectra,
    *,
    overlay_refusal: str | None = None,
    landmarks: np.ndarray | None = None,
) -> list[tuple[BasisAlignment, LBSpectrum]]:
    """Every candidate alignment of ``example``, each scored on normalised coordinates.

    Args:
        object_spectrum: the object's m eigenpairs.
        object_mesh: the object's rest mesh.
        object_frame: its :func:`~lbshape.shapespace.frames.body_frame`.
        example: the example's rest mesh in the object's frame, at the object's volume.
        spectra: ``spectra(count)`` → the example's offered eigenpairs for ``count``
            object modes (:func:`lbshape.shapespace.projections.offered_spectrum`).
        overlay_refusal: why the overlay is no candidate (e.g. ``"frame alignment
            residual 0.300 exceeds 0.2"``: the shapes do not overlap), or None when it is.
        landmarks: optional (p, 2) pairs (object vertex, example vertex) for the overlay.

    Returns:
        [(:class:`BasisAlignment` with ``method``, ``residual`` on normalised coordinates,
        ``distortion`` and ``stretch``; the example spectrum its C starts from)], in
        the order of :data:`METHODS` (the overlay left out with ``overlay_refusal``).
    """
    m = object_spectrum.eigenvalues.shape[0]
    phi_obj = object_spectrum.eigenvectors
    reference = reference_transfer(object_mesh, object_frame, phi_obj, example)
    candidates = []
    if overlay_refusal is None:
        spectrum = spectra(m)
        found = align_bases(object_spectrum, object_mesh, spectrum, example.points,
                            landmarks=landmarks, max_residual=np.inf)
        candidates.append(("overlay", found, spectrum, None))
    spectrum = spectra(INTRINSIC_MODES * m)
    C = intrinsic_map(object_spectrum, normalised_coordinates(object_mesh.points,
                                                              object_mesh.tets, object_frame),
                      spectrum, normalised_coordinates(example.points, example.tets,
                                                       object_frame))
    _, sigma_obj = principal_extent(object_mesh.points, object_mesh.tets, object_frame)
    _, sigma_ex = principal_extent(example.points, example.tets, object_frame)
    stretch = (object_frame.axes * (sigma_obj / sigma_ex)) @ object_frame.axes.T
    candidates.append(("intrinsic", BasisAlignment(C, np.nan, np.full(m, np.nan)), spectrum,
                       stretch))
    scored = []
    for method, found, spectrum, map_stretch in candidates:
        phi = spectrum.eigenvectors[:, : found.C.shape[0]]
        quality = transfer_quality(phi, reference, spectrum.mass, found.C,
                                   found.outside_fraction)
        scored.append((dataclasses.replace(
            quality, method=method, stretch=map_stretch,
            distortion=spectral_distortion(found.C, object_spectrum.eigenvalues,
                                           spectrum.eigenvalues)), spectrum))
        log.info("basis alignment %s: residual %.3f, distortion %.3f", method,
                 scored[-1][0].residual, scored[-1][0].distortion)
    return scored


def choose_alignment(
    object_spectrum: LBSpectrum,
    object_mesh: TetMesh,
    object_frame: BodyFrame,
    example: TetMesh,
    spectra,
    *,
    overlay_refusal: str | None = None,
    landmarks: np.ndarray | None = None,
    max_residual: float = MAX_RESIDUAL,
    max_distortion: float = MAX_DISTORTION,
) -> tuple[BasisAlignment, LBSpectrum]:
    """The better of the :func:`candidate_alignments` (see the module docstring).

    Args:
        object_spectrum, object_mesh, object_frame, example, spectra, overlay_refusal,
            landmarks: as for :func:`candidate_alignments`.
        max_residual: largest accepted residual of the chosen map.
        max_distortion: largest accepted spectral distortion of the chosen map.

    Returns:
        (the chosen :class:`BasisAlignment`; the example spectrum its C starts from).

    Raises:
        LbshapeError: the chosen map's residual or distortion is above its bound.
    """
    scored = candidate_alignments(object_spectrum, object_mesh, object_frame, example, spectra,
                                  overlay_refusal=overlay_refusal, landmarks=landmarks)
    best, spectrum = scored[0]
    for found, offered in scored[1:]:
        if found.residual < best.residual - TIE:
            best, spectrum = found, offered
    if not (best.residual <= max_residual and best.distortion <= max_distortion):
        tried = ", ".join(f"{a.method} {a.residual:.3f}/{a.distortion:.2f}"
                          for a, _ in scored)
        lead = "" if overlay_refusal is None else f"{overlay_refusal} (no overlay) and "
        raise LbshapeError(
            f"example does not correspond to the object: {lead}LB basis alignment residual "
            f"{best.residual:.3f} (limit {max_residual:g}), spectral distortion "
            f"{best.distortion:.2f} (limit {max_distortion:g}) with the {best.method} map "
            f"(residual/distortion: {tried})")
    return best, spectrum


def transfer_error(C: np.ndarray, object_spectrum: LBSpectrum, object_values: np.ndarray,
                   example_spectrum: LBSpectrum, example_values: np.ndarray) -> float:
    """Relative M-norm error of a function transferred through C against the same
    function computed directly on the example, within what the bases hold.

    The object's f (n_o,) becomes ``Φ_ex C Φ_objᵀ M_obj f``; the example's own g (n_e,)
    is projected onto span(Φ_ex C) (the image of the object's m modes), so only the map's
    error counts, not the truncation. ``C`` (m_ex, m); ``example_spectrum`` holds at
    least m_ex eigenpairs.
    """
    a = object_spectrum.eigenvectors.T @ (object_spectrum.mass @ object_values)
    phi = example_spectrum.eigenvectors[:, : C.shape[0]] @ C
    M = example_spectrum.mass
    transferred = phi @ a
    direct = phi @ (phi.T @ (M @ example_values))
    diff = transferred - direct
    return float(np.sqrt(diff @ (M @ diff) / (direct @ (M @ direct))))
