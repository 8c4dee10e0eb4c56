"""Benchmark (Table 2, speed vs error) and render commands on the demo scene."""

from __future__ import annotations

import csv
import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from conftest import golden

from lbshape.analysis.norms import trajectory_error
from lbshape.cli import main
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh
from lbshape.pipeline.simulate import force_elements
from lbshape.studies.bench import ROW_EXTRA_KEYS, ROW_FREE_EVAL_KEYS, ROW_KEYS
from lbshape.studies.realtime import NEWTON_VARIANTS

STEPS = 15  # > the 10 warm-up steps


def _png(path):
    import matplotlib.image

    return matplotlib.image.imread(str(path))[..., :3]


def _assert_not_blank(path, *, coloured: float | None = None, drawn: float = 0.02):
    """More than ``drawn`` of the pixels differ from the white background, and (if
    given) more than ``coloured`` are colours (a colour map or plot lines), not greys."""
    rgb = _png(path)
    fraction = np.any(rgb < 0.9, axis=2).mean()
    assert fraction > drawn, f"{path.name}: only {fraction:.2%} of the pixels are drawn"
    if coloured is None:
        return
    chroma = (rgb.max(axis=2) - rgb.min(axis=2) > 0.1).mean()
    assert chroma > coloured, f"{path.name}: only {chroma:.3%} coloured pixels"


# --------------------------------------------------------------- trajectory error
def _one_tet(density=1000.0):
    points = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 3.0]])
    mesh = TetMesh(points, np.array([[0, 1, 2, 3]]))
    return mesh, mass_matrix(mesh, density), density * 1.0  # volume 2·1·3/6 = 1 m³


def test_trajectory_error_is_zero_for_identical_trajectories():
    from lbshape.geometry.primitives import structured_box

    mesh = structured_box((1.0, 0.5, 0.5), (4, 2, 2))
    u = np.random.default_rng(7).normal(size=(6, mesh.n_vertices, 3))
    times = np.linspace(0.0, 0.005, 6)
    error = trajectory_error(u, u.copy(), mass_matrix(mesh, 1000.0), times=times,
                             times_full=times.copy())
    assert error == 0.0, f"identical trajectories gave error {error}"


def test_trajectory_error_matches_hand_computed_values():
    # One tetrahedron of volume 1 m³: consistent mass M_ab = ρV/20 (1 + δ_ab) I₃, so a
    # uniform field c has ‖c‖²_M = ρV|c|² and a single-vertex field d has ρV/10 |d|².
    mesh, mass, rho_v = _one_tet()
    K, c = 5, np.array([0.01, -0.02, 0.02])  # |c| = 0.03 m
    u_full = np.array([k * np.tile(c, (4, 1)) for k in range(K + 1)])  # (6, 4, 3)
    d = np.array([0.0, 0.004, 0.003])  # |d| = 0.005 m, at vertex 2 only, at t_3
    u = u_full.copy()
    u[3, 2] += d
    expected = np.sqrt(rho_v / 10) * 0.005 / (np.sqrt(rho_v) * K * 0.03)
    np.testing.assert_allclose(trajectory_error(u, u_full, mass), expected, rtol=1e-12)
    # uniform offsets at t_1 (0.002 m) and t_2 (0.006 m): the larger one sets the error
    shifted = u_full.copy()
    shifted[1] += [0.002, 0.0, 0.0]
    shifted[2] += [0.0, 0.0, -0.006]
    np.testing.assert_allclose(trajectory_error(shifted, u_full, mass), 0.006 / (K * 0.03),
                               rtol=1e-12)
    # (k, 3n) input gives the same value
    np.testing.assert_allclose(trajectory_error(u.reshape(K + 1, -1),
                                                u_full.reshape(K + 1, -1), mass),
                               expected, rtol=1e-12)


def test_trajectory_error_rejects_mismatched_input():
    mesh, mass, _ = _one_tet()
    u = np.ones((3, 4, 3))
    times = np.array([0.0, 0.001, 0.002])
    with pytest.raises(LbshapeError, match="different times"):
        trajectory_error(u, u, mass, times=times, times_full=times + 0.001)
    with pytest.raises(LbshapeError, match="same non-empty"):
        trajectory_error(u, u[:2], mass)
    with pytest.raises(LbshapeError, match="never moves"):
        trajectory_error(u, np.zeros_like(u), mass)


