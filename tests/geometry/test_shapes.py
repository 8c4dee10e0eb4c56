"""Built-in shapes: sizes of the paper's Table 2, named groups, volumes, the CLI."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest
from conftest import observed_rates

from lbshape.cli import main
from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import check_mesh, count_components, gmsh_session, load_mesh
from lbshape.geometry.shapes import (
    SHAPES,
    TARGET_RTOL,
    build_shape,
    geometry_volume,
    shape_names,
    write_shape,
)

EPS = 1e-9
#: shapes bounded by planes only: their meshes have the exact volume
PLANAR_VOLUME = {"bar-cuboid": 0.04, "demo-bar": 0.04, "cross": 0.019,
                 "cross-example": 0.019, "cube": 1.0}
#: analytic volume of the cylinder bars, pi r^2 L
CYLINDER_VOLUME = math.pi * 0.1128**2 * 1.0

_meshes: dict[str, object] = {}
#: meshing the 11k-vertex teddy example takes ~17 s on a loaded two-core machine
_SLOW_SHAPES = {"teddy-example"}


def built(name):
    """The mesh of ``name`` at its default size, built once per test session."""
    if name not in _meshes:
        _meshes[name] = build_shape(name)
    return _meshes[name]


def test_registry_names_and_targets():
    assert shape_names() == [
        "bar-cuboid", "bar-cylinder", "cross", "cross-example", "car", "car-example",
        "teddy", "teddy-example", "demo-bar", "demo-cylinder", "cube", "l-beam",
    ]
    table2 = {"bar-cuboid": (327, 1053), "bar-cylinder": (2478, None),
              "cross": (1561, 4912), "cross-example": (3172, None), "car": (727, 2369),
              "car-example": (1019, None), "teddy": (591, 1755),
              "teddy-example": (11193, None)}
    for name, (vertices, tets) in table2.items():
        assert (SHAPES[name].target_vertices, SHAPES[name].target_tets) == (vertices, tets)


@pytest.mark.parametrize(
    "name", [pytest.param(n, marks=pytest.mark.slow) if n in _SLOW_SHAPES else n for n in SHAPES]
)
def test_default_mesh_hits_target_and_is_one_valid_body(name):
    spec = SHAPES[name]
    mesh = built(name)
    n_v, n_t = mesh.n_vertices, mesh.n_tets
    low, high = (1 - TARGET_RTOL) * spec.target_vertices, (1 + TARGET_RTOL) * spec.target_vertices
    assert low <= n_v <= high, f"{name}: {n_v} vertices, target {spec.target_vertices} +-20%"
    if spec.target_tets is not None:
        low, high = (1 - TARGET_RTOL) * spec.target_tets, (1 + TARGET_RTOL) * spec.target_tets
        assert low <= n_t <= high, f"{name}: {n_t} tets, target {spec.target_tets} +-20%"
    assert count_components(n_v, mesh.tets) == 1
    assert np.all(mesh.signed_volumes() > 0), f"{name}: non-positive tetrahedra"
    again = check_mesh(mesh)  # idempotent: nothing dropped or re-oriented
    np.testing.assert_array_equal(again.tets, mesh.tets)
    assert again.n_vertices == n_v


@pytest.mark.parametrize(
    "name", [pytest.param(n, marks=pytest.mark.slow) if n in _SLOW_SHAPES else n for n in SHAPES]
)
def test_named_groups_are_present_and_cover_the_body(name):
    mesh = built(name)
    for group in SHAPES[name].groups:
        assert len(mesh.vertex_groups.get(group, [])) > 0, f"{name}: group {group} empty"
    assert set(mesh.vertex_groups) == set(SHAPES[name].groups)
    # the volume groups partition the tetrahedra: each tet in exactly one group
    owner = np.zeros(mesh.n_tets, dtype=int)
    for cells in mesh.cell_groups.values():
        assert len(cells) > 0
        owner[cells] += 1
    assert owner.min() == 1 and owner.max() == 1, f"{name}: tets in {set(owner)} groups"


def _centroids(mesh, group):
    return mesh.points[mesh.tets[mesh.cell_groups[group]]].mean(axis=1)


@pytest.mark.parametrize("name", ["bar-cuboid", "bar-cylinder", "demo-bar", "demo-cylinder"])
def test_bar_ends_are_where_the_scenes_expect_them(name):
    mesh = built(name)
    top, bottom = mesh.vertex_groups["top"], mesh.vertex_groups["bottom"]
    np.testing.assert_allclose(mesh.points[top, 2], 1.0, rtol=0, atol=EPS)
    np.testing.assert_allclose(mesh.points[bottom, 2], 0.0, rtol=0, atol=EPS)
    ends = np.isclose(mesh.points[:, 2], 0.0, atol=EPS) | np.isclose(mesh.points[:, 2], 1.0,
                                                                      atol=EPS)
    assert ends.sum() == len(top) + len(bottom)  # every end vertex is in a group
    np.testing.assert_allclose(mesh.points.min(axis=0)[2], 0.0, atol=EPS)
    np.testing.assert_allclose(mesh.points.max(axis=0)[2], 1.0, atol=EPS)


def test_cross_regions_and_centre():
    mesh = built("cross")
    assert np.all(_centroids(mesh, "left")[:, 0] < -0.05)
    assert np.all(_centroids(mesh, "right")[:, 0] > 0.05)
    assert np.all(np.abs(_centroids(mesh, "middle")[:, 0]) < 0.05)
    # the middle holds both vertical arms
    y = _centroids(mesh, "middle")[:, 1]
    assert y.min() < -0.4 and y.max() > 0.4, f"middle spans y in [{y.min()}, {y.max()}]"
    centre = mesh.points[mesh.vertex_groups["centre"]]
    assert np.all(np.abs(centre[:, :2]) <= 0.05 + EPS)
    np.testing.assert_allclose(np.abs(centre[:, 2]), 0.05, rtol=0, atol=EPS)
    assert np.sum(centre[:, 2] > 0) >= 4 and np.sum(centre[:, 2] < 0) >= 4


def test_teddy_limbs_sides_and_back():
    mesh = built("teddy")
    for side, sign in (("left", 1), ("right", -1)):
        arm, leg = _centroids(mesh, f"{side}_arm"), _centroids(mesh, f"{side}_leg")
        assert np.all(sign * arm[:, 0] > 0.1), f"{side} arm not on its side"
        assert np.all(sign * leg[:, 0] > 0.0), f"{side} leg not on its side"
        # legs point forward (-y); the leg ellipsoid spans y in [-0.31, 0.03]
        assert leg[:, 1].mean() < -0.1 and leg[:, 1].max() < 0.03, leg[:, 1]
        assert leg[:, 2].max() < arm[:, 2].min(), "legs below the arms"
    back = mesh.points[mesh.vertex_groups["back"]]
    assert np.all(back[:, 1] >= 0.08 - EPS) and np.all(np.abs(back[:, 2]) <= 0.2 + EPS)
    # the back includes the rearmost vertex of the torso (|z| < 0.2, below the head)
    waist = np.flatnonzero(np.abs(mesh.points[:, 2]) < 0.2)
    assert waist[np.argmax(mesh.points[waist, 1])] in set(mesh.vertex_groups["back"])


@pytest.mark.parametrize("name", list(PLANAR_VOLUME))
def test_planar_shapes_have_the_exact_volume(name):
    np.testing.assert_allclose(built(name).volume(), PLANAR_VOLUME[name], rtol=1e-12)
    np.testing.assert_allclose(geometry_volume(name), PLANAR_VOLUME[name], rtol=1e-9)


@pytest.mark.parametrize(
    ("coarse", "fine", "exact"),
    [("demo-cylinder", "bar-cylinder", CYLINDER_VOLUME),
     pytest.param("teddy", "teddy-example", None, marks=pytest.mark.slow)],
)
def test_curved_volume_error_converges_at_second_order(coarse, fine, exact):
    """Inscribed curved surfaces: volume error O(h^2); reference analytic or the CAD."""
    reference = exact if exact is not None else geometry_volume(coarse)
    if exact is not None:
        np.testing.assert_allclose(geometry_volume(coarse), exact, rtol=1e-9)
    errors = [abs(built(n).volume() - reference) / reference for n in (coarse, fine)]
    sizes = [SHAPES[n].default_size for n in (coarse, fine)]
    rate = observed_rates(errors, sizes)[0]
    assert errors[0] < 0.08, f"{coarse}: relative volume error {errors[0]:.3g}"
    assert 1.5 <= rate <= 2.5, f"observed rate {rate:.2f} (errors {errors}, h {sizes})"


def test_car_volume_close_to_its_geometry():
    reference = geometry_volume("car")
    for name in ("car", "car-example"):
        error = abs(built(name).volume() - reference) / reference
        assert error < 0.01, f"{name}: relative volume error {error:.3g}"


@pytest.mark.parametrize("name", ["bar-cuboid", "cross", "car", "teddy"])
def test_rebuild_is_identical(name):
    first, second = built(name), build_shape(name)
    assert (second.n_vertices, second.n_tets) == (first.n_vertices, first.n_tets)
    np.testing.assert_array_equal(second.points, first.points)
    np.testing.assert_array_equal(second.tets, first.tets)


def test_build_neither_inherits_nor_leaks_gmsh_options():
    with gmsh_session() as gmsh:
        gmsh.option.setNumber("Mesh.Algorithm3D", 4)
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.5)
        mesh = build_shape("demo-bar")
        assert gmsh.option.getNumber("Mesh.Algorithm3D") == 4
        assert gmsh.option.getNumber("Mesh.MeshSizeMax") == 0.5
    np.testing.assert_array_equal(mesh.tets, built("demo-bar").tets)


def test_size_changes_resolution():
    coarse = build_shape("cube", size=0.5)
    fine = built("cube")
    assert coarse.n_vertices < fine.n_vertices / 4, (coarse.n_vertices, fine.n_vertices)
    np.testing.assert_allclose(coarse.volume(), 1.0, rtol=1e-12)


@pytest.mark.parametrize("size", [0.0, -0.1, float("nan"), float("inf"), True, "0.1", 1e-4])
def test_bad_size_raises(size):
    with pytest.raises(LbshapeError, match="size") as info:
        build_shape("cube", size=size)
    assert "\n" not in str(info.value)


def test_unknown_name_lists_valid_names():
    with pytest.raises(LbshapeError, match="unknown shape 'sphere'") as info:
        build_shape("sphere")
    assert all(name in str(info.value) for name in SHAPES)


def test_write_shape_round_trip_and_atomic_failure(tmp_path, monkeypatch):
    path = tmp_path / "out" / "cross.msh"
    written = write_shape("cross", path)
    loaded = load_mesh(path)
    assert (loaded.n_vertices, loaded.n_tets) == (written.n_vertices, written.n_tets)
    np.testing.assert_allclose(loaded.points, written.points, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(loaded.tets, written.tets)
    for kind in ("cell_groups", "vertex_groups"):
        ours, theirs = getattr(written, kind), getattr(loaded, kind)
        assert set(ours) == set(theirs)
        for group in ours:
            np.testing.assert_array_equal(theirs[group], ours[group])

    # a failure at the rename keeps the old file intact and leaves no temporary
    before = path.read_bytes()

    def fail(*args):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(LbshapeError, match="cannot write"):
        write_shape("cube", path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in path.parent.iterdir()) == ["cross.msh"]
    with pytest.raises(LbshapeError, match="must be a .msh file"):
        write_shape("cube", tmp_path / "cube.vtk")


def test_cli_writes_a_mesh_that_loads_back(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["mesh", "demo-bar"]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    expected = built("demo-bar")
    assert out == [f"demo-bar: {expected.n_vertices} vertices, {expected.n_tets} tets "
                   "-> demo-bar.msh"]
    loaded = load_mesh(tmp_path / "demo-bar.msh")
    assert (loaded.n_vertices, loaded.n_tets) == (expected.n_vertices, expected.n_tets)

    assert main(["mesh", "cube", "--size", "0.5", "-o", "sub/c.msh"]) == 0
    loaded = load_mesh(tmp_path / "sub" / "c.msh")
    coarse = build_shape("cube", size=0.5)
    assert (loaded.n_vertices, loaded.n_tets) == (coarse.n_vertices, coarse.n_tets)
    assert f"{coarse.n_vertices} vertices" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["mesh", "sphere"], "unknown shape 'sphere'; valid names: bar-cuboid"),
        (["mesh", "cube", "--size", "0"], "finite positive"),
        (["mesh", "cube", "--size", "-1"], "finite positive"),
        (["mesh", "cube", "--size", "nan"], "finite positive"),
        (["mesh", "cube", "--size", "1e-4"], "size too small"),
        (["mesh", "cube", "-o", "cube.vtk"], "must be a .msh file"),
    ],
)
def test_cli_bad_input(tmp_path, capsys, monkeypatch, argv, message):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0], lines
    assert captured.out == ""
    assert list(tmp_path.iterdir()) == []  # no partial output
