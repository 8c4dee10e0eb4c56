"""Scene schema: built-in scenes, strict validation, precompute vs runtime fields."""

from __future__ import annotations

import numpy as np
import pytest

from lbshape.errors import LbshapeError
from lbshape.geometry.primitives import structured_box
from lbshape.io.cache import cache_key
from lbshape.pipeline.meshes import build_mesh, selected_vertices
from lbshape.scene import builtin_scene_names, load_scene

BASE = """\
name = "test-bar"
[object]
mesh = "bar.msh"
[material]
model = "stvk"
young = 1.0e5
poisson = 0.3
density = 1000.0
[damping]
alpha = 0.1
beta = 0.01
[reduced]
m = 10
r = 30
s = 60
[examples]
stiffness = 200.0
[[examples.pose]]
mesh = "example.msh"
pose = "twist"
parameters = { angle = 1.57 }
landmarks = [[0, 12]]
[[examples.pose]]
mesh = "example.msh"
pose = "s-bend"
parameters = { amplitude = 0.1, direction = "x" }
[fixed]
region = "z > 0.999"
[[loads]]
type = "region_torque"
vector = [0.0, 0.0, 5.0]
region = "z < 0.001"
profile = "ramp"
start = 0.0
duration = 0.5
[simulation]
dt = 0.001
steps = 100
integrator = "newmark"
"""


@pytest.fixture
def write_scene(tmp_path):
    """Write BASE with text replacements next to dummy mesh files; return its path."""
    (tmp_path / "bar.msh").write_text("object mesh\n")
    (tmp_path / "example.msh").write_text("example mesh\n")

    def write(*replacements, append="", name="bar.toml"):
        text = BASE
        for old, new in replacements:
            assert old in text, f"test bug: {old!r} not in the base scene"
            text = text.replace(old, new, 1)
        path = tmp_path / name
        path.write_text(text + append)
        return path

    return write


def load_error(path) -> str:
    with pytest.raises(LbshapeError) as failure:
        load_scene(str(path))
    message = str(failure.value)
    assert "\n" not in message, f"multi-line message: {message!r}"
    assert message.count(".toml:") <= 1, f"repeated prefix: {message!r}"
    return message


def test_builtin_scenes_load_with_the_documented_sizes():
    names = builtin_scene_names()
    assert {"bar-cuboid", "bar-cylinder", "demo"} <= set(names), names
    expected = {
        "bar-cuboid": (10, 30, 60, "bar-cuboid"),
        "bar-cylinder": (10, 30, 60, "bar-cylinder"),
        "demo": (10, 20, 40, "demo-cylinder"),
    }
    for name, (m, r, s, example_shape) in expected.items():
        scene = load_scene(name)
        assert scene.name == name
        assert (scene.reduced.m, scene.reduced.r, scene.reduced.s) == (m, r, s)
        assert not scene.is_free and scene.has_examples
        assert not scene.has_contact and not scene.has_local_examples
        assert len(scene.examples.poses) == 2
        assert {p.source.shape for p in scene.examples.poses} == {example_shape}
        assert scene.examples.poses[0].pose == "twist"
        assert scene.examples.poses[0].parameters["angle"] == pytest.approx(np.pi / 2, rel=1e-3)
        assert any(load.type == "region_torque" and load.profile.kind == "ramp"
                   for load in scene.loads)
    assert load_scene("bar-cylinder").object.shape == "bar-cuboid"
    assert load_scene("demo").simulation.steps <= 300


def test_builtin_bar_regions_select_the_top_and_bottom_faces():
    mesh = structured_box((0.2, 0.2, 1.0), (2, 2, 5))
    scene = load_scene("bar-cuboid")
    top = selected_vertices(scene.fixed, mesh, what="fixed")
    torque = next(load for load in scene.loads if load.type == "region_torque")
    bottom = selected_vertices(torque.selection, mesh)
    face = 9  # (2+1) x (2+1) vertices per end face
    assert top.size == face and np.all(mesh.points[top, 2] == 1.0)
    assert bottom.size == face and np.all(mesh.points[bottom, 2] == 0.0)


def test_a_valid_scene_resolves_meshes_next_to_the_file(write_scene, tmp_path, monkeypatch):
    path = write_scene()
    monkeypatch.chdir(tmp_path.parent)
    scene = load_scene(str(path))
    assert scene.object.mesh_file == (tmp_path / "bar.msh").resolve()
    assert scene.examples.poses[1].parameters == {"amplitude": 0.1, "direction": "x"}
    assert scene.examples.poses[0].landmarks == ((0, 12),)
    assert scene.simulation.dt == 0.001 and scene.simulation.steps == 100
    assert scene.source == path.resolve()


