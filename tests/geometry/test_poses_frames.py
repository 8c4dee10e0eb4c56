"""Analytic poses and body frames: checked against closed-form geometry."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import golden
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh, check_mesh, gmsh_model, mesh_from_gmsh_model
from lbshape.geometry.poses import POSES, apply_pose, arc, pose_parameters, s_bend, twist
from lbshape.geometry.primitives import box, cylinder, structured_box
from lbshape.geometry.shapes import build_shape
from lbshape.shapespace.frames import (
    MAX_RELATIVE_RMS,
    _third_moments,
    align_to_object,
    body_frame,
)

BAR_DIV = (4, 4, 16)


@pytest.fixture(scope="module")
def bar() -> TetMesh:
    """0.2 x 0.2 x 1 m bar along z in [0, 1], centred on the z axis."""
    return structured_box((0.2, 0.2, 1.0), BAR_DIV, (-0.1, -0.1, 0.0))


def _edges(mesh: TetMesh) -> np.ndarray:
    pairs = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    e = np.concatenate([mesh.tets[:, list(p)] for p in pairs])
    return np.unique(np.sort(e, axis=1), axis=0)


def _max_edge_strain(rest: np.ndarray, posed: np.ndarray, edges: np.ndarray) -> float:
    l0 = np.linalg.norm(rest[edges[:, 0]] - rest[edges[:, 1]], axis=1)
    l1 = np.linalg.norm(posed[edges[:, 0]] - posed[edges[:, 1]], axis=1)
    return float(np.max(np.abs(l1 / l0 - 1.0)))


def _asymmetric(mesh: TetMesh) -> TetMesh:
    """A doubly tapered, curved box: no symmetry, so its frame is unambiguous."""
    x, y, z = mesh.points.T
    return mesh.with_points(np.column_stack(
        [x, y * (1 - 0.6 * x) + 0.2 * x**2, z * (1 - 0.7 * y) * (1 - 0.3 * x)]))


# ---------------------------------------------------------------- poses


@pytest.mark.parametrize("profile", ["linear", "smooth"])
def test_twist_angle_along_the_bar(bar, profile):
    angle = 1.2
    posed = twist(bar.points, angle=angle, profile=profile)
    z = bar.points[:, 2]
    off_axis = np.hypot(bar.points[:, 0], bar.points[:, 1]) > 1e-9
    turned = (np.arctan2(posed[:, 1], posed[:, 0])
              - np.arctan2(bar.points[:, 1], bar.points[:, 0]))
    turned = (turned + np.pi) % (2 * np.pi) - np.pi
    expected = angle * (z if profile == "linear" else z * z * (3 - 2 * z))
    err = np.abs(turned - expected)[off_axis].max()
    assert err < 1e-12, f"twist angle error {err:.2e} rad"
    np.testing.assert_allclose(posed[z == 0.0], bar.points[z == 0.0], atol=1e-15)
    np.testing.assert_allclose(posed[:, 2], z, atol=0)
    np.testing.assert_allclose(np.hypot(posed[:, 0], posed[:, 1]),
                               np.hypot(bar.points[:, 0], bar.points[:, 1]), rtol=1e-13)


def test_twist_anchor_max_keeps_the_top(bar):
    posed = twist(bar.points, angle=0.8, anchor="max")
    top, bottom = bar.points[:, 2] == 1.0, bar.points[:, 2] == 0.0
    np.testing.assert_allclose(posed[top], bar.points[top], atol=1e-15)
    expected = bar.points[bottom] @ Rotation.from_rotvec([0, 0, 0.8]).as_matrix().T
    np.testing.assert_allclose(posed[bottom], expected, atol=1e-14)


def test_twist_edge_strain_within_shear_bound(bar):
    """Linear twist is a simple shear of amount γ = r θ' ≤ r_max·angle/L per point;
    an edge stretches by at most γ/2 + γ²/2."""
    angle = 0.6
    gamma = np.hypot(0.1, 0.1) * angle
    strain = _max_edge_strain(bar.points, twist(bar.points, angle=angle), _edges(bar))
    assert 0.2 * gamma < strain <= gamma / 2 + gamma**2 / 2, f"edge strain {strain:.4f}"


def test_arc_centreline_is_a_circle_of_the_right_length(bar):
    angle = 1.0
    posed = arc(bar.points, angle=angle, direction="x")
    on_axis = np.hypot(bar.points[:, 0], bar.points[:, 1]) < 1e-12
    s = bar.points[on_axis, 2]
    R = 1.0 / angle
    expected = np.column_stack([R * (1 - np.cos(s / R)), 0 * s, R * np.sin(s / R)])
    err = np.abs(posed[on_axis] - expected).max()
    assert err < 1e-8, f"arc centreline error {err:.2e} m"
    # cross-sections stay rigid: the far end is rotated by `angle` about y
    top = bar.points[:, 2] == 1.0
    local = posed[top] - expected[-1]
    rot = Rotation.from_rotvec([0.0, angle, 0.0]).as_matrix()
    sections = (bar.points[top] - [0.0, 0.0, 1.0]) @ rot.T
    assert np.abs(local - sections).max() < 1e-8


def test_bends_are_isometric_on_the_centreline_and_bounded_elsewhere(bar):
    line = np.column_stack([np.zeros(4001), np.zeros(4001), np.linspace(0, 1, 4001)])
    box_corners = np.array([[-0.1, -0.1, 0.0], [0.1, 0.1, 0.0]])
    pts = np.vstack([line, box_corners])  # the same bounding box as the bar
    for name, params in [("s-bend", {"amplitude": 0.3, "direction": "y"}),
                         ("arc", {"angle": 1.3, "direction": "x"})]:
        posed = POSES[name](pts, **params)[:4001]
        length = np.linalg.norm(np.diff(posed, axis=0), axis=1).sum()
        assert abs(length - 1.0) < 1e-6, f"{name}: centreline length {length:.8f}"
    posed = s_bend(bar.points, amplitude=0.3, direction="y")
    tip = (bar.points[:, 2] == 1.0) & (np.abs(bar.points[:, :2]).sum(axis=1) < 1e-12)
    assert abs(posed[tip, 1][0] - 0.3) < 1e-6, f"s-bend end offset {posed[tip, 1][0]}"
    top = bar.points[:, 2] == 1.0  # tangent axial at the far end: a flat, level section
    assert np.ptp(posed[top, 2]) < 1e-9
    # off the centreline, fibres stretch by at most |d| κ_max (bending)
    psi_max = 1.0  # bound on ψ_max for amplitude 0.3 (solved value ≈ 0.53)
    kappa = np.pi * psi_max
    strain = _max_edge_strain(bar.points, posed, _edges(bar))
    assert strain <= 0.1 * kappa, f"s-bend edge strain {strain:.4f}"


def test_apply_pose_returns_same_connectivity(bar):
    posed = apply_pose(bar, "arc", angle=0.5, direction="y", anchor="max")
    assert posed.tets is bar.tets
    assert (posed.signed_volumes() > 0).all()
    top = bar.points[:, 2] == 1.0
    np.testing.assert_allclose(posed.points[top], bar.points[top], atol=1e-12)


def test_extreme_twist_is_reported_as_inverting():
    coarse = structured_box((0.2, 0.2, 1.0), (1, 1, 2), (-0.1, -0.1, 0.0))
    apply_pose(coarse, "twist", angle=2.0)  # still valid
    with pytest.raises(LbshapeError, match=r"inverts \d+ of 12 tetrahedra"):
        apply_pose(coarse, "twist", angle=4.0)


@pytest.mark.parametrize(
    ("name", "params", "message"),
    [
        ("bend", {"angle": 1.0}, "unknown pose 'bend'; valid poses: arc, s-bend, twist"),
        ("twist", {"angel": 1.0}, "no parameter"),
        ("twist", {}, "needs parameter"),
        ("twist", {"angle": float("nan")}, "finite number"),
        ("twist", {"angle": "1"}, "finite number"),
        ("twist", {"angle": 1.0, "axis": "w"}, "axis must be one of"),
        ("twist", {"angle": 1.0, "profile": "cubic"}, "profile must be one of"),
        ("arc", {"angle": 1.0, "direction": "z"}, "must differ from the axis"),
        ("s-bend", {"amplitude": 0.9}, "out of range"),
        ("arc", {"angle": 1.0, "anchor": "top"}, "anchor must be one of"),
    ],
)
def test_bad_pose_input(bar, name, params, message):
    with pytest.raises(LbshapeError, match=message):
        apply_pose(bar, name, **params)


def test_pose_parameters_are_listed():
    assert pose_parameters("twist") == (("angle",), ("axis", "profile", "anchor"))
    assert pose_parameters("s-bend")[0] == ("amplitude",)


# ---------------------------------------------------------------- frames


def test_box_frame_matches_analytic_moments():
    a, b, c = 0.9, 0.5, 0.3
    origin = np.array([0.2, -0.4, 1.0])
    mesh = box((a, b, c), 0.15, tuple(origin))
    R = Rotation.from_rotvec([0.4, -0.7, 1.1]).as_matrix()
    shift = np.array([1.0, 2.0, -3.0])
    moved = mesh.with_points(mesh.points @ R.T + shift)
    frame = body_frame(moved)
    V = a * b * c
    assert abs(frame.volume - V) < 1e-13 * V
    np.testing.assert_allclose(frame.origin, R @ (origin + [a / 2, b / 2, c / 2]) + shift,
                               rtol=0, atol=1e-13)
    np.testing.assert_allclose(frame.second_moments, V * np.array([a, b, c]) ** 2 / 12,
                               rtol=1e-12)
    inertia = V / 12 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])
    np.testing.assert_allclose(frame.inertia, R @ inertia @ R.T, rtol=0, atol=1e-14)
    # principal axes are the rotated coordinate axes (up to sign); a box is symmetric
    np.testing.assert_allclose(np.abs(frame.axes), np.abs(R), atol=1e-10)
    assert frame.ambiguous_signs.all() and frame.ambiguous
    assert np.linalg.det(frame.axes) == pytest.approx(1.0, abs=1e-12)


def test_third_moment_of_unit_tetrahedron_is_exact():
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    mu = _third_moments(pts, np.array([[0, 1, 2, 3]]), np.full(3, 0.25), np.eye(3))
    np.testing.assert_allclose(mu, 1.0 / 960.0, rtol=1e-13)


def test_rigidly_moved_asymmetric_shape_has_the_moved_frame():
    shape = _asymmetric(structured_box((1.0, 0.6, 0.4), (5, 3, 2)))
    frame = body_frame(shape)
    assert not frame.ambiguous, f"third moments {frame.third_moments}"
    R = Rotation.from_rotvec([2.0, 0.5, -1.0]).as_matrix()
    t = np.array([3.0, -1.0, 0.5])
    moved = body_frame(shape.with_points(shape.points @ R.T + t))
    np.testing.assert_allclose(moved.axes, R @ frame.axes, atol=1e-12)
    np.testing.assert_allclose(moved.origin, R @ frame.origin + t, atol=1e-12)
    pts = shape.points[:7]
    np.testing.assert_allclose(frame.from_frame(frame.to_frame(pts)), pts, atol=1e-14)
    np.testing.assert_allclose(moved.to_frame(pts @ R.T + t), frame.to_frame(pts), atol=1e-12)


def test_alignment_normalises_volume_and_lands_on_the_object():
    shape = _asymmetric(structured_box((1.0, 0.6, 0.4), (5, 3, 2)))
    R = Rotation.from_rotvec([0.3, -1.2, 2.0]).as_matrix()
    copy = shape.points @ R.T * 1.7 + [1.0, 2.0, 3.0]
    aligned = align_to_object(copy, shape.tets, body_frame(shape))
    assert aligned.candidates == 1 and aligned.icp_rms is None
    assert aligned.scale == pytest.approx(1 / 1.7, rel=1e-12)
    err = np.abs(aligned.points - shape.points).max()
    assert err < 1e-12, f"aligned copy is {err:.2e} m off the object"
    np.testing.assert_allclose(aligned.apply(copy), aligned.points, atol=1e-14)
    vol = np.abs(shape.with_points(aligned.points).signed_volumes()).sum()
    assert abs(vol - shape.volume()) < 1e-12 * shape.volume()


def test_symmetric_remesh_in_place_keeps_its_orientation():
    obj = box((1.0, 0.6, 0.4), 0.12)
    other = box((1.0, 0.6, 0.4), 0.09)
    aligned = align_to_object(other.points, other.tets, body_frame(obj),
                              reference_points=obj.points)
    assert aligned.candidates == 4  # sign flips of a mirror-symmetric box
    angle = np.arccos(np.clip((np.trace(aligned.rotation) - 1) / 2, -1, 1))
    assert angle < 1e-6, f"rotation of {angle:.2e} rad applied to a copy in place"


def test_degenerate_cube_rotated_copy_is_resolved_by_icp():
    cube = structured_box((1.0, 1.0, 1.0), (3, 3, 3))
    R = Rotation.from_rotvec([0.5, 0.2, -0.3]).as_matrix()
    copy = cube.points @ R.T * 2.0
    aligned = align_to_object(copy, cube.tets, body_frame(cube),
                              reference_points=cube.points)
    assert aligned.candidates == 24
    assert aligned.icp_rms < 1e-8, f"ICP RMS {aligned.icp_rms:.2e} m"
    # the aligned copy coincides with the cube up to one of its symmetries
    d, _ = cKDTree(cube.points).query(aligned.points)
    assert d.max() < 1e-8


def _ball(h: float) -> TetMesh:
    """Unstructured gmsh mesh of the unit ball (radius 1 m, edge length ``h`` m)."""
    with gmsh_model("ball") as gmsh:
        gmsh.model.occ.addSphere(0.0, 0.0, 0.0, 1.0)
        gmsh.model.occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMin", h)
        gmsh.option.setNumber("Mesh.MeshSizeMax", h)
        gmsh.option.setNumber("Mesh.RandomSeed", 1)
        gmsh.model.mesh.generate(3)
        return check_mesh(mesh_from_gmsh_model(gmsh.model, source="ball"), source="ball")


@pytest.fixture(scope="module")
def degenerate_shapes() -> dict[str, tuple[TetMesh, list[int]]]:
    """Meshes with degenerate principal moments and their expected cluster labels:
    isotropic (a cube, a ball) or with exactly two equal moments (a square-section
    box, a cylinder). All are unstructured, so only one rotation (or a symmetry of
    the vertex set) puts a copy exactly on the original."""
    return {
        "cube": (box((1.0, 1.0, 1.0), 0.25), [0, 0, 0]),
        "ball": (_ball(0.3), [0, 0, 0]),
        "square box": (box((1.0, 1.0, 2.0), 0.25), [0, 1, 1]),
        "cylinder": (cylinder(0.3, 1.0, 0.12), [0, 1, 1]),
    }


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("shape", ["cube", "ball", "square box", "cylinder"])
def test_rotated_scaled_copy_of_a_degenerate_shape_lands_on_it(degenerate_shapes, shape, seed):
    mesh, clusters = degenerate_shapes[shape]
    frame = body_frame(mesh)
    np.testing.assert_array_equal(frame.degenerate, clusters,
                                  err_msg=f"moments {frame.second_moments}")
    rng = np.random.default_rng(seed)
    R = Rotation.random(random_state=rng).as_matrix()
    copy = 1.7 * mesh.points @ R.T + rng.normal(size=3)
    aligned = align_to_object(copy, mesh.tets, frame, reference_points=mesh.points)
    assert aligned.icp_rms < 1e-8, f"ICP RMS {aligned.icp_rms:.2e} m"
    d, _ = cKDTree(mesh.points).query(aligned.points)
    assert d.max() < 1e-8, f"aligned copy is {d.max():.2e} m off the object"


@pytest.mark.parametrize("seed", range(5))
def test_cube_alignment_does_not_depend_on_the_eigensolver_basis(monkeypatch, seed):
    """Inside a degenerate eigenspace any orthonormal basis is correct and another
    LAPACK may return another one: rotate the basis of every isotropic tensor."""
    cube = structured_box((1.0, 1.0, 1.0), (3, 3, 3))
    rng = np.random.default_rng(seed)
    Q = Rotation.random(random_state=rng).as_matrix()
    eigh = np.linalg.eigh

    def other_basis(a):
        values, vectors = eigh(a)
        isotropic = np.ptp(values) <= 1e-12 * np.abs(values).max()
        return values, vectors @ Q if isotropic else vectors

    monkeypatch.setattr(np.linalg, "eigh", other_basis)
    R = Rotation.from_rotvec([0.5, 0.2, -0.3]).as_matrix()
    aligned = align_to_object(cube.points @ R.T * 2.0, cube.tets, body_frame(cube),
                              reference_points=cube.points)
    assert aligned.icp_rms < 1e-8, f"ICP RMS {aligned.icp_rms:.2e} m"


@pytest.mark.parametrize("pair", [("demo-bar", "demo-cylinder"), ("bar-cuboid", "bar-cylinder")])
def test_builtin_cross_topology_pairs_pass_the_residual_check_with_margin(pair):
    """Cuboid bar vs cylinder examples of the built-in scenes: measured relative RMS
    0.121 (demo) and 0.086 (bar), well below the threshold."""
    obj, example = (build_shape(name) for name in pair)
    aligned = align_to_object(example.points, example.tets, body_frame(obj),
                              reference_points=obj.points)
    margin = golden("poses_frames.cross_topology_relative_rms").limit
    assert aligned.relative_rms < margin * MAX_RELATIVE_RMS, \
        f"relative RMS {aligned.relative_rms:.3f} vs threshold {MAX_RELATIVE_RMS}"


def test_mismatched_example_is_refused_with_a_one_line_error(bar):
    cube = box((0.585, 0.585, 0.585), 0.1)  # the bar's volume, not its shape
    with pytest.raises(LbshapeError, match=r"^example 2 \(cube\): example does not correspond to "
                       r"the object: frame alignment residual 0\.\d+ exceeds 0\.2 ") as info:
        align_to_object(cube.points, cube.tets, body_frame(bar), reference_points=bar.points,
                        name="example 2 (cube)")
    assert "\n" not in str(info.value)
    # without a threshold the residual is reported, and it is clearly above it
    aligned = align_to_object(cube.points, cube.tets, body_frame(bar),
                              reference_points=bar.points, max_relative_rms=None)
    assert aligned.relative_rms > 1.25 * MAX_RELATIVE_RMS, f"{aligned.relative_rms:.3f}"
