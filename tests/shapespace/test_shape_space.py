"""Shape-space descriptors, displacement coefficients and direct projections."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from conftest import observed_rates
from scipy.spatial.transform import Rotation

from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh
from lbshape.geometry.poses import apply_pose
from lbshape.geometry.primitives import box, cylinder, structured_box
from lbshape.shapespace.alignment import align_bases, pose_basis_map
from lbshape.shapespace.frames import align_to_object, body_frame
from lbshape.shapespace.projections import (
    ShapeSpace,
    block_basis,
    descriptor_matrix,
    descriptors,
    direct_projection,
    embed_example,
    example_coefficients_via_posed_basis,
    example_displacement_coefficients,
    lb_coefficients,
    make_shape_space,
    offered_spectrum,
    reconstruct,
    reduced_projection,
)
from lbshape.spectral.spectrum import lb_spectrum

M_MODES = 8


@pytest.fixture(scope="module")
def bar() -> TetMesh:
    return structured_box((0.2, 0.2, 1.0), (4, 4, 16), (-0.1, -0.1, 0.0))


@pytest.fixture(scope="module")
def bar_spectrum(bar):
    return lb_spectrum(bar, M_MODES)


def _mass_orthonormal_basis(rng, mass, n, r):
    """A random (3n, r) U with Uᵀ M₃ U = I."""
    M3 = sp.kron(mass, sp.identity(3), format="csr")
    U = rng.normal(size=(3 * n, r))
    chol = np.linalg.cholesky(U.T @ (M3 @ U))
    return np.linalg.solve(chol, U.T).T, M3


def test_first_descriptor_of_a_box_converges_at_second_order():
    """Box [0,2]x[0,1]x[0,1]: φ₁ = ±cos(πx/2) (M-normalised), λ₁ = π²/4, so
    l₁ = λ₁⟨p, φ₁⟩_M = (∓2, 0, 0) exactly in the continuum."""
    errors, h = [], []
    for k in (2, 4, 8):
        mesh = structured_box((2.0, 1.0, 1.0), (2 * k, k, k))
        spec = lb_spectrum(mesh, 1)
        l1 = descriptors(mesh.points, spec.eigenvalues, spec.eigenvectors, spec.mass)[0]
        errors.append(abs(abs(l1[0]) - 2.0) + abs(l1[1]) + abs(l1[2]))
        h.append(1.0 / k)
    rates = observed_rates(errors, h)
    assert errors[-1] < 0.01, f"descriptor errors {errors}"
    assert rates.min() > 1.7 and rates[-1] < 2.3, f"observed rates {rates}, errors {errors}"


def test_displacement_in_the_span_round_trips_exactly(bar, bar_spectrum):
    rng = np.random.default_rng(7)
    phi, M = bar_spectrum.eigenvectors, bar_spectrum.mass
    c = rng.normal(size=(M_MODES, 3)) * 1e-3
    u = phi @ c  # smooth displacement spanned by the first m eigenfunctions
    got = lb_coefficients(u, phi, M)
    np.testing.assert_allclose(got, c, rtol=0, atol=1e-13 * np.abs(c).max())
    p = reconstruct(bar.points, got, phi)
    np.testing.assert_allclose(p, bar.points + u, rtol=0, atol=1e-15)
    # descriptors are λ-weighted coefficients; a translation changes nothing
    d = descriptors(bar.points + u + [0.3, -2.0, 5.0], bar_spectrum.eigenvalues, phi, M)
    d_rest = descriptors(bar.points, bar_spectrum.eigenvalues, phi, M)
    np.testing.assert_allclose((d - d_rest) / bar_spectrum.eigenvalues[:, None], c,
                               rtol=0, atol=1e-9 * np.abs(c).max())


def test_moved_and_scaled_copy_has_zero_displacement(bar, bar_spectrum):
    """No rest mesh given: the object's rest coefficients are subtracted."""
    x, y, z = bar.points.T  # break the bar's symmetry so that the frame is unique
    obj = bar.with_points(np.column_stack([x + 0.05 * z**2, y * (1 + 0.5 * x), z + 0.3 * x]))
    spec = lb_spectrum(obj, M_MODES)
    R = Rotation.from_rotvec([1.0, -0.4, 0.7]).as_matrix()
    copy = 0.6 * obj.points @ R.T + [2.0, 0.0, -1.0]
    aligned = align_to_object(copy, obj.tets, body_frame(obj), reference_points=obj.points)
    ex_spec = lb_spectrum(obj.with_points(aligned.points), M_MODES)
    alignment = align_bases(spec, obj, ex_spec, aligned.points)
    rest = lb_coefficients(obj.points, spec.eigenvectors, spec.mass)
    c = example_displacement_coefficients(aligned.points, ex_spec.eigenvectors, ex_spec.mass,
                                          alignment, object_rest_coefficients=rest)
    relative = np.linalg.norm(c) / np.linalg.norm(rest)
    assert relative < 1e-8, f"displacement of a rigid copy: {relative:.2e} of the rest norm"


