"""Aligning example LB bases to the object's: remeshed, moved, sign-flipped,
degenerate, cross-topology and unrelated examples."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.linalg import subspace_angles
from scipy.spatial.transform import Rotation

from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh
from lbshape.geometry.poses import apply_pose
from lbshape.geometry.primitives import box, cylinder, structured_box
from lbshape.shapespace.alignment import (
    align_bases,
    compose,
    interpolation_matrix,
    pose_basis_map,
    scaled_spectrum,
)
from lbshape.shapespace.frames import MAX_RELATIVE_RMS, align_to_object, body_frame
from lbshape.spectral.spectrum import lb_spectrum


def _asymmetric(mesh: TetMesh) -> TetMesh:
    x, y, z = mesh.points.T
    return mesh.with_points(np.column_stack(
        [x, y * (1 - 0.6 * x) + 0.2 * x**2, z * (1 - 0.7 * y) * (1 - 0.3 * x)]))


def _align(obj: TetMesh, example: TetMesh, m: int, *, max_relative_rms=MAX_RELATIVE_RMS,
           **kwargs):
    """Frame-align ``example`` to ``obj``, compute both spectra, align the bases."""
    obj_spec = lb_spectrum(obj, m)
    aligned = align_to_object(example.points, example.tets, body_frame(obj),
                              reference_points=obj.points, max_relative_rms=max_relative_rms)
    ex_spec = lb_spectrum(example.with_points(aligned.points), m)
    return obj_spec, ex_spec, aligned, align_bases(obj_spec, obj, ex_spec, aligned.points,
                                                   **kwargs)


@pytest.fixture(scope="module")
def bar() -> TetMesh:
    return structured_box((0.2, 0.2, 1.0), (4, 4, 16), (-0.1, -0.1, 0.0))


def test_interpolation_is_exact_for_affine_fields_and_projects_outside_points():
    mesh = box((1.0, 0.5, 0.4), 0.15)
    rng = np.random.default_rng(3)
    inside = rng.uniform([0, 0, 0], [1.0, 0.5, 0.4], size=(300, 3))
    outside = np.array([[1.05, 0.25, 0.2], [0.5, -0.02, 0.41], [-0.03, 0.6, -0.01]])
    W, out = interpolation_matrix(mesh, np.vstack([inside, outside]))
    assert not out[:300].any() and out[300:].all()
    np.testing.assert_allclose(W.sum(axis=1), 1.0, rtol=1e-13)
    A, b = rng.normal(size=(3, 2)), rng.normal(size=2)
    values = W @ (mesh.points @ A + b)
    err = np.abs(values[:300] - (inside @ A + b)).max()
    assert err < 1e-12, f"affine interpolation error {err:.2e}"
    nearest = np.clip(outside, 0, [1.0, 0.5, 0.4])  # closest boundary points of the box
    np.testing.assert_allclose(values[300:], nearest @ A + b, atol=1e-12)


def test_scaled_spectrum_equals_spectrum_of_scaled_mesh():
    mesh = box((1.0, 0.6, 0.4), 0.15)
    ref = lb_spectrum(mesh.with_points(2.5 * mesh.points), 5)
    scaled = scaled_spectrum(lb_spectrum(mesh, 5), 2.5)
    np.testing.assert_allclose(scaled.eigenvalues, ref.eigenvalues, rtol=1e-9)
    np.testing.assert_allclose(scaled.eigenvectors, ref.eigenvectors, atol=1e-8 * 2.5**-1.5)
    assert abs(scaled.mass - ref.mass).max() < 1e-12 * abs(ref.mass).max()


def test_remeshed_copy_aligns_with_signs_only():
    """A box at two resolutions: C is diagonal up to the remeshing error, and its
    signs are the relative signs of the two meshes' eigenfunctions at the point
    where the object's eigenfunction peaks (the sign rule breaks symmetric ties by
    vertex index, so remeshed copies may legitimately differ in sign)."""
    obj, ex = box((1.0, 0.6, 0.4), 0.1), box((1.0, 0.6, 0.4), 0.07)
    obj_spec, ex_spec, aligned, result = _align(obj, ex, 6)
    expected = []
    for i in range(6):
        peak = np.argmax(np.abs(obj_spec.eigenvectors[:, i]))
        j = np.argmin(np.linalg.norm(aligned.points - obj.points[peak], axis=1))
        expected.append(np.sign(ex_spec.eigenvectors[j, i] * obj_spec.eigenvectors[peak, i]))
    deviation = np.linalg.norm(result.C - np.diag(expected))
    assert deviation < 0.1, f"||C - diag(signs)|| = {deviation:.3e}\n{result.C.round(3)}"
    assert result.residual < 0.05, f"residual {result.residual:.3e}"


def test_rotated_scaled_copy_aligns_to_identity():
    obj = _asymmetric(structured_box((1.0, 0.6, 0.4), (8, 5, 4)))
    R = Rotation.from_rotvec([0.3, -1.2, 2.0]).as_matrix()
    raw = obj.with_points(1.7 * obj.points @ R.T + [1.0, 2.0, 3.0])
    obj_spec = lb_spectrum(obj, 6)
    aligned = align_to_object(raw.points, raw.tets, body_frame(obj))
    # spectrum of the raw example, rescaled analytically to the object's volume
    ex_spec = scaled_spectrum(lb_spectrum(raw, 6), aligned.scale)
    result = align_bases(obj_spec, obj, ex_spec, aligned.points)
    deviation = np.linalg.norm(result.C - np.eye(6))
    assert deviation < 1e-6, f"||C - I|| = {deviation:.3e}"
    assert result.residual < 1e-6 and result.outside_fraction < 0.05


def test_flipped_signs_are_recovered_exactly_also_with_landmarks():
    obj = box((1.0, 0.6, 0.4), 0.12)
    spec = lb_spectrum(obj, 6)
    signs = np.array([1.0, -1.0, -1.0, 1.0, -1.0, 1.0])
    flipped = dataclasses.replace(spec, eigenvectors=spec.eigenvectors * signs)
    result = align_bases(spec, obj, flipped, obj.points)
    deviation = np.linalg.norm(result.C - np.diag(signs))
    assert deviation < 1e-10, f"||C - diag(signs)|| = {deviation:.3e}"
    pairs = np.column_stack([np.arange(0, obj.n_vertices, 17)] * 2)
    with_landmarks = align_bases(spec, obj, flipped, obj.points, landmarks=pairs,
                                 landmark_weight=100.0)
    assert np.linalg.norm(with_landmarks.C - np.diag(signs)) < 1e-10
    with pytest.raises(LbshapeError, match="landmark vertex index out of range"):
        align_bases(spec, obj, flipped, obj.points, landmarks=np.array([[0, 10**6]]))


def test_degenerate_cube_aligns_as_subspaces():
    obj, ex = structured_box((1.0, 1.0, 1.0), (5, 5, 5)), box((1.0, 1.0, 1.0), 0.15)
    obj_spec, ex_spec, aligned, result = _align(obj, ex, 6)
    clusters = [slice(0, 3), slice(3, 6)]  # (π², 2π²) triples; λ₇ = 3π² is simple
    lam = obj_spec.eigenvalues
    assert np.ptp(lam[0:3]) < 0.01 * lam[0] and np.ptp(lam[3:6]) < 0.05 * lam[3], lam
    assert lam[3] > 1.8 * lam[2], lam
    W, _ = interpolation_matrix(obj, aligned.points)
    F = W @ obj_spec.eigenvectors
    mapped = ex_spec.eigenvectors @ result.C
    for cl in clusters:
        angles = subspace_angles(mapped[:, cl], F[:, cl])
        assert angles.max() < 0.15, f"principal angles {angles} rad in cluster {cl}"
        off = np.abs(np.delete(result.C[:, cl], np.r_[cl], axis=0)).max()
        assert off < 0.05, f"C leaks {off:.3f} out of the eigenvalue cluster {cl}"
    # the cluster blocks are genuine rotations, not the identity
    assert np.abs(result.C[0:3, 0:3] - np.eye(3)).max() > 0.1
    assert result.residual < 0.1, f"residual {result.residual:.3f}"


def test_cylinder_bar_aligns_with_cuboid_bar_on_axial_modes(bar):
    cyl = cylinder(0.1128, 1.0, 0.045)
    obj_spec, _, _, result = _align(bar, cyl, 8)
    z = bar.points[:, 2]
    levels = np.unique(z)
    phi = obj_spec.eigenvectors

    def within_slice_variance(f):
        return sum(np.sum((f[z == lv] - f[z == lv].mean()) ** 2) for lv in levels) / np.sum(
            (f - f.mean()) ** 2)

    ratios = np.array([within_slice_variance(phi[:, i]) for i in range(8)])
    axial = np.flatnonzero(ratios < 1e-2)[:4]  # functions of z only: cos(kπz), k = 1..4
    np.testing.assert_array_equal(axial, [0, 1, 2, 3], err_msg=f"ratios {ratios}")
    block = result.C[np.ix_(axial, axial)]
    deviation = np.abs(np.abs(block) - np.eye(4)).max()
    assert deviation < 0.03, f"axial block of C deviates by {deviation:.3f}\n{block.round(3)}"
    assert result.per_mode_residual[axial].max() < 0.1, result.per_mode_residual


def test_unrelated_shape_is_refused(bar):
    """The frame alignment refuses a cube for a bar first; without that check the LB
    basis alignment refuses it too."""
    cube = box((0.585, 0.585, 0.585), 0.1)
    with pytest.raises(LbshapeError, match=r"frame alignment residual 0\.\d+ exceeds 0\.2"):
        _align(bar, cube, 6)
    with pytest.raises(LbshapeError, match=r"residual 0\.\d+ exceeds 0\.5"):
        _align(bar, cube, 6, max_relative_rms=None)


def test_too_many_modes_for_the_example_is_refused(bar):
    tiny = structured_box((0.2, 0.2, 1.0), (1, 1, 1), (-0.1, -0.1, 0.0))
    with pytest.raises(LbshapeError, match="too large for a mesh with 8 vertices"):
        lb_spectrum(tiny, 10)
    obj_spec = lb_spectrum(bar, 10)
    aligned = align_to_object(tiny.points, tiny.tets, body_frame(bar))
    ex_spec = lb_spectrum(tiny.with_points(aligned.points), 5)
    with pytest.raises(LbshapeError, match="has 5 eigenfunctions but the object uses m=10"):
        align_bases(obj_spec, bar, ex_spec, aligned.points)


def test_example_spectrum_at_wrong_volume_is_refused(bar):
    obj_spec = lb_spectrum(bar, 4)
    raw = bar.with_points(2.0 * bar.points)
    with pytest.raises(LbshapeError, match="compute it on the aligned example"):
        align_bases(obj_spec, bar, lb_spectrum(raw, 4), bar.points)


def test_posed_basis_map_composes_with_rest_alignment(bar):
    """Paper route: the example's spectrum on its posed shape, mapped to its rest
    basis (same vertices) and then to the object's."""
    rest_spec = lb_spectrum(bar, 6)
    posed = apply_pose(bar, "twist", angle=0.3)
    posed_spec = lb_spectrum(posed, 6)
    pose_map = pose_basis_map(posed_spec, rest_spec.eigenvectors)
    assert np.abs(np.abs(pose_map.C) - np.eye(6)).max() < 0.05, pose_map.C.round(3)
    assert pose_map.residual < 0.05
    identity = align_bases(rest_spec, bar, rest_spec, bar.points)
    chained = compose(pose_map, identity)
    np.testing.assert_allclose(chained.C, pose_map.C, atol=1e-12)
    assert chained.residual == pytest.approx(pose_map.residual + identity.residual)
