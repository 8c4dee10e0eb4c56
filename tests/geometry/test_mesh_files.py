"""Mesh input from files: meshio volumes, closed surfaces (and bad ones), the
``mesh`` command, posed-file examples across topologies, single-rank output under MPI."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import meshio
import numpy as np
import pytest

from lbshape.cli import main as cli_main
from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh
from lbshape.geometry.mesh_files import (
    check_surface,
    harmonic_extension,
    read_mesh_file,
    tetrahedralise_surface,
)
from lbshape.geometry.poses import apply_pose
from lbshape.geometry.primitives import structured_box
from lbshape.geometry.shapes import build_shape
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import simulate
from lbshape.scene.reader import scene_from_dict

REPO = Path(__file__).resolve().parents[2]
PYTHON = str(REPO / ".venv" / "bin" / "python") if (REPO / ".venv").is_dir() else sys.executable
SIZE = (1.0, 0.6, 0.4)


def surface_of(mesh: TetMesh) -> tuple[np.ndarray, np.ndarray]:
    """(points, triangles) of a tet mesh's boundary, vertices compacted."""
    faces = mesh.boundary_faces()
    used = np.unique(faces)
    index = np.full(mesh.n_vertices, -1)
    index[used] = np.arange(used.size)
    return mesh.points[used].copy(), index[faces]


def write_surface(path: Path, points, triangles) -> Path:
    meshio.write(path, meshio.Mesh(points, [("triangle", np.asarray(triangles, dtype=np.int32))]))
    return path


@pytest.fixture(scope="module")
def box_mesh() -> TetMesh:
    return structured_box(SIZE, (3, 2, 2))


@pytest.fixture(scope="module")
def box_surface(box_mesh):
    return surface_of(box_mesh)