def test_arc_examples_on_cylinder_and_cuboid_agree(bar, bar_spectrum):
    """The same arc pose on a cuboid bar and on a cylinder bar gives nearly the same
    displacement coefficients in the cuboid's basis when each example subtracts its
    own rest; the paper's route through the posed spectrum agrees too."""
    obj_frame = body_frame(bar)
    results = {}
    for name, mesh in (("cuboid", bar), ("cylinder", cylinder(0.1128, 1.0, 0.045))):
        aligned = align_to_object(mesh.points, mesh.tets, obj_frame, reference_points=bar.points)
        rest_mesh = mesh.with_points(aligned.points)
        # the example offers extra modes to the alignment, as embed_example does
        rest_spec = offered_spectrum(rest_mesh, M_MODES)
        alignment = align_bases(bar_spectrum, bar, rest_spec, aligned.points)
        posed = aligned.apply(apply_pose(mesh, "arc", angle=1.0, direction="x").points)
        c = example_displacement_coefficients(posed, rest_spec.eigenvectors, rest_spec.mass,
                                              alignment, rest_points=aligned.points)
        posed_spec = lb_spectrum(rest_mesh.with_points(posed), rest_spec.eigenvalues.size)
        pose_map = pose_basis_map(posed_spec, rest_spec.eigenvectors)
        c_paper = example_coefficients_via_posed_basis(
            posed, posed_spec.eigenvectors, posed_spec.mass, aligned.points,
            rest_spec.eigenvectors, rest_spec.mass, pose_map, alignment)
        route_gap = np.linalg.norm(c_paper - c) / np.linalg.norm(c)
        assert route_gap < 0.05, f"{name}: posed-basis route differs by {route_gap:.3f}"
        results[name] = c
    cuboid, cyl = results["cuboid"], results["cylinder"]
    cyl_mesh = cylinder(0.1128, 1.0, 0.045)
    embedded = embed_example(bar, bar_spectrum, cyl_mesh, [
        apply_pose(cyl_mesh, "arc", angle=1.0, direction="x").points, cyl_mesh.points])
    np.testing.assert_allclose(embedded.coefficients[0], cyl, rtol=0, atol=1e-12)
    np.testing.assert_allclose(embedded.coefficients[1], 0.0, atol=1e-15)
    gap = np.linalg.norm(cyl - cuboid) / np.linalg.norm(cuboid)
    # observed 0.03-0.08: the cylinder's near-degenerate mode pairs split differently
    # with the process's floating-point state (e.g. after off-screen rendering); a
    # wrong alignment gives a gap of order 1
    assert gap < 0.10, f"cylinder vs cuboid arc coefficients differ by {gap:.3f}"
    # the cuboid example is the object itself: the arc's reconstruction on the object
    # is the M-projection of the pose's displacement
    u = apply_pose(bar, "arc", angle=1.0, direction="x").points - bar.points
    np.testing.assert_allclose(cuboid, lb_coefficients(u, bar_spectrum.eigenvectors,
                                                       bar_spectrum.mass), atol=1e-12)


def test_embed_example_names_a_mismatched_example(bar, bar_spectrum):
    cube = box((0.585, 0.585, 0.585), 0.1)  # the bar's volume, not its shape
    with pytest.raises(LbshapeError, match=r"^example 2 \(cube\): example does not correspond "
                                           r"to the object: frame alignment residual [^\n]*$"):
        embed_example(bar, bar_spectrum, cube, [cube.points], name="example 2 (cube)")


def test_direct_projection_matches_explicit_products(bar, bar_spectrum):
    rng = np.random.default_rng(11)
    n, m, r = bar.n_vertices, M_MODES, 12
    phi, M = bar_spectrum.eigenvectors, bar_spectrum.mass
    U, M3 = _mass_orthonormal_basis(rng, M, n, r)
    T = direct_projection(U, phi, M)
    assert T.shape == (r, 3 * m)
    L = block_basis(phi)
    np.testing.assert_allclose(T, U.T @ (M3 @ L), rtol=0, atol=1e-12 * np.abs(T).max())
    # Tᵀ q equals the LB coefficients of u = U q computed directly
    q = rng.normal(size=r)
    u = (U @ q).reshape(n, 3)
    direct = lb_coefficients(u, phi, M).ravel()
    np.testing.assert_allclose(T.T @ q, direct, rtol=0, atol=1e-12 * np.abs(direct).max())
    # with U = L itself the projection is the identity
    T_self = direct_projection(L, phi, M)
    err = np.abs(T_self - np.eye(3 * m)).max()
    assert err < 1e-12, f"T(L) deviates from I by {err:.2e}"
    with pytest.raises(LbshapeError, match="basis must have shape"):
        direct_projection(U[:-1], phi, M)