# ------------------------------------------------------------------------ bench
def test_bench_command_rows_match_the_contract_and_independent_errors(tmp_path, capsys):
    from lbshape.geometry.shapes import build_shape
    from lbshape.pipeline.precompute import precompute
    from lbshape.pipeline.simulate import simulate
    from lbshape.scene import load_scene

    code = main(["bench", "demo", "--json", "--steps", str(STEPS), "--repeats", "1",
                 "--out-dir", str(tmp_path)])
    assert code == 0
    rows = json.loads(capsys.readouterr().out)["rows"]
    assert [row["method"] for row in rows] == ["full", "euclidean", "reduced"]
    for row in rows:
        assert tuple(row) == ROW_KEYS + ROW_EXTRA_KEYS + ROW_FREE_EVAL_KEYS, f"keys {list(row)}"
        assert all(row[key] is None for key in ROW_FREE_EVAL_KEYS), row  # no --free-eval
        assert all(row[key] is None for key in ROW_EXTRA_KEYS), row  # a fixed object
        assert row["scene"] == "demo"
        assert 0.0 < row["t_interp_ms"] <= row["t_total_ms"], row
    # sizes from the scene and its meshes
    scene = load_scene("demo")
    pre = precompute(scene)
    example_vertices = build_shape(scene.examples.poses[-1].source.shape).n_vertices
    by_method = {row["method"]: row for row in rows}
    for row in rows:
        assert (row["n_vertices"], row["n_tets"]) == (pre.mesh.n_vertices, pre.mesh.n_tets)
        assert row["example_vertices"] == example_vertices
        assert row["m"] == scene.reduced.m
    assert (by_method["reduced"]["r"], by_method["reduced"]["s"]) == (pre.r, force_elements(pre))
    assert by_method["full"]["error_vs_full"] == 0.0
    # the errors equal the trajectory error of independent runs (deterministic)
    mass = mass_matrix(pre.mesh, pre.material.density)
    full = simulate(scene, pre, method="full", steps=STEPS)
    for method in ("euclidean", "reduced"):
        run = simulate(scene, pre, method=method, steps=STEPS)
        expected = trajectory_error(run.displacements, full.displacements, mass,
                                    times=run.times, times_full=full.times)
        assert expected > 0.0
        np.testing.assert_allclose(by_method[method]["error_vs_full"], expected, rtol=1e-9,
                                   err_msg=method)
    # files: JSON rows identical to the printed ones, Markdown table row for the scene
    written = json.loads((tmp_path / "table2.json").read_text())
    assert written["rows"] == rows
    assert written["settings"][0]["steps"] == STEPS
    table = (tmp_path / "table2.md").read_text()
    assert f"| demo | {3 * pre.mesh.n_vertices} | {pre.mesh.n_tets} | {example_vertices} |" \
        in table
    assert sorted(p.name for p in tmp_path.iterdir()) == ["table2.json", "table2.md"]


def test_bench_command_rejects_too_few_steps_without_output(tmp_path, capsys):
    code = main(["bench", "demo", "--steps", "5", "--out-dir", str(tmp_path)])
    assert code != 0
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and "\n" not in err, err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_bench_script_writes_table_and_sweep(tmp_path, load_script):
    from lbshape.scene import load_scene

    module = load_script("bench_table2")
    own = load_scene("demo").reduced  # the second sweep point is the scene's own (r, s)
    paths = module.main([
        "demo", "--steps", str(STEPS), "--repeats", "1", "--sweep-scene", "demo",
        "--sweep-r", str(own.r), "--sweep-s", f"10,{own.s}", "--sweep-m", "",
        "--sweep-steps", str(STEPS), "--sweep-repeats", "1", "--out-dir", str(tmp_path),
    ])
    assert sorted(Path(p).name for p in paths) == [
        "speed_vs_error.csv", "speed_vs_error.png", "step_breakdown.json", "step_breakdown.md",
        "table2.json", "table2.md"]
    # the Newton policies against converged Newton at dt = 1 ms: one unchecked update and
    # the real-time tolerance stay on the converged trajectory
    study = json.loads((tmp_path / "step_breakdown.json").read_text())["demo"]
    assert [v["label"] for v in study] == [label for label, _, _ in NEWTON_VARIANTS]
    one, realtime, converged = study
    limit = golden("bench_render.one_update_vs_converged").limit
    assert one["mean_iterations"] == 1.0 and one["difference"] < limit, one
    assert 1.0 <= realtime["mean_iterations"] <= converged["mean_iterations"], realtime
    assert realtime["difference"] < 1e-3, realtime
    assert converged["difference"] == 0.0
    lines = (tmp_path / "speed_vs_error.csv").read_text().splitlines()
    assert lines[0].startswith("#")
    points = list(csv.DictReader(lines[1:]))
    # both force models: the polynomial once per r, the cubature at every s; r is the
    # basis' size (the scene's r and the example responses appended to it)
    from lbshape.pipeline.precompute import precompute

    r = precompute(load_scene("demo")).r
    assert r > own.r
    assert [(int(p["r"]), int(p["s_max"]), p["forces"]) for p in points] == [
        (r, own.s, "polynomial"), (r, 10, "cubature"), (r, own.s, "cubature")]
    for p in points:
        assert 0 < int(p["s"]) <= int(p["s_max"]) and float(p["error_vs_full"]) > 0
    # the sweep point with the scene's own r, s and force model is Table 2's reduced row
    reduced = next(r for r in json.loads((tmp_path / "table2.json").read_text())["rows"]
                   if r["method"] == "reduced")
    np.testing.assert_allclose(float(points[0]["error_vs_full"]), reduced["error_vs_full"],
                               rtol=1e-5)
    # three points far left of the 1 ms line (the reduced step takes ~0.05 ms): few pixels
    _assert_not_blank(tmp_path / "speed_vs_error.png", coloured=0.0005)


