"""Examples posed part by part: each part by its own pose, the rest of the mesh harmonic."""

from __future__ import annotations

import numpy as np
import pytest

from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh
from lbshape.geometry.poses import arc, pose_parts, twist
from lbshape.geometry.primitives import structured_box
from lbshape.pipeline.example_parts import ExampleParts
from lbshape.pipeline.meshes import build_mesh, example_meshes, posed_part, selected_vertices
from lbshape.scene import load_scene
from lbshape.scene.schema import MeshSource
from lbshape.shapespace.local_regions import region_cells, submesh


@pytest.fixture(scope="module")
def bar() -> TetMesh:
    """0.2 x 0.2 x 1 m bar along z in [0, 1]."""
    return structured_box((0.2, 0.2, 1.0), (4, 4, 16), (-0.1, -0.1, 0.0))


def _where(mesh: TetMesh, condition) -> np.ndarray:
    return np.flatnonzero(condition(mesh.points))


def _harmonic_residual(mesh: TetMesh, displacement: np.ndarray) -> np.ndarray:
    """(n, 3) Σ_j w_ij (d_i − d_j) over the mesh's edges, w = 1 / rest length,
    written out edge by edge (independently of the code under test)."""
    pairs = {tuple(sorted((int(tet[i]), int(tet[j]))))
             for tet in mesh.tets for i in range(4) for j in range(i + 1, 4)}
    residual = np.zeros_like(displacement)
    for a, b in pairs:
        w = 1.0 / np.linalg.norm(mesh.points[a] - mesh.points[b])
        residual[a] += w * (displacement[a] - displacement[b])
        residual[b] += w * (displacement[b] - displacement[a])
    return residual


def test_parts_take_their_own_pose_held_vertices_stay_and_the_rest_is_harmonic(bar):
    top = _where(bar, lambda p: p[:, 2] > 0.7)
    middle = _where(bar, lambda p: (p[:, 2] > 0.3) & (p[:, 2] < 0.4))
    held = _where(bar, lambda p: p[:, 2] < 0.05)
    parts = [(top, "twist", {"angle": 0.6}),
             (middle, "arc", {"angle": 0.3, "direction": "x", "axis": "y"})]
    posed = pose_parts(bar, parts, held)

    assert np.array_equal(posed.tets, bar.tets)
    # each part exactly as its pose maps the part's own points (its own extent)
    np.testing.assert_allclose(posed.points[top], twist(bar.points[top], angle=0.6),
                               atol=1e-14)
    np.testing.assert_allclose(posed.points[middle],
                               arc(bar.points[middle], angle=0.3, direction="x", axis="y"),
                               atol=1e-14)
    assert np.array_equal(posed.points[held], bar.points[held])

    known = np.zeros(bar.n_vertices, bool)
    known[np.concatenate([top, middle, held])] = True
    d = posed.points - bar.points
    residual = _harmonic_residual(bar, d)[~known]
    scale = np.abs(d).max() / np.linalg.norm(bar.points[1] - bar.points[0])
    assert np.abs(residual).max() < 1e-10 * scale
    # the discrete maximum principle: the free vertices move within the known range
    assert (d[~known] <= d[known].max(axis=0) + 1e-12).all()
    assert (d[~known] >= d[known].min(axis=0) - 1e-12).all()
    # and they do move: between the held end and the bent middle, away from both
    between = _where(bar, lambda p: (p[:, 2] > 0.1) & (p[:, 2] < 0.25))
    assert np.abs(d[between]).max() > 1e-3


def test_a_piece_of_the_mesh_without_a_part_stays_in_place(bar):
    other = structured_box((0.2, 0.2, 0.2), (2, 2, 2), (1.0, 0.0, 0.0))
    both = TetMesh(np.vstack([bar.points, other.points]),
                   np.vstack([bar.tets, other.tets + bar.n_vertices]))
    top = _where(both, lambda p: (p[:, 2] > 0.7) & (p[:, 0] < 0.5))
    posed = pose_parts(both, [(top, "twist", {"angle": 0.6})])
    assert np.array_equal(posed.points[bar.n_vertices:], other.points)
    assert np.abs(posed.points[:bar.n_vertices] - bar.points).max() > 0.01


