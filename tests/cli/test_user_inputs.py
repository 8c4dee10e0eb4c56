"""What a new user meets first: their own gmsh script as a shape (``lbshape mesh``,
scenes), every mesh format in ``eigen`` and ``modes``, default output folders outside
the repository, and the pictures of their scenes (no-examples comparison, free bodies
with their contact planes and one fixed camera, warnings that do not break a progress
bar)."""

from __future__ import annotations

import json
import logging
import re
import sys
import textwrap
from pathlib import Path

import meshio
import numpy as np
import pytest

from lbshape.cli import main
from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import load_mesh
from lbshape.geometry.primitives import structured_box
from lbshape.geometry.shapes import build_script
from lbshape.io.paths import REPOSITORY, RESULTS_DIR, USER_RESULTS, output_root
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import simulate
from lbshape.scene import load_scene, mesh_source

#: a user's script: a 0.2 x 0.2 x 1 m bar along z with its top face as a group
BAR_SCRIPT = '''
import gmsh

DEFAULT_SIZE = 0.12


def build(model, h):
    occ = model.occ
    body = occ.addBox(-0.1, -0.1, 0.0, 0.2, 0.2, 1.0)
    occ.synchronize()
    top = model.getEntitiesInBoundingBox(-1, -1, 0.999, 1, 1, 1.001, dim=2)
    model.setPhysicalName(2, model.addPhysicalGroup(2, [t for _, t in top]), "top")
    model.setPhysicalName(3, model.addPhysicalGroup(3, [body]), "body")
    gmsh.option.setNumber("Mesh.MeshSizeMin", h)
    gmsh.option.setNumber("Mesh.MeshSizeMax", h)
'''

#: a fixed bar under gravity and a torque at its free end, twisted by its examples
EXAMPLES_SCENE = '''
[object]
shape = "part.py"
size = 0.15

[material]
young = 1.0e5

[reduced]
m = 4
r = 10
s = 20

[examples]
stiffness = 3000.0

[[examples.pose]]
shape = "part.py"
size = 0.12
pose = "twist"
parameters = { angle = 1.2, axis = "z", anchor = "max" }

[fixed]
group = "top"

[[loads]]
type = "region_torque"
vector = [0.0, 0.0, 2.0]
region = "z < 0.01"

[simulation]
steps = 40
'''

#: a free bar thrown along x, spinning, falling onto a floor
FREE_SCENE = '''
[object]
shape = "part.py"
size = 0.15

[material]
young = 1.0e5

[damping]
beta = 0.01

[reduced]
m = 4
r = 10
s = 20

[initial]
velocity = [2.0, 0.0, 0.0]
angular_velocity = [0.0, 2.0, 0.0]

[[loads]]
type = "gravity"
vector = [0.0, 0.0, -9.81]

[[planes]]
point = [0.0, 0.0, -0.1]
normal = [0.0, 0.0, 1.0]
stiffness = 1.0e4

[simulation]
steps = 150
'''


def _write(folder: Path, name: str, text: str) -> Path:
    path = folder / name
    path.write_text(textwrap.dedent(text))
    return path


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: "), err
    return err[0]


def _png(path: Path) -> np.ndarray:
    import matplotlib.image

    return matplotlib.image.imread(str(path))[..., :3]