# ----------------------------------------------------------------------- render
@pytest.mark.slow
def test_render_command_writes_non_blank_pngs(tmp_path):
    out = tmp_path / "figures"
    assert main(["render", "demo", "--out", str(out), "--steps", "30"]) == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == ["comparison.json", "comparison.png", "eigenfunctions.png",
                     "examples_on_object.png", "examples_raw.png", "simulation.png",
                     "summary.json"], names
    for name in ("eigenfunctions.png", "examples_on_object.png", "simulation.png",
                 "comparison.png"):
        _assert_not_blank(out / name, coloured=0.01)
    _assert_not_blank(out / "examples_raw.png")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["simulation"]["steps"] == 30 and summary["message"] == ""
    comparison = json.loads((out / "comparison.json").read_text())
    assert "no examples" in comparison["panels"][1] and comparison["example_influence"] > 0


def test_figure3_panels_for_a_same_and_other_topology_pair(tmp_path):
    from lbshape.scene import load_scene
    from lbshape.scene.schema import MeshSource
    from lbshape.studies.figures import figure3

    other = load_scene("demo")  # cylinder examples
    poses = tuple(dataclasses.replace(p, source=MeshSource(shape="demo-bar"))
                  for p in other.examples.poses)
    same = dataclasses.replace(other, name="demo-same",
                               examples=dataclasses.replace(other.examples, poses=poses))
    result = figure3(same, other, tmp_path / "figure3.png", steps=20)
    assert len(result.labels) == 5 and result.labels[0] == "rest"
    assert "no examples" in result.labels[1] and "demo-cylinder" in result.labels[4]
    maxima = np.asarray(result.final_max_displacement)
    assert maxima[0] == 0.0 and np.all(maxima[1:] > 0), maxima
    assert np.isfinite(result.reduced_vs_full_final)
    _assert_not_blank(result.path, coloured=0.01)
    assert json.loads((tmp_path / "figure3.json").read_text())["steps"] == 20
    with pytest.raises(LbshapeError, match="needs scenes with examples"):
        figure3(dataclasses.replace(same, examples=None), other, tmp_path / "x.png")