def test_overlapping_parts_and_inverting_poses_are_refused(bar):
    top = _where(bar, lambda p: p[:, 2] > 0.7)
    upper = _where(bar, lambda p: p[:, 2] > 0.5)
    with pytest.raises(LbshapeError, match="part 1 of the pose shares .* with part 0"):
        pose_parts(bar, [(top, "twist", {"angle": 0.6}), (upper, "twist", {"angle": 0.2})])
    with pytest.raises(LbshapeError, match="shares .* with the held vertices"):
        pose_parts(bar, [(upper, "twist", {"angle": 0.6})], held=top)
    with pytest.raises(LbshapeError, match="has no parameter"):
        pose_parts(bar, [(top, "twist", {"angle": 0.6, "amplitude": 1.0})])
    # a part bent hard next to a held neighbour folds the tetrahedra between them
    thin = _where(bar, lambda p: p[:, 2] > 0.95)
    below = _where(bar, lambda p: (p[:, 2] > 0.9) & (p[:, 2] < 0.95))
    with pytest.raises(LbshapeError, match="the pose of 1 parts inverts"):
        pose_parts(bar, [(thin, "arc", {"angle": 3.0, "direction": "z", "axis": "x"})],
                   held=below)


SCENE = """\
name = "parts"
[object]
shape = "demo-bar"
[examples]
stiffness = 100.0
[[examples.pose]]
shape = "demo-bar"
{extra}
[[examples.pose.parts]]
region = "z > 0.5"
pose = "arc"
parameters = {{ angle = {angle}, direction = "x" }}
[fixed]
region = "z < 0.001"
"""


def _scene(tmp_path, extra='hold = { region = "z < 0.01" }', angle=0.4):
    path = tmp_path / "parts.toml"
    path.write_text(SCENE.format(extra=extra, angle=angle))
    return path


def test_a_scene_poses_an_example_part_by_part(tmp_path):
    scene = load_scene(str(_scene(tmp_path)))
    pose = scene.examples.poses[0]
    assert pose.pose is None and not pose.is_posed_file
    assert pose.parts[0].pose == "arc" and pose.hold.region == "z < 0.01"
    # the parts are part of the precompute's key
    other = load_scene(str(_scene(tmp_path, angle=0.5)))
    assert scene.precompute_key_fields() != other.precompute_key_fields()

    object_mesh = _demo_bar()
    rest, posed = example_meshes(pose, object_mesh)
    part = selected_vertices(pose.parts[0].selection, rest)
    np.testing.assert_allclose(posed.points[part],
                               arc(rest.points[part], angle=0.4, direction="x"), atol=1e-14)
    held = selected_vertices(pose.hold, rest)
    assert np.array_equal(posed.points[held], rest.points[held])
    # a local region of such an example takes the example's own positions of its part
    cells = region_cells(rest, region="z > 0.3")
    part_mesh, vertices = submesh(rest, cells)
    np.testing.assert_array_equal(posed_part(pose, part_mesh, vertices, posed),
                                  posed.points[vertices])
    # but has no pose on the object's own region: its parts live on its own mesh
    # (the representation measurement skips it instead of indexing another mesh)
    object_part, object_vertices = submesh(object_mesh,
                                           region_cells(object_mesh, region="z > 0.3"))
    with pytest.raises(LbshapeError, match="no pose on the object's mesh"):
        ExampleParts(scene, object_mesh).object_pose(0, object_part, object_vertices)


def _demo_bar() -> TetMesh:
    return build_mesh(MeshSource(shape="demo-bar"))


@pytest.mark.parametrize(("extra", "words"), [
    ('pose = "twist"\nparameters = { angle = 1.0 }', "takes 'pose' (the whole example) or "
     "'parts'"),
    ('hold = { group = "" }', "'examples.pose[0].hold.group' must be a non-empty string"),
    ('hold = { colour = "red" }', "unknown key 'examples.pose[0].hold.colour'"),
])
def test_bad_part_poses_are_named(tmp_path, extra, words):
    with pytest.raises(LbshapeError, match=None) as failure:
        load_scene(str(_scene(tmp_path, extra=extra)))
    assert words in str(failure.value), str(failure.value)


def test_a_hold_without_parts_and_a_part_without_pose_are_refused(tmp_path):
    path = tmp_path / "hold.toml"
    path.write_text(SCENE.format(extra='hold = { region = "z < 0.01" }', angle=0.4)
                    .split("[[examples.pose.parts]]")[0] + '[fixed]\nregion = "z < 0.001"\n')
    with pytest.raises(LbshapeError, match=r"'examples.pose\[0\].hold' keeps vertices at rest"):
        load_scene(str(path))
    path.write_text(SCENE.format(extra="", angle=0.4).replace('pose = "arc"\n', ""))
    with pytest.raises(LbshapeError, match=r"examples.pose\[0\].parts\[0\]"):
        load_scene(str(path))