# ------------------------------------------------------------ a user's gmsh script
def test_user_script_meshes_and_its_scene_simulates(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    _write(tmp_path, "part.py", BAR_SCRIPT)
    assert main(["mesh", "part.py"]) == 0  # DEFAULT_SIZE, written beside as part.msh
    assert "part.py:" in capsys.readouterr().out
    written = load_mesh(tmp_path / "part.msh")
    assert written.n_tets > 100 and written.volume() == pytest.approx(0.04, rel=1e-9)
    assert {"top", "body"} <= set(written.vertex_groups)  # the script's groups survive
    coarse = build_script(tmp_path / "part.py", size=0.2)
    assert coarse.n_vertices < written.n_vertices

    scene_path = _write(tmp_path, "bar.toml", '''
        [object]
        shape = "part.py"
        size = 0.15
        [material]
        young = 1.0e5
        [reduced]
        m = 4
        r = 8
        s = 20
        [fixed]
        group = "top"
        [[loads]]
        type = "gravity"
        vector = [0.0, 0.0, -9.81]
        [simulation]
        steps = 12
        ''')
    scene = load_scene(scene_path)
    assert scene.object.script == tmp_path / "part.py" and scene.object.size == 0.15
    pre = precompute(scene)
    output = simulate(scene, pre, method="reduced")
    assert output.stats["stable"] and output.stats["steps"] == 12
    assert 0.0 < output.stats["max_displacement"] < 0.1
    # the script is part of the cache key: an edit rebuilds
    before = pre.mesh.n_vertices
    (tmp_path / "part.py").write_text(BAR_SCRIPT.replace("0.2, 0.2, 1.0", "0.2, 0.2, 0.8")
                                      .replace("0.999, 1, 1, 1.001", "0.799, 1, 1, 0.801"))
    assert precompute(load_scene(scene_path)).mesh.n_vertices != before


@pytest.mark.parametrize(("script", "words"), [
    (None, "gmsh script not found"),
    ("x = 1\n", "defines no build(model, h)"),
    ("import gmsh\ndef build(model, h)\n", "failed while loading (SyntaxError"),
    ("import no_such_module_zz\n", "failed while loading (ModuleNotFoundError"),
    ("def build(model, h):\n    raise ValueError('bad\\nthing')\n",
     "build(model, h) failed (ValueError: bad thing)"),
    ("def build(model, h):\n    model.occ.addRectangle(0, 0, 0, 1, 1)\n", "built no volume"),
    ("def build(model, h):\n    model.occ.addBox(0, 0, 0, 1, 1, 1)\n"
     "    model.occ.addBox(2, 0, 0, 1, 1, 1)\n", "2 disconnected pieces"),
    ("def build(model, h):\n    model.occ.addBox(0, 0, 0, 1, 1, 1)\n", "no mesh size"),
])
def test_bad_user_scripts_fail_in_one_line(tmp_path, capsys, script, words):
    path = tmp_path / "mine.py"
    if script is not None:
        path.write_text(script)
    args = ["mesh", str(path), "-o", str(tmp_path / "out.msh")]
    if "no mesh size" not in words:
        args += ["--size", "0.5"]
    assert main(args) == 2
    line = _one_error_line(capsys)
    assert words in line and "mine.py" in line, line
    assert not (tmp_path / "out.msh").exists()


def test_scene_keys_for_user_scripts(tmp_path):
    _write(tmp_path, "part.py", BAR_SCRIPT)
    base = '[fixed]\nregion = "z > 0.999"\n'
    cases = [('[object]\nshape = "missing.py"\n', "gmsh script not found"),
             ('[object]\nmesh = "part.py"\n', "is a gmsh script; give it as 'object.shape'"),
             ('[object]\nshape = "sphere"\n', "or a gmsh script ending in .py")]
    for text, words in cases:
        with pytest.raises(LbshapeError, match=re.escape(words)):
            load_scene(_write(tmp_path, "s.toml", text + base))
    source = mesh_source("part.py", base_dir=tmp_path)
    assert source.script == tmp_path / "part.py" and source.label == "part.py"
    assert source.key()["script_sha256"] != mesh_source(
        _write(tmp_path, "other.py", BAR_SCRIPT + "\n# edited\n")).key()["script_sha256"]


# ------------------------------------------------- eigen and modes on every format
@pytest.fixture(scope="module")
def cube_files(tmp_path_factory):
    """A unit cube as .vtu (volume), and its boundary as .stl and .obj (surfaces)."""
    folder = tmp_path_factory.mktemp("cube")
    cube = structured_box((1.0, 1.0, 1.0), (4, 4, 4))
    meshio.write(folder / "cube.vtu", meshio.Mesh(cube.points, [("tetra", cube.tets)]))
    faces = cube.boundary_faces()
    used = np.unique(faces)
    index = np.full(cube.n_vertices, -1)
    index[used] = np.arange(used.size)
    surface = meshio.Mesh(cube.points[used], [("triangle", index[faces].astype(np.int32))])
    for ext in ("stl", "obj"):
        meshio.write(folder / f"cube.{ext}", surface)
    return folder, cube


def _json_of(capsys) -> dict:
    return json.loads(capsys.readouterr().out)


def test_eigen_and_modes_take_every_mesh_format(cube_files, tmp_path, capsys):
    folder, cube = cube_files
    assert main(["eigen", str(folder / "cube.vtu"), "--m", "4", "--json"]) == 0
    vtu = _json_of(capsys)
    assert vtu["n_vertices"] == cube.n_vertices and vtu["n_tets"] == cube.n_tets
    # the same mesh through .msh gives the same spectrum
    assert main(["mesh", str(folder / "cube.vtu"), "-o", str(tmp_path / "cube.msh")]) == 0
    capsys.readouterr()
    assert main(["eigen", str(tmp_path / "cube.msh"), "--m", "4", "--json"]) == 0
    np.testing.assert_allclose(_json_of(capsys)["eigenvalues"], vtu["eigenvalues"], rtol=1e-8)
    # Neumann unit cube: lambda_1 = pi^2 (three times), lambda_4 = 2 pi^2
    for ext in ("stl", "obj"):
        assert main(["eigen", str(folder / f"cube.{ext}"), "--m", "4", "--json"]) == 0
        surface = _json_of(capsys)
        assert surface["volume"] == pytest.approx(1.0, rel=1e-9), ext
        values = np.asarray(surface["eigenvalues"])
        np.testing.assert_allclose(values[:3], np.pi**2, rtol=0.15, err_msg=ext)
        assert values[3] == pytest.approx(2 * np.pi**2, rel=0.25), ext
    assert main(["modes", str(folder / "cube.stl"), "--r", "3", "--json"]) == 0
    modes = _json_of(capsys)
    assert modes["n_rigid"] == 6 and len(modes["frequencies_hz"]) == 3
    assert main(["modes", "cube", "--size", "0.5", "--r", "2", "--fixed", "z < 1e-6",
                 "--json"]) == 0
    assert _json_of(capsys)["n_rigid"] == 0


@pytest.mark.parametrize(("args", "words"), [
    (["eigen", "nothere.msh"], "mesh file not found"),
    (["eigen", "sphere"], "unknown shape 'sphere'"),
    (["modes", "nothere.py"], "gmsh script not found"),
    (["eigen", "cube.vtu", "--size", "0.1"], "applies to surface files"),
    (["eigen", "cube.txt"], "mesh file not found"),
])
def test_eigen_and_modes_bad_meshes_fail_in_one_line(cube_files, monkeypatch, capsys, args,
                                                     words):
    monkeypatch.chdir(cube_files[0])
    assert main(args) == 2
    assert words in _one_error_line(capsys)


# ---------------------------------------------------------- default output folders
def test_default_outputs_outside_the_repository(tmp_path, monkeypatch):
    from lbshape.studies import demo, figures, tune

    monkeypatch.chdir(tmp_path)
    assert output_root() == tmp_path / USER_RESULTS
    assert figures.default_out("s") == tmp_path / USER_RESULTS / "figures" / "s"
    assert demo.default_out() == tmp_path / USER_RESULTS / "demo"
    assert tune.default_out() == tmp_path / USER_RESULTS / "tune"
    monkeypatch.chdir(REPOSITORY / "tests")  # inside the checkout, not its root
    assert output_root() == REPOSITORY / "tests" / USER_RESULTS
    monkeypatch.chdir(REPOSITORY)
    assert output_root() == RESULTS_DIR
    assert demo.default_out() == RESULTS_DIR / "demo"


@pytest.mark.slow
def test_user_scene_render_defaults_to_the_current_folder_with_a_comparison(
        tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    _write(tmp_path, "part.py", BAR_SCRIPT)
    _write(tmp_path, "twisted.toml", EXAMPLES_SCENE)
    assert main(["render", "twisted.toml"]) == 0
    out = tmp_path / USER_RESULTS / "figures" / "twisted"
    assert str(out / "comparison.png") in capsys.readouterr().out
    assert not (RESULTS_DIR / "figures" / "twisted").exists()
    names = sorted(p.name for p in out.iterdir())
    assert {"simulation.png", "comparison.png", "comparison.json", "examples_on_object.png",
            "summary.json"} <= set(names), names
    comparison = json.loads((out / "comparison.json").read_text())
    assert comparison["panels"][0] == "rest" and "no examples" in comparison["panels"][1]
    assert comparison["example_influence"] > 0.05, comparison
    rgb = _png(out / "comparison.png")
    thirds = np.array_split(rgb, 3, axis=1)  # rest | no examples | examples
    for panel in thirds:
        assert np.any(panel < 0.9, axis=2).mean() > 0.02  # a shape in every panel
    coloured = [(p.max(axis=2) - p.min(axis=2) > 0.1).mean() for p in thirds]
    assert coloured[1] > 0.01 and coloured[2] > 0.01, coloured  # both runs coloured by |u|


# -------------------------------------------------------- free bodies: planes, camera
def _plane_pixels(rgb: np.ndarray) -> np.ndarray:
    """Pixels of an unlit translucent plane over the white background."""
    from matplotlib.colors import to_rgb

    from lbshape.report.render import PLANE_COLOR, PLANE_OPACITY

    blend = PLANE_OPACITY * np.asarray(to_rgb(PLANE_COLOR)) + (1.0 - PLANE_OPACITY)
    return np.all(np.abs(rgb - blend) < 0.02, axis=2)


def test_plane_rectangles_cover_the_trajectory():
    from lbshape.report.render import plane_rectangles

    points = np.array([[0.0, 0.0, 1.0], [3.0, 1.0, 2.0]])
    floor, wall = plane_rectangles([(np.zeros(3), np.array([0.0, 0.0, 2.0])),
                                    (np.array([4.0, 0.0, 0.0]), np.array([-1.0, 0.0, 0.0]))],
                                   points, margin=0.0)
    np.testing.assert_allclose(floor[:, 2], 0.0)
    np.testing.assert_allclose(np.sort(floor[:, :2], axis=0)[[0, -1]], [[0, 0], [3, 1]],
                               atol=1e-12)
    np.testing.assert_allclose(wall[:, 0], 4.0)
    np.testing.assert_allclose(np.ptp(wall[:, 1:], axis=0), [1.0, 1.0], atol=1e-12)


def test_fixed_camera_keeps_a_moving_body_in_every_panel(tmp_path):
    from lbshape.report.render import render_shapes

    bar = structured_box((0.2, 0.2, 0.6), (1, 1, 3))
    moved = [bar.with_points(bar.points + [1.5 * k, 0.0, 0.0]) for k in range(3)]
    floor = [(np.zeros(3), np.array([0.0, 0.0, 1.0]))]
    extent = np.vstack([m.points for m in moved])
    shown = render_shapes(moved, ["a", "b", "c"], tmp_path / "fixed.png", planes=floor,
                          extent=extent, window_size=(900, 300))
    plain = render_shapes(moved, ["a", "b", "c"], tmp_path / "plain.png",
                          window_size=(900, 300))
    rgb, before = _png(shown), _png(plain)
    assert _plane_pixels(rgb).mean() > 0.05  # the floor is drawn
    assert _plane_pixels(before).mean() < 0.001  # and only where asked for
    centres = []
    for panel in np.array_split(rgb[40:], 3, axis=1):  # below the captions
        body = np.any(panel < 0.75, axis=2) & ~_plane_pixels(panel)
        assert body.mean() > 0.005, "a panel lost the body"
        centres.append(np.argwhere(body)[:, 1].mean() / panel.shape[1])
    # one camera for all panels: the body moves across them, left to right
    assert centres[0] < centres[1] - 0.1 < centres[2] - 0.2, centres


def test_free_body_render_draws_its_floor(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _write(tmp_path, "part.py", BAR_SCRIPT)
    _write(tmp_path, "thrown.toml", FREE_SCENE)
    assert main(["render", "thrown.toml", "--out", "figs"]) == 0
    rgb = _png(tmp_path / "figs" / "simulation.png")
    for panel in np.array_split(rgb, 4, axis=1):  # four frames, one camera, one floor
        assert _plane_pixels(panel).mean() > 0.02
        assert (panel.max(axis=2) - panel.min(axis=2) > 0.15).mean() > 0.005  # the body


# ------------------------------------------------------- warnings and progress bars
def test_warnings_get_their_own_line_under_a_progress_bar(capsys):
    from tqdm import tqdm

    from lbshape.cli.main import configure_logging

    configure_logging()
    with tqdm(total=2, desc="[1/3] mesh", file=sys.stderr, bar_format="{desc} {bar:10}") as bar:
        bar.update(1)
        logging.getLogger("lbshape.geometry.mesh").warning("mesh.vtu: re-oriented 3 inverted "
                                                           "tetrahedra")
        bar.update(1)
    pieces = re.split(r"[\r\n]", capsys.readouterr().err)
    assert "WARNING: mesh.vtu: re-oriented 3 inverted tetrahedra" in pieces, pieces


def test_precompute_prints_the_inverted_tetrahedra_warning_on_its_own_line(tmp_path, capsys):
    bar = structured_box((0.2, 0.2, 1.0), (1, 1, 4))
    tets = bar.tets.copy()
    tets[::5] = tets[::5][:, [1, 0, 2, 3]]  # a few inverted, as some exporters write them
    meshio.write(tmp_path / "flipped.vtu", meshio.Mesh(bar.points, [("tetra", tets)]))
    _write(tmp_path, "flipped.toml", '''
        [object]
        mesh = "flipped.vtu"
        [reduced]
        m = 4
        r = 6
        s = 10
        [fixed]
        region = "z > 0.999"
        ''')
    assert main(["precompute", str(tmp_path / "flipped.toml")]) == 0
    err = capsys.readouterr().err
    pieces = re.split(r"[\r\n]", err)
    count = int(np.ceil(len(tets) / 5))
    expected = f"re-oriented {count} inverted tetrahedra"
    assert any(p.startswith("WARNING: ") and p.endswith(expected) for p in pieces), err
    assert not any(expected in p and not p.startswith("WARNING: ") for p in pieces), err


@pytest.mark.slow
def test_a_fresh_precompute_prints_no_compiler_build_log(tmp_path):
    """The form compiler's C build (``running build_ext``, gcc command lines) stays out of
    the progress bars: a precompute with empty precompute and form caches."""
    import os
    import subprocess

    bar = structured_box((0.2, 0.2, 1.0), (1, 1, 3))
    meshio.write(tmp_path / "bar.vtu", meshio.Mesh(bar.points, [("tetra", bar.tets)]))
    _write(tmp_path, "tiny.toml", '''
        [object]
        mesh = "bar.vtu"
        [reduced]
        m = 4
        r = 6
        s = 10
        [fixed]
        region = "z < 1e-6"
        ''')
    env = {**os.environ, "PYTHONPATH": str(REPOSITORY), "OMP_NUM_THREADS": "1",
           "LBSHAPE_CACHE": str(tmp_path / "cache"),
           "XDG_CACHE_HOME": str(tmp_path / "xdg")}  # DOLFINx's JIT cache: ~/.cache/fenics
    done = subprocess.run([sys.executable, "-m", "lbshape.cli", "precompute",
                           str(tmp_path / "tiny.toml")], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=1200)
    assert done.returncode == 0, done.stderr[-2000:]
    assert any((tmp_path / "xdg" / "fenics").rglob("*.c")), "no form was compiled"
    assert "build_ext" not in done.stderr and "gcc" not in done.stderr, done.stderr[-2000:]


def test_render_follows_the_output_folder_rule_of_simulate(tmp_path, capsys):
    """A folder holding other files is refused before any work; one holding only an
    earlier render's files is replaced as a whole."""
    foreign = tmp_path / "notes"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    assert main(["render", "demo", "--steps", "3", "--out", str(foreign)]) == 2
    assert "holds other files (notes.txt)" in capsys.readouterr().err
    assert sorted(p.name for p in foreign.iterdir()) == ["notes.txt"]
    earlier = tmp_path / "figs"
    earlier.mkdir()
    (earlier / "stale_render.png").write_bytes(b"old")
    assert main(["render", "demo", "--steps", "3", "--out", str(earlier)]) == 0
    out = capsys.readouterr().out
    assert not (earlier / "stale_render.png").exists()
    assert (earlier / "simulation.png").exists() and str(earlier / "simulation.png") in out
    assert ".tmp" not in out