@pytest.mark.slow
def test_figure6_measures_local_against_global_examples_on_one_object(tmp_path):
    import meshio

    from lbshape.geometry.primitives import structured_box
    from lbshape.pipeline.precompute import precompute
    from lbshape.pipeline.simulate import simulate
    from lbshape.scene.reader import scene_from_dict
    from lbshape.studies.figures import figure6

    bar = structured_box((0.2, 0.2, 1.0), (2, 2, 8))
    meshio.write(tmp_path / "bar.vtu", meshio.Mesh(bar.points, [("tetra", bar.tets)]))
    twist = {"mesh": "bar.vtu", "pose": "twist", "parameters": {"angle": 1.0, "axis": "z",
                                                                 "anchor": "min"}}
    bend = {"mesh": "bar.vtu", "pose": "arc", "parameters": {"angle": 0.5, "axis": "z",
                                                              "direction": "x"}}
    common = {"object": {"mesh": "bar.vtu"}, "reduced": {"m": 4, "r": 12, "s": 20},
              "fixed": {"region": "z < 0.001"}, "simulation": {"steps": 30},
              "loads": [{"type": "gravity", "vector": [3.0, 0.0, 0.0]}]}
    global_scene = scene_from_dict({**common, "examples": {"stiffness": 300.0,
                                                           "pose": [twist, bend]}},
                                   name="bar-global", base_dir=tmp_path)
    local_scene = scene_from_dict(
        {**common, "examples": {"stiffness": 300.0, "pose": [twist, bend]},
         "regions": [{"name": "low", "region": "z < 0.5", "examples": [0]},
                     {"name": "high", "region": "z > 0.5", "examples": [1]}]},
        name="bar-local", base_dir=tmp_path)
    result = figure6(global_scene, local_scene, tmp_path / "figure6.png")
    _assert_not_blank(result.path, coloured=0.01)
    _assert_not_blank(result.difference, coloured=0.005)
    # the numbers against the runs made here, independently of the figure
    finals = {}
    for name, scene in (("global", global_scene), ("local", local_scene)):
        finals[name] = simulate(scene, precompute(scene)).displacements[-1]
    distance = np.linalg.norm(finals["local"] - finals["global"], axis=1)
    assert result.difference_max == pytest.approx(distance.max(), rel=1e-9)
    assert result.difference_max > 1e-3  # the two example sets pull differently
    height = np.ptp(bar.points[:, 2])
    top = bar.points[:, 2] > 0.5
    assert result.difference_by_region["high"] == pytest.approx(
        distance[top].max() / height, rel=1e-9)
    assert result.region_displacement["local"]["high"] == pytest.approx(
        np.linalg.norm(finals["local"][top], axis=1).max() / height, rel=1e-9)
    stored = json.loads((tmp_path / "figure6.json").read_text())
    assert set(stored["closest_example"]["local"]) == {"low", "high"}
    with pytest.raises(LbshapeError, match="global examples and one with local"):
        figure6(global_scene, global_scene, tmp_path / "x.png")
    harder = dataclasses.replace(local_scene, loads=tuple(
        dataclasses.replace(load, vector=(6.0, 0.0, 0.0)) for load in local_scene.loads))
    with pytest.raises(LbshapeError, match="differ in loads"):
        figure6(global_scene, harder, tmp_path / "x.png")


def test_render_command_bad_scene_leaves_no_output(tmp_path, capsys):
    scene = tmp_path / "bad.toml"
    scene.write_text('[object]\nshape = "demo-bar"\n[reduced]\nr = 100000\n'
                     '[fixed]\nregion = "z > 0.999"\n')
    out = tmp_path / "figures"
    assert main(["render", str(scene), "--out", str(out)]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("error:") and "reduced.r" in err[-1], err
    assert not out.exists()


@pytest.mark.slow
def test_resting_step_measures_a_body_on_the_floor(load_script):
    """The free-body bench's resting window: bar-s-cuboid from 1.5 s is on the floor
    (most steps touch a plane, in contact passes of 1/3 ms, swept); the step file's
    section marks a mean over 1 ms as missed."""
    from lbshape.pipeline.precompute import precompute
    from lbshape.scene import load_scene
    from lbshape.studies.realtime import free_body_step_markdown

    module = load_script("bench_free_body")
    scene = load_scene("bar-s-cuboid")
    row = module.resting_step(scene, precompute(scene), repeats=1)
    assert row["touching_share"] > 0.5
    assert 2.0 <= row["passes_per_step"] <= 3.0  # contact passes, a few in flight
    assert row["sweeps_per_step"] >= row["passes_per_step"]
    assert row["center_drift"] < 0.5  # resting, sliding or rocking: not thrown
    payload = {"rows": [], "machine": {"cpu": "x", "cores": 2, "threads": {}},
               "resting": [dict(row, mean_ms=1.2), dict(row, scene="fast", mean_ms=0.5)]}
    text = free_body_step_markdown(payload)
    assert "| bar-s-cuboid | 1 |" in text and "| 1.200 | **no** |" in text
    assert "| 0.500 | yes |" in text
    assert "On the floor" not in free_body_step_markdown(dict(payload, resting=[]))
