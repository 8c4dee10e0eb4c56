"""The public API (``import lbshape``): its names, the documented snippet in a fresh
interpreter for each method and a free body, the same trajectory as ``lbshape simulate``,
scenes built in code from arrays in memory, and one-line errors for bad input."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import lbshape
import lbshape.api as lbshape_api
from lbshape.cli.main import main
from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import TetMesh
from lbshape.geometry.primitives import structured_box
from lbshape.pipeline.precompute_key import scene_cache_key

ROOT = Path(__file__).resolve().parents[2]
API_NAMES = sorted([
    "LbshapeError", "RunRecord", "Scene", "Simulation", "SolverError", "TetMesh",
    "lb_spectrum", "load_scene", "precompute", "read_mesh", "simulation",
    # a run with its outputs and its error against the full reference
    "METHODS", "SimulationOutput", "compare", "run_error", "simulate",
])
#: the rest of lbshape.api: building blocks of the command line (meshes, modes, several
#: scenes, a run's files), not re-exported by ``import lbshape``
BUILDING_BLOCKS = sorted([
    "RUN_FILES", "WARMUP_STEPS", "write_outputs",
    "CAD_FORMATS", "LENGTH_UNITS",
    "Material", "SHAPES", "SURFACE_FORMATS", "build_mesh", "expand_scenes", "get_shape",
    "linear_modes", "mesh_source", "region_vertices", "run_collectively", "run_jobs",
    "summary_table", "write_mesh",
])


def _python(code: str, *, cwd: Path | None = None, env: dict | None = None) -> str:
    """Run ``code`` in a fresh interpreter with this checkout's package; its stdout."""
    environ = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1", **(env or {})}
    done = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=cwd or ROOT,
                          env=environ, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout


def test_import_is_light_and_exports_exactly_the_api():
    out = _python("""
        import json, sys
        import lbshape
        heavy = [m for m in ("dolfinx", "pyvista", "matplotlib", "gmsh", "numba", "scipy")
                 if m in sys.modules]
        print(json.dumps({"heavy": heavy, "all": lbshape.__all__}))
    """)
    result = json.loads(out)
    assert result["heavy"] == []
    assert sorted(result["all"]) == API_NAMES
    assert all(getattr(lbshape, name) is not None for name in API_NAMES)
    assert sorted(lbshape_api.__all__) == sorted(API_NAMES + BUILDING_BLOCKS)
    assert issubclass(lbshape.SolverError, lbshape.LbshapeError)
    assert lbshape.TetMesh is TetMesh
    with pytest.raises(AttributeError):
        lbshape.no_such_name  # noqa: B018


#: the documented snippet (PLAN's "Public API"), as a user types it; few steps
SNIPPET = """
    import json
    import lbshape
    scene = lbshape.load_scene({scene!r})
    pre = lbshape.precompute(scene)
    out = {{}}
    for method in {methods!r}:
        sim = lbshape.simulation(scene, pre, method=method)
        for _ in range({steps}):
            sim.step()
        u = sim.displacement()
        t = sim.time
        vertex = int(abs(u).sum(axis=1).argmax())
        target = sim.points()[vertex] + [0.0, 0.0, 0.01]
        on = sim.set_examples(False); sim.grab(vertex, target); sim.step(); sim.release()
        sim.reset(); rest = float(abs(sim.displacement()).max()); state = sim.state
        record = sim.run({steps})
        assert isinstance(record, lbshape.RunRecord)
        out[method] = {{"shape": list(u.shape), "time": t, "max": float(abs(u).max()),
                       "examples": on, "rest": rest, "after_reset": sim.time,
                       "record_steps": record.steps, "stable": record.stable,
                       "state_time": state.time}}
    print(json.dumps(out))
"""


def _check_snippet(out: dict, n: int, dt: float, steps: int) -> None:
    for result in out.values():
        assert result["shape"] == [n, 3]  # every engine: (n, 3)
        assert result["time"] == pytest.approx(steps * dt, rel=1e-12)
        assert result["max"] > 0.0
        assert result["rest"] <= 1e-12 and result["state_time"] == 0.0  # round-off: free body
        assert result["stable"] and result["record_steps"] == steps
        assert result["after_reset"] == pytest.approx(steps * dt, rel=1e-12)


@pytest.mark.slow
def test_snippet_runs_in_a_fresh_interpreter_for_every_method():
    steps = 10
    out = json.loads(_python(SNIPPET.format(scene="demo", steps=steps,
                                            methods=("reduced", "euclidean", "full"))))
    scene = lbshape.load_scene("demo")
    assert sorted(out) == ["euclidean", "full", "reduced"]
    _check_snippet(out, 84, scene.simulation.dt, steps)
    assert all(result["examples"] is False for result in out.values())