# ------------------------------------------------------------------ formats
@pytest.mark.parametrize("ext", ["vtu", "vtk", "mesh"])
def test_volume_formats_round_trip(tmp_path, box_mesh, ext):
    path = tmp_path / f"box.{ext}"
    meshio.write(path, meshio.Mesh(box_mesh.points, [("tetra", box_mesh.tets)]))
    mesh = read_mesh_file(path)
    np.testing.assert_allclose(mesh.points, box_mesh.points, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(mesh.tets, box_mesh.tets)


@pytest.mark.parametrize("ext", ["stl", "obj", "ply", "off"])
def test_surface_formats_tetrahedralised(tmp_path, box_surface, ext):
    points, triangles = box_surface
    path = write_surface(tmp_path / f"box.{ext}", points, triangles)
    kept = read_mesh_file(path)  # surface kept: its vertices are all on the boundary
    assert kept.volume() == pytest.approx(np.prod(SIZE), rel=1e-9)
    boundary = np.unique(kept.boundary_faces())
    assert boundary.size == points.shape[0], f"{boundary.size} boundary vertices"
    h = 0.1
    fine = read_mesh_file(path, size=h)  # remeshed at h
    assert fine.volume() == pytest.approx(np.prod(SIZE), rel=1e-6)
    p = fine.points[fine.tets]
    edges = np.linalg.norm(p[:, [1, 2, 3, 2, 3, 3]] - p[:, [0, 0, 0, 1, 1, 2]], axis=2)
    assert 0.5 * h < np.median(edges) < 1.5 * h, f"median edge {np.median(edges):.3g} m"
    assert fine.n_vertices > 4 * kept.n_vertices


def test_volume_file_errors(tmp_path, box_mesh, box_surface):
    path = tmp_path / "box.vtu"
    meshio.write(path, meshio.Mesh(box_mesh.points, [("tetra", box_mesh.tets)]))
    with pytest.raises(LbshapeError, match="size applies to surface files"):
        read_mesh_file(path, size=0.1)
    flat = tmp_path / "skin.vtu"
    meshio.write(flat, meshio.Mesh(*box_surface[:1], [("triangle", box_surface[1])]))
    with pytest.raises(LbshapeError, match="no linear tetrahedra"):
        read_mesh_file(flat)
    (tmp_path / "box.xyz").write_text("1 2 3\n")
    with pytest.raises(LbshapeError, match="unsupported mesh format"):
        read_mesh_file(tmp_path / "box.xyz")
    (tmp_path / "junk.stl").write_bytes(b"\x00\x01garbage")
    with pytest.raises(LbshapeError, match="junk.stl"):
        read_mesh_file(tmp_path / "junk.stl")


# ------------------------------------------------------------- bad surfaces
def _two_boxes(points, triangles, shift):
    return np.vstack([points, points + np.asarray(shift)]), \
        np.vstack([triangles, triangles + points.shape[0]])


def test_bad_surfaces_named(box_surface):
    points, triangles = box_surface
    span = np.array(SIZE)
    cases = {
        "open": (points, triangles[1:], "surface is open: 3 boundary edges"),
        "edge": (*_two_boxes(points, triangles, [span[0], span[1], 0]),
                 "non-manifold: .* edges on more than two triangles"),
        "vertex": (*_two_boxes(points, triangles, span), "non-manifold: 1 vertices"),
        "pieces": (*_two_boxes(points, triangles, [2 * span[0], 0, 0]), "2 disconnected pieces"),
        "degenerate": (np.vstack([points, points[triangles[0, :2]].mean(axis=0)]),
                       np.vstack([triangles, [[triangles[0, 0], triangles[0, 1],
                                               points.shape[0]]]]), "1 zero-area triangles"),
    }
    for name, (p, t, message) in cases.items():
        with pytest.raises(LbshapeError, match=message) as info:
            tetrahedralise_surface(p, t, source=name)
        assert "\n" not in str(info.value) and str(info.value).startswith(f"{name}: ")
    cleaned, tris = check_surface(points, triangles)  # the good one passes unchanged in size
    assert cleaned.shape == points.shape and tris.shape == triangles.shape


def test_self_intersecting_surface(box_surface):
    points, triangles = box_surface
    top = np.flatnonzero((np.abs(points[:, 2] - SIZE[2]) < 1e-12)
                         & (np.abs(points[:, 0] - SIZE[0] / 3) < 1e-12)
                         & (np.abs(points[:, 1] - SIZE[1] / 2) < 1e-12))
    assert top.size == 1
    pierced = points.copy()
    pierced[top, 2] = -0.5 * SIZE[2]  # a top vertex pushed through the bottom face
    check_surface(pierced, triangles)  # closed and manifold: only gmsh sees the crossing
    for size in (None, 0.15):
        with pytest.raises(LbshapeError, match="self-intersecting"):
            tetrahedralise_surface(pierced, triangles, size=size, source="pierced")


def test_stl_duplicate_vertices_are_merged(tmp_path, box_surface):
    points, triangles = box_surface
    soup = points[triangles].reshape(-1, 3)  # every triangle with its own three vertices
    merged, tris = check_surface(soup, np.arange(soup.shape[0]).reshape(-1, 3))
    assert merged.shape == points.shape and tris.shape == triangles.shape


def test_harmonic_extension_reproduces_affine_fields(box_mesh):
    A = np.array([[0.1, 0.2, 0.0], [0.0, -0.1, 0.3], [0.05, 0.0, 0.2]])
    boundary = np.unique(box_mesh.boundary_faces())
    field = box_mesh.points @ A.T
    u = harmonic_extension(box_mesh, boundary, field[boundary])
    np.testing.assert_allclose(u, field, rtol=0, atol=1e-12)


# --------------------------------------------------------------- the command
def test_cli_mesh_from_surface_and_errors(tmp_path, box_surface, capsys):
    stl = write_surface(tmp_path / "box.stl", *box_surface)
    out = tmp_path / "box.msh"
    assert cli_main(["mesh", str(stl), "--size", "0.2", "-o", str(out)]) == 0
    assert "vertices" in capsys.readouterr().out
    mesh = read_mesh_file(out)
    assert mesh.volume() == pytest.approx(np.prod(SIZE), rel=1e-6)
    bad = write_surface(tmp_path / "open.stl", box_surface[0], box_surface[1][1:])
    target = tmp_path / "open.msh"
    assert cli_main(["mesh", str(bad), "-o", str(target)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "open" in err and err.count("\n") == 1
    assert not target.exists() and sorted(p.name for p in tmp_path.iterdir()) == [
        "box.msh", "box.stl", "open.stl"]


# ---------------------------------------------------- posed-file examples
@pytest.fixture(scope="module")
def posed_files(tmp_path_factory):
    """A folder with the object (a cuboid bar as .vtu), a cylinder surface of
    another topology at rest and twisted (STL, same facets), and a bent copy of
    the object (.vtu)."""
    folder = tmp_path_factory.mktemp("posed")
    bar, cylinder = build_shape("demo-bar"), build_shape("demo-cylinder")
    meshio.write(folder / "bar.vtu", meshio.Mesh(bar.points, [("tetra", bar.tets)]))
    bent = apply_pose(bar, "arc", angle=0.4, axis="z", anchor="max")
    meshio.write(folder / "bar-bent.vtu", meshio.Mesh(bent.points, [("tetra", bent.tets)]))
    twisted = apply_pose(cylinder, "twist", angle=1.5708, axis="z", anchor="max")
    write_surface(folder / "cylinder.stl", *surface_of(cylinder))
    write_surface(folder / "cylinder-twisted.stl", *surface_of(twisted))
    return folder


_BASE = {"object": {"mesh": "bar.vtu"}, "reduced": {"m": 6, "r": 12, "s": 20},
         "fixed": {"region": "z > 0.999"}, "simulation": {"steps": 30},
         "loads": [{"type": "region_torque", "vector": [0, 0, 100.0], "region": "z < 0.001",
                    "profile": "ramp", "duration": 0.02}]}
_TWIST = {"shape": "demo-cylinder", "pose": "twist",
          "parameters": {"angle": 1.5708, "axis": "z", "anchor": "max"}}
_ARC = {"shape": "demo-bar", "pose": "arc", "parameters": {"angle": 0.4, "axis": "z",
                                                            "anchor": "max"}}


def _scene(folder, poses, name="posed-files"):
    return scene_from_dict({**_BASE, "examples": {"stiffness": 200.0, "pose": poses}},
                           name=name, base_dir=folder)


def test_posed_files_match_analytic_poses(posed_files, tmp_path):
    """A twisted cylinder STL (with its rest STL) and a bent copy of the object
    (without rest) give the displacement of the same analytic poses."""
    poses = [_TWIST, {"mesh": "cylinder-twisted.stl", "rest": "cylinder.stl"},
             _ARC, {"mesh": "bar-bent.vtu"}]
    scene = _scene(posed_files, poses)
    pre = precompute(scene)
    c = pre.examples.example_coefficients
    twist_error = np.linalg.norm(c[1] - c[0]) / np.linalg.norm(c[0])
    assert twist_error < 0.02, f"STL pair vs analytic twist: {twist_error:.3g}"
    np.testing.assert_allclose(c[3], c[2], rtol=0, atol=1e-9 * np.abs(c[2]).max())
    assert np.linalg.norm(c[0]) > 0.5 * np.linalg.norm(c[2])  # neither is a zero pose
    result = simulate(scene, pre, method="reduced", steps=30, out=tmp_path / "run")
    assert result.stats["stable"] and result.stats["max_displacement"] > 0
    assert (tmp_path / "run" / "stats.json").is_file()


def test_posed_files_without_correspondence_refused(posed_files):
    meshio.write(posed_files / "cylinder.vtu",
                 meshio.Mesh(*[(m.points, [("tetra", m.tets)])
                               for m in [build_shape("demo-cylinder")]][0]))
    cases = [({"mesh": "cylinder-twisted.stl"}, "no vertex correspondence with the object"),
             ({"mesh": "cylinder-twisted.stl", "rest": "cylinder.vtu"}, "different meshes")]
    for pose, message in cases:
        with pytest.raises(LbshapeError, match=message) as info:
            precompute(_scene(posed_files, [pose], name="refused"), force=True)
        assert "\n" not in str(info.value) and "example 0" in str(info.value)


def test_scene_keys_for_mesh_files(posed_files):
    def read(pose=None, obj=None):
        data = {**_BASE, "object": obj or _BASE["object"]}
        if pose is not None:
            data["examples"] = {"stiffness": 1.0, "pose": [pose]}
        return scene_from_dict(data, name="keys", base_dir=posed_files)

    scene = read({"mesh": "cylinder-twisted.stl", "rest": "cylinder.stl", "size": 0.05})
    pose = scene.examples.poses[0]
    assert pose.rest.mesh_file.name == "cylinder.stl" and pose.rest.size == 0.05
    assert read(obj={"mesh": "cylinder.stl", "size": 0.1}).object.size == 0.1
    bad = [
        ({"mesh": "bar-bent.vtu", "size": 0.1}, None, "applies to built-in shapes and surface"),
        ({**_TWIST, "rest": "cylinder.stl"}, None, "'examples.pose\\[0\\].rest'"),
        ({"mesh": "bar-bent.vtu", "rest": "missing.vtu"}, None, "mesh file not found"),
        ({"mesh": "bar-bent.vtu", "rests": "cylinder.stl"}, None, "unknown key"),
        (None, {"mesh": "bar.vtu", "size": 0.1}, "applies to built-in shapes and surface"),
    ]
    for pose, obj, message in bad:
        with pytest.raises(LbshapeError, match=message):
            read(pose, obj)


# -------------------------------------------------------- rendering, MPI
def test_render_prints_no_x_warning(tmp_path):
    script = ("from lbshape.geometry.primitives import structured_box\n"
              "from lbshape.report.render import render_shapes\n"
              f"render_shapes([structured_box((1, 1, 1), (2, 2, 2))], ['box'], "
              f"{str(tmp_path / 'box.png')!r}, window_size=(200, 200))\n")
    env = {k: v for k, v in os.environ.items() if k != "DISPLAY"}
    proc = subprocess.run([PYTHON, "-c", script], cwd=REPO, env=env, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "box.png").stat().st_size > 0
    assert "X server" not in proc.stderr and "WARN" not in proc.stderr, proc.stderr


def _mpirun(*args, cwd, env) -> subprocess.CompletedProcess:
    mpirun = shutil.which("mpirun")
    if mpirun is None:
        pytest.skip("mpirun not available")
    return subprocess.run(
        [mpirun, "--allow-run-as-root", "--oversubscribe", "-n", "2", PYTHON, "-m",
         "lbshape.cli", *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


@pytest.mark.mpi
def test_two_ranks_print_and_write_once(tmp_path):
    scene = tmp_path / "small.toml"
    scene.write_text('name = "mpi-small"\n[object]\nshape = "cube"\nsize = 0.25\n'
                     '[reduced]\nm = 4\nr = 6\ns = 10\n[fixed]\nregion = "z < 0.001"\n'
                     '[simulation]\nsteps = 5\n')
    cache = tmp_path / "cache"
    env = {**os.environ, "OMP_NUM_THREADS": "1", "LBSHAPE_CACHE": str(cache),
           "PYTHONPATH": str(REPO)}
    proc = _mpirun("precompute", str(scene), cwd=REPO, env=env)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.count("precompute mpi-small") == 1, proc.stdout
    assert len(list(cache.rglob("*.npz"))) == 1
    serial = subprocess.run([PYTHON, "-m", "lbshape.cli", "precompute", str(scene), "--force"],
                            cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    assert serial.returncode == 0, serial.stderr
    first = re.compile(r"\[1/\d+\] mesh")
    bars = len(first.findall(serial.stderr))
    assert bars > 0 and len(first.findall(proc.stderr)) == bars, proc.stderr
    out = tmp_path / "run"
    proc = _mpirun("simulate", str(scene), "--out", str(out), cwd=REPO, env=env)
    assert proc.returncode != 0 and not out.exists()
    errors = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert errors == [errors[0]] and "one process" in errors[0] and "2 MPI ranks" in errors[0]