@pytest.mark.parametrize(("replacement", "append", "key"), [
    (("young = 1.0e5", "yung = 1.0e5"), "", "'material.yung'"),
    (("name =", "nmae ="), "", "'nmae'"),
    (("landmarks =", "landmark ="), "", "'examples.pose[0].landmark'"),
    (("parameters = { angle = 1.57 }", "parameters = { angle = 1.57, twist = 2 }"), "",
     "'examples.pose[0].parameters.twist'"),
    (("profile =", "shape ="), "", "'loads[0].shape'"),
    (None, "[[planes]]\npoint = [0, 0, 0]\nnormal = [0, 0, 1]\nstiffnes = 1.0\n",
     "'planes[0].stiffnes'"),
])
def test_unknown_keys_are_named(write_scene, replacement, append, key):
    message = load_error(write_scene(*([replacement] if replacement else []), append=append))
    assert f"unknown key {key}" in message, message
    assert message.startswith("scene bar.toml:"), message


@pytest.mark.parametrize(("old", "new", "words"), [
    ("young = 1.0e5", 'young = "soft"', ("material.young", "number")),
    ("young = 1.0e5", "young = true", ("material.young", "number")),
    ("steps = 100", "steps = 1.5", ("simulation.steps", "integer")),
    ("m = 10", "m = 0", ("reduced.m", ">= 1")),
    ("r = 30", "r = -3", ("reduced.r", ">= 1")),
    ("s = 60", "s = 0", ("reduced.s", ">= 1")),
    ("dt = 0.001", "dt = 0.0", ("simulation.dt", "> 0")),
    ("dt = 0.001", "dt = -0.1", ("simulation.dt", "> 0")),
    ("dt = 0.001", "dt = nan", ("simulation.dt", "finite")),
    ("poisson = 0.3", "poisson = 0.5", ("poisson", "(-1, 0.5)")),
    ("young = 1.0e5", "young = 0", ("young", "> 0")),
    ("beta = 0.01", "beta = -0.01", ("damping.beta", ">= 0")),
    ('integrator = "newmark"', 'integrator = "rk4"', ("simulation.integrator", "newmark")),
    ('model = "stvk"', 'model = "rubber"', ("material.model", "neohookean")),
    ('pose = "twist"', 'pose = "spin"', ("examples.pose[0].pose", "s-bend")),
    ("parameters = { angle = 1.57 }", "parameters = { angle = [1] }",
     ("examples.pose[0].parameters.angle", "number")),
    ('direction = "x"', 'direction = "w"', ("examples.pose[1].parameters.direction", "x, y, z")),
    ("stiffness = 200.0", "stiffness = -1.0", ("examples.stiffness", ">= 0")),
    ("vector = [0.0, 0.0, 5.0]", "vector = [0.0, 5.0]", ("loads[0].vector", "3 numbers")),
    ("duration = 0.5", "duration = 0.0", ("loads[0].duration", "> 0")),
    ('type = "region_torque"', 'type = "push"', ("loads[0].type", "region_force")),
    ("landmarks = [[0, 12]]", "landmarks = [[0, -12]]", ("examples.pose[0].landmarks", ">= 0")),
])
def test_wrong_types_and_ranges_name_the_key(write_scene, old, new, words):
    message = load_error(write_scene((old, new)))
    for word in words:
        assert word in message, f"{word!r} missing from: {message}"


@pytest.mark.parametrize(("old", "new", "key"), [
    ('region = "z > 0.999"', "region = \"__import__('os')\"", "fixed.region"),
    ('region = "z < 0.001"', 'region = "z.real < 1"', "loads[0].region"),
    ('region = "z > 0.999"', 'region = "z >"', "fixed.region"),
    ('region = "z > 0.999"', 'region = "w > 1"', "fixed.region"),
])
def test_unsafe_or_malformed_regions_are_rejected(write_scene, old, new, key):
    message = load_error(write_scene((old, new)))
    assert f"'{key}'" in message, message


def test_missing_mesh_files_are_named(write_scene):
    message = load_error(write_scene(('mesh = "bar.msh"', 'mesh = "nowhere.msh"')))
    assert "'object.mesh'" in message and "nowhere.msh" in message, message
    message = load_error(write_scene(('mesh = "example.msh"', 'mesh = "sub/none.msh"')))
    assert "'examples.pose[0].mesh'" in message, message


STRUCTURAL = [
    ((('mesh = "bar.msh"', 'mesh = "bar.msh"\nshape = "bar-cuboid"'),), "",
     "exactly one of 'shape' or 'mesh'"),
    ((('mesh = "bar.msh"', 'mesh = "bar.msh"\nsize = 0.1'),), "", "'object.size'"),
    ((), '[[regions]]\nname = "a"\nregion = "x < 0"\nexamples = [0, 2]\n',
     "'regions[0].examples' must be in [0, 1], got 2"),
    ((('region = "z > 0.999"', 'region = "z > 0.999"\ngroup = "top"'),), "", "not both"),
    ((('pose = "twist"\n', ""),), "", "'examples.pose[0].parameters' needs a 'pose'"),
    ((('type = "region_torque"', 'type = "gravity"'),), "",
     "'loads[0].region' is not used by gravity"),
    ((("[object]", "[object\n"),), "", "invalid TOML"),
    ((("[object]\nmesh = \"bar.msh\"\n", ""),), "", "missing required table '[object]'"),
]


