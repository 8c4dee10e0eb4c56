"""Scene keys of a mesh file: ``units`` / ``scale``, ``piece``, ``fill_holes``; and a
scene in millimetres whose object is a CAD file (occt-misc's wedge), end to end."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import lbshape
from lbshape.errors import LbshapeError
from lbshape.geometry.primitives import structured_box
from lbshape.pipeline.meshes import build_mesh
from lbshape.scene import scene_from_dict

OCCT = Path("/usr/share/opencascade/data")
WEDGE = OCCT / "occ" / "wedge_ok.brep"  # 8 x 10 x 10 (mm), volume 560 mm³
needs_occt = pytest.mark.skipif(
    not OCCT.is_dir(), reason="Debian package occt-misc not installed (scripts/setup "
    "installs it): its sample CAD files are missing")

_BASE = {"fixed": {"region": "z < 1e-4"}, "simulation": {"dt": 0.002, "steps": 5}}


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> Path:
    import meshio

    folder = tmp_path_factory.mktemp("file-keys")
    box = structured_box((10.0, 4.0, 4.0), (5, 2, 2))  # in millimetres
    meshio.write(folder / "bar.vtu", meshio.Mesh(box.points, [("tetra", box.tets)]))
    surface = box.boundary_faces()
    meshio.write(folder / "bar.stl", meshio.Mesh(box.points, [("triangle", surface)]))
    return folder


def _read(folder: Path, obj: dict, **extra):
    return scene_from_dict({**_BASE, "object": obj, **extra}, name="keys", base_dir=folder)


def test_units_scale_the_object_and_its_examples(files):
    metres = build_mesh(_read(files, {"mesh": "bar.vtu"}).object)
    scene = _read(files, {"mesh": "bar.vtu", "units": "mm"}, examples={
        "stiffness": 1.0, "pose": [{"mesh": "bar.stl", "units": "mm", "size": 0.004}]})
    assert scene.object.units == "mm" and scene.examples.poses[0].source.units == "mm"
    mm = build_mesh(scene.object)
    assert mm.volume() == pytest.approx(1e-9 * metres.volume(), rel=1e-12)
    np.testing.assert_allclose(mm.points, 1e-3 * metres.points)
    example = build_mesh(scene.examples.poses[0].source)
    assert example.volume() == pytest.approx(mm.volume(), rel=1e-9)
    scaled = build_mesh(_read(files, {"mesh": "bar.vtu", "scale": 0.001}).object)
    np.testing.assert_allclose(scaled.points, mm.points)


def test_units_change_the_cache_key_only_when_given(files):
    plain = _read(files, {"mesh": "bar.vtu"}).object.key()
    assert set(plain) == {"mesh_sha256"}  # existing caches keep their key
    assert _read(files, {"mesh": "bar.vtu", "units": "mm"}).object.key()["units"] == "mm"


@pytest.mark.parametrize("obj, message", [
    ({"mesh": "bar.vtu", "units": "ft"},
     "'object.units' must be one of m, mm, cm, in; got 'ft'"),
    ({"mesh": "bar.vtu", "units": "mm", "scale": 0.001}, "'units' or 'scale'"),
    ({"mesh": "bar.vtu", "scale": 0}, "'object.scale' must be > 0"),
    ({"mesh": "bar.vtu", "piece": "largest"}, "'object.piece' applies to surface and CAD"),
    ({"mesh": "bar.stl", "piece": -1}, "piece number \\(>= 0\\) or \"largest\""),
    ({"mesh": "bar.stl", "fill_holes": "yes"}, "'object.fill_holes' must be true or false"),
    ({"mesh": "bar.vtu", "fill_holes": True}, "'object.fill_holes' applies to surface files"),
    ({"shape": "bar", "units": "mm"}, "'object.units' applies to mesh files"),
    ({"mesh": "bar.vtu", "unit": "mm"}, "unknown key 'object.unit'"),
])
def test_bad_file_keys_are_one_line_errors(files, obj, message):
    with pytest.raises(LbshapeError, match=message) as info:
        _read(files, obj)
    assert "\n" not in str(info.value)


def test_surface_keys_reach_the_reader(files):
    scene = _read(files, {"mesh": "bar.stl", "piece": "largest", "fill_holes": True,
                          "units": "cm"})
    source = scene.object
    assert (source.piece, source.fill_holes, source.units) == ("largest", True, "cm")
    assert build_mesh(source).volume() == pytest.approx(160e-6, rel=1e-9)


def test_scene_from_mesh_rejects_units():
    box = structured_box((0.1, 0.02, 0.02), (4, 1, 1))
    with pytest.raises(LbshapeError, match="already in metres"):
        scene_from_dict({**_BASE, "object": {"mesh": box, "units": "mm"}}, name="memory")


@needs_occt
def test_cad_object_in_millimetres_keys(files):
    scene = _read(files, {"mesh": str(WEDGE), "units": "mm", "size": 0.004})
    assert scene.object.size == 0.004
    mesh = build_mesh(scene.object)
    assert mesh.volume() == pytest.approx(5.6e-7, rel=1e-9)
    assert np.ptp(mesh.points, axis=0) == pytest.approx([0.008, 0.010, 0.010])


@needs_occt
@pytest.mark.slow
def test_scene_in_millimetres_with_a_cad_object_simulates(tmp_path):
    toml = tmp_path / "wedge.toml"
    toml.write_text(f'''
name = "wedge-mm"
[object]
mesh = "{WEDGE}"
units = "mm"
size = 0.004

[material]
young = 1.0e5
density = 1000.0

[reduced]
m = 4
r = 6
s = 10

[examples]
stiffness = 100.0
[[examples.pose]]
mesh = "{WEDGE}"
units = "mm"
size = 0.004
pose = "twist"
parameters = {{ angle = 0.3, axis = "z", anchor = "min" }}

[fixed]
region = "z < 1e-4"

[[loads]]
type = "gravity"
vector = [0.0, -9.81, 0.0]

[simulation]
dt = 0.002
steps = 5
''')
    scene = lbshape.load_scene(toml)
    pre = lbshape.precompute(scene)
    sim = lbshape.simulation(scene, pre)
    record = sim.run(5)
    assert record.stable
    u = sim.displacement()
    assert u.shape == (build_mesh(scene.object).n_vertices, 3)
    assert np.isfinite(u).all() and 0.0 < np.abs(u).max() < 0.01


@needs_occt
def test_the_docs_millimetre_scene_is_valid():
    import tomllib

    text = (Path(__file__).resolve().parents[2] / "docs" / "scenes.md").read_text("utf-8")
    block = text.split("# wedge.toml:", 1)[1].split("\n", 1)[1].split("```", 1)[0]
    scene = scene_from_dict(tomllib.loads(block), name="wedge-mm")
    assert scene.object.units == "mm" and scene.object.mesh_file == WEDGE
    assert scene.examples.poses[0].source.units == "mm"