@pytest.mark.slow
def test_snippet_runs_a_free_body():
    steps = 5
    # the free-body engine and the full one (euclidean is the reduced engine, another target)
    out = json.loads(_python(SNIPPET.format(scene="bar-s-cuboid", steps=steps,
                                            methods=("reduced", "full"))))
    scene = lbshape.load_scene("bar-s-cuboid")
    assert scene.is_free
    pre = lbshape.precompute(scene)  # cached by the interpreter above
    _check_snippet(out, pre.mesh.n_vertices, scene.simulation.dt, steps)


def test_api_trajectory_is_the_simulate_command_s(tmp_path, capsys):
    steps = 20
    assert main(["simulate", "demo", "--steps", str(steps), "--out", str(tmp_path / "run"),
                 "--no-influence"]) == 0
    capsys.readouterr()
    stored = np.load(tmp_path / "run" / "states.npz")
    scene = lbshape.load_scene("demo")
    sim = lbshape.simulation(scene, lbshape.precompute(scene))
    frames = [sim.displacement()]
    for _ in range(steps):
        sim.step()
        frames.append(sim.displacement())
    frames = np.array(frames)
    scale = np.linalg.norm(stored["displacements"])
    assert frames.shape == stored["displacements"].shape
    assert np.linalg.norm(frames - stored["displacements"]) <= 1e-12 * scale
    # run() from the start again gives the same record
    sim.reset()
    record = sim.run(steps)
    np.testing.assert_allclose(record.times, stored["times"], rtol=1e-12)
    assert np.linalg.norm(sim.displacements(record) - stored["displacements"]) <= 1e-12 * scale


def _box() -> TetMesh:
    return structured_box((0.2, 0.04, 0.04), (10, 2, 2))


@pytest.mark.slow
def test_scene_from_arrays_in_memory_writes_only_the_cache(tmp_path):
    work, tmp, cache = tmp_path / "work", tmp_path / "tmp", tmp_path / "cache"
    work.mkdir()
    tmp.mkdir()
    out = _python("""
        import json
        import numpy as np
        import lbshape
        from lbshape.geometry.primitives import structured_box

        box = structured_box((0.2, 0.04, 0.04), (10, 2, 2))
        points, tets = np.array(box.points), np.array(box.tets)
        bent = points.copy()
        bent[:, 2] += 0.2 * points[:, 0] ** 2
        scene = lbshape.Scene.from_mesh(
            (points, tets), name="bar-in-memory", fixed="x < 1e-6",
            material={"young": 2e5, "density": 1000.0}, reduced={"m": 6, "r": 10, "s": 20},
            examples=[{"pose": "twist", "parameters": {"angle": 0.8, "axis": "x"}}, bent],
            example_stiffness=500.0, dt=0.005, steps=10)
        sim = lbshape.simulation(scene)  # precomputes it (into the cache)
        pre = sim.pre
        record = sim.run(10)
        again = lbshape.precompute(lbshape.Scene.from_mesh(
            (points.copy(), tets.copy()), name="bar-in-memory", fixed="x < 1e-6",
            material={"young": 2e5, "density": 1000.0}, reduced={"m": 6, "r": 10, "s": 20},
            examples=[{"pose": "twist", "parameters": {"angle": 0.8, "axis": "x"}}, bent],
            example_stiffness=500.0, dt=0.005, steps=10))
        print(json.dumps({"stable": record.stable, "shape": list(sim.displacement().shape),
                          "moved": float(abs(sim.displacement()).max()),
                          "cached": again.stages.from_cache, "key": again.key == pre.key}))
    """, cwd=work, env={"LBSHAPE_CACHE": str(cache), "TMPDIR": str(tmp)})
    result = json.loads(out)
    assert result == {"stable": True, "shape": [_box().n_vertices, 3],
                      "moved": result["moved"], "cached": True, "key": True}
    assert result["moved"] > 0.0
    assert list(work.iterdir()) == [] and list(tmp.iterdir()) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cache", "tmp", "work"]
    assert any(cache.glob("precompute-*.npz"))  # named by its content


def test_from_mesh_keys_the_cache_by_the_arrays():
    box = _box()
    scene = lbshape.Scene.from_mesh(box, fixed="x < 1e-6")
    same = lbshape.Scene.from_mesh((box.points.copy(), box.tets.copy()), fixed="x < 1e-6")
    moved = lbshape.Scene.from_mesh(box.with_points(box.points * 1.01), fixed="x < 1e-6")
    assert scene_cache_key(scene) == scene_cache_key(same)
    assert scene_cache_key(scene) != scene_cache_key(moved)
    assert scene == same and scene != moved
    assert scene.object.mesh is not None and scene.is_free is False