@pytest.mark.parametrize(("replacements", "append", "words"), STRUCTURAL)
def test_structural_errors(write_scene, replacements, append, words):
    message = load_error(write_scene(*replacements, append=append))
    assert words in message, f"{words!r} missing from: {message}"


def test_unknown_scene_names_and_paths(tmp_path):
    assert "scene file not found" in load_error(tmp_path / "absent.toml")
    message = load_error("no-such-scene")
    assert "unknown scene 'no-such-scene'" in message and "demo" in message, message


def test_unknown_shape_names_are_rejected(write_scene):
    message = load_error(write_scene(('mesh = "bar.msh"', 'shape = "banana"')))
    assert "'object.shape'" in message and "banana" in message, message


def test_derived_flags_follow_the_scene(write_scene):
    # a free body damps its deformation only (alpha = 0)
    free = write_scene(('[fixed]\nregion = "z > 0.999"\n', ""), ("alpha = 0.1", "alpha = 0.0"),
                       append=(
        "[[planes]]\npoint = [0, 0, 0]\nnormal = [0, 0, 2]\nstiffness = 1e4\n"
        '[[regions]]\nname = "left"\nregion = "x < 0"\nexamples = [1]\n'))
    scene = load_scene(str(free))
    assert scene.is_free and scene.has_contact and scene.has_local_examples and scene.has_examples
    assert scene.planes[0].normal == (0.0, 0.0, 1.0)
    assert scene.regions[0].examples == (1,)
    bare = write_scene(append="", name="bare.toml")
    text = bare.read_text()
    start, end = text.index("[examples]"), text.index("[fixed]")
    bare.write_text(text[:start] + text[end:])
    scene = load_scene(str(bare))
    assert not scene.has_examples and not scene.is_free and not scene.has_contact
    assert scene.precompute_key_fields()["examples"] is None


def test_precompute_key_depends_on_exactly_the_precompute_fields(write_scene, tmp_path):
    def keys(*replacements):
        scene = load_scene(str(write_scene(*replacements)))
        return cache_key(scene.precompute_key_fields()), cache_key(scene.runtime_fields())

    base_pre, base_run = keys()
    assert keys() == (base_pre, base_run), "keys must be deterministic"
    precompute_changes = [
        ("m = 10", "m = 12"),
        ("r = 30", "r = 20"),
        ("s = 60", "s = 40"),
        ("young = 1.0e5", "young = 2.0e5"),
        ('model = "stvk"', 'model = "neohookean"'),
        ("parameters = { angle = 1.57 }", "parameters = { angle = 1.2 }"),
        ("landmarks = [[0, 12]]", "landmarks = [[0, 13]]"),
        ('region = "z > 0.999"', 'region = "z > 0.99"'),
    ]
    for change in precompute_changes:
        pre, _ = keys(change)
        assert pre != base_pre, f"precompute key ignores {change}"
    runtime_changes = [
        ("dt = 0.001", "dt = 0.002"),
        ("steps = 100", "steps = 500"),
        ("vector = [0.0, 0.0, 5.0]", "vector = [0.0, 0.0, 7.0]"),
        ("duration = 0.5", "duration = 0.25"),
        ("stiffness = 200.0", "stiffness = 50.0"),
        ("beta = 0.01", "beta = 0.02"),
        ('integrator = "newmark"', 'integrator = "backward-euler"'),
    ]
    for change in runtime_changes:
        pre, run = keys(change)
        assert pre == base_pre, f"precompute key depends on runtime field {change}"
        assert run != base_run, f"runtime fields ignore {change}"
    # the example mesh enters through its content, not its name
    (tmp_path / "example.msh").write_text("another example mesh\n")
    assert keys()[0] != base_pre


def test_demo_scene_on_its_real_meshes():
    """Regions select the top/bottom groups; the example poses keep the top in place."""
    poses = pytest.importorskip("lbshape.geometry.poses")
    scene = load_scene("demo")
    mesh = build_mesh(scene.object)
    np.testing.assert_array_equal(np.sort(selected_vertices(scene.fixed, mesh)),
                                  np.sort(mesh.vertex_groups["top"]))
    torque = next(load for load in scene.loads if load.type == "region_torque")
    np.testing.assert_array_equal(np.sort(selected_vertices(torque.selection, mesh)),
                                  np.sort(mesh.vertex_groups["bottom"]))
    example = scene.examples.poses[0]
    rest = build_mesh(example.source)
    posed = poses.apply_pose(rest, example.pose, **example.parameters)
    moved = np.linalg.norm(posed.points - rest.points, axis=1)
    top, bottom = rest.vertex_groups["top"], rest.vertex_groups["bottom"]
    assert moved[top].max() < 1e-12, f"top moved by {moved[top].max():.2e} m"
    # +90 degrees at the bottom: a rim vertex at radius 0.1128 m moves by sqrt(2) r
    assert moved[bottom].max() == pytest.approx(np.sqrt(2) * 0.1128, rel=0.05)