def test_shape_space_runtime_matrices(bar, bar_spectrum):
    rng = np.random.default_rng(5)
    n, m, r, rho = bar.n_vertices, M_MODES, 10, 1000.0
    phi, M, lam = bar_spectrum.eigenvectors, bar_spectrum.mass, bar_spectrum.eigenvalues
    U, _ = _mass_orthonormal_basis(rng, M, n, r)
    U = U / np.sqrt(rho)  # orthonormal in the elastic mass ρ M₃
    examples = rng.normal(size=(2, m, 3))
    fake = [type("A", (), {"residual": 0.1, "method": "overlay"})(),
            type("A", (), {"residual": 0.2, "method": "intrinsic"})()]
    space = make_shape_space(lam, phi, M, bar.points, U, examples, fake, ["a", "b"],
                             density=rho)
    assert (space.m, space.r) == (m, r)
    q = rng.normal(size=r)
    expected = (lam[:, None] * lb_coefficients((U @ q).reshape(n, 3), phi, M)).ravel()
    np.testing.assert_allclose(space.descriptor_matrix @ q, expected, rtol=1e-12,
                               atol=1e-12 * np.abs(expected).max())
    np.testing.assert_allclose(space.example_descriptors[1],
                               (lam[:, None] * examples[1]).ravel(), rtol=1e-14)
    np.testing.assert_allclose(space.example_reduced, examples.reshape(2, -1) @ space.projection.T)
    np.testing.assert_allclose(space.rest_coefficients, lb_coefficients(bar.points, phi, M))
    np.testing.assert_allclose(space.alignment_residuals, [0.1, 0.2])
    assert space.alignment_methods == ("overlay", "intrinsic")
    with pytest.raises(LbshapeError, match="example coefficients must be"):
        ShapeSpace(lam, examples[:, :3], space.projection, space.rest_coefficients,
                   space.alignment_residuals, ("a", "b"), rho)


@pytest.mark.parametrize("rho", [1.0, 1000.0, 7.5])
def test_reduced_projection_is_the_mass_projection_onto_the_basis(bar, bar_spectrum, rho):
    """The density convention, checked against explicit full-space products: for U
    orthonormal in the elastic mass M = ρ M₃, ``U (T c)`` is the M-orthogonal projection
    of ``L c`` onto span U, and ``D q`` the λ-weighted LB coefficients of ``U q``. A
    missed or doubled density factor (×√ρ, ×ρ) fails both for ρ ≠ 1."""
    rng = np.random.default_rng(3)
    n, m, r = bar.n_vertices, M_MODES, 12
    phi, M1, lam = bar_spectrum.eigenvectors, bar_spectrum.mass, bar_spectrum.eigenvalues
    U3, M3 = _mass_orthonormal_basis(rng, M1, n, r)
    U = U3 / np.sqrt(rho)
    M = rho * M3  # the elastic mass (kg)
    np.testing.assert_allclose(U.T @ (M @ U), np.eye(r), atol=1e-12)
    T = reduced_projection(U, phi, M1, rho)
    L = block_basis(phi)
    c = rng.normal(size=3 * m)
    target = L @ c
    # the M-projection onto span U, solved from its normal equations (not from UᵀMU = I)
    gram = U.T @ (M @ U)
    projected = U @ np.linalg.solve(gram, U.T @ (M @ target))
    np.testing.assert_allclose(U @ (T @ c), projected, rtol=0,
                               atol=1e-10 * np.abs(projected).max())
    # the residual is M-orthogonal to the basis
    residual = target - U @ (T @ c)
    assert np.abs(U.T @ (M @ residual)).max() < 1e-10 * np.abs(U.T @ (M @ target)).max()
    # the descriptor of U q, computed on the full-space field
    q = rng.normal(size=r)
    expected = (lam[:, None] * lb_coefficients((U @ q).reshape(n, 3), phi, M1)).ravel()
    np.testing.assert_allclose(descriptor_matrix(lam, T, rho) @ q, expected, rtol=0,
                               atol=1e-10 * np.abs(expected).max())


def test_bad_shapes_are_refused(bar, bar_spectrum):
    phi = bar_spectrum.eigenvectors
    with pytest.raises(LbshapeError, match=r"expected an \(\d+, 3\) array"):
        lb_coefficients(bar.points[:-1], phi, bar_spectrum.mass)
    with pytest.raises(LbshapeError, match="coefficients must have shape"):
        reconstruct(bar.points, np.zeros((M_MODES + 1, 3)), phi)