def test_from_mesh_examples_from_code():
    box = _box()
    posed = box.with_points(box.points + [0.0, 0.0, 0.01])
    scene = lbshape.Scene.from_mesh(
        box, fixed={"region": "x < 1e-6"}, example_stiffness=100.0,
        examples=[{"pose": "arc", "parameters": {"angle": 0.5, "axis": "x"}},
                  {"pose": "s-bend", "parameters": {"amplitude": 0.01, "axis": "x"}},
                  posed, (posed.points, posed.tets), posed.points])
    poses = scene.examples.poses
    assert [p.pose for p in poses] == ["arc", "s-bend", None, None, None]
    assert all(p.source.mesh is not None for p in poses)
    assert [p.is_posed_file for p in poses] == [False, False, True, True, True]
    assert poses[2].source == poses[3].source == poses[4].source
    assert poses[0].source == scene.object


@pytest.mark.parametrize("mesh, options, message", [
    ("bar.msh", {}, "expected a TetMesh or (points, tets)"),
    ((np.zeros((4, 3)), np.array([[0, 1, 2, 3]])), {}, "degenerate"),
    ((np.eye(4)[:, :3], [[0, 1, 2, 9]]), {}, "out of range"),
    ((np.eye(4)[:, :3], [[0.5, 1, 2, 3]]), {}, "(t, 4) integer"),
    (None, {"fixed": "z <"}, "'fixed.region'"),
    (None, {"material": {"poisson": 0.7}}, "poisson"),
    (None, {"material": {"yung": 1e5}}, "unknown key 'material.yung'"),
    (None, {"dt": 0.0}, "'simulation.dt' must be > 0"),
    (None, {"examples": [{"pose": "twist"}], "example_stiffness": 1.0}, "needs 'angle'"),
    (None, {"examples": [{"pose": "twirl", "parameters": {"angle": 1}}],
            "example_stiffness": 1.0}, "'examples.pose[0].pose' must be one of"),
    (None, {"examples": [np.zeros((3, 3))], "example_stiffness": 1.0}, "posed points"),
    (None, {"examples": [{"pose": "arc", "parameters": {"angle": 1}}],
            "example_stiffness": "stiff"}, "'examples.stiffness' must be a number >= 0"),
    (None, {"examples": [{"pose": "arc", "parameters": {"angle": 1}}],
            "example_stiffness": None}, "example_stiffness must be a number >= 0"),
    (None, {"example_stiffness": 10.0}, "'examples.pose' needs at least 1 entries"),
    (None, {"loads": [{"type": "gravity"}]}, "'loads[0].vector'"),
])
def test_bad_input_to_from_mesh_is_a_one_line_error(mesh, options, message):
    with pytest.raises(LbshapeError) as caught:
        lbshape.Scene.from_mesh(_box() if mesh is None else mesh, name="bad", **options)
    text = str(caught.value)
    assert message in text and "\n" not in text and text.startswith("scene bad: ")


def test_simulation_rejects_an_unknown_method():
    scene = lbshape.Scene.from_mesh(_box(), fixed="x < 1e-6")
    with pytest.raises(LbshapeError, match="method must be one of"):
        lbshape.simulation(scene, object(), method="implicit")


@pytest.mark.parametrize("method", ["reduced", "full"])
def test_grab_pulls_and_state_comes_back(method):
    scene = lbshape.load_scene("demo")
    sim = lbshape.simulation(scene, lbshape.precompute(scene), method=method)
    assert sim.set_examples(False) is False and sim.set_examples(True) is True
    sim.run(5)
    state = sim.state
    after = sim.run(5)
    again = (sim.reset(state), sim.run(5))[1]
    np.testing.assert_array_equal(again.states, after.states)
    # a pull towards 2 cm along +x of a bottom vertex (the top is fixed), from the same state
    sim.reset(state)
    bottom = np.flatnonzero(sim.rest_points[:, 2] < 1e-3)
    vertex = int(bottom[np.argmax(sim.rest_points[bottom, 0])])
    start = sim.points()[vertex].copy()
    target = start + [0.02, 0.0, 0.0]
    sim.grab(vertex, target)
    assert sim.drag.stiffness == pytest.approx(sim.drag_stiffness)
    sim.run(20)
    pulled = np.linalg.norm(sim.points()[vertex] - target)
    sim.release()
    assert sim.drag is None
    sim.reset(state)
    sim.run(20)
    free = np.linalg.norm(sim.points()[vertex] - target)
    assert pulled < 0.9 * free  # the pull brought it nearer its target
    sim.grab(vertex)  # default target: where it is
    sim.move(start)
    np.testing.assert_array_equal(sim.drag.target, start)
    sim.reset()  # rest at t = 0, the pull released
    assert sim.time == 0.0 and sim.drag is None
    assert np.abs(sim.displacement()).max() == 0.0
    with pytest.raises(LbshapeError, match="vertex must be an index"):
        sim.grab(sim.n_vertices)
