"""``lbshape live``: the on-screen window under a display (a virtual X server started here
when none is set), driven by scripted events through the same code as the mouse and keys.

Physical checks: a drag pulls the dragged vertex towards its target against the same run
without it; the examples switch changes the shape and the picture; the loop is paced to
the wall clock (never ahead of it); a divergence stops it with the engine's message.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import golden

from lbshape.errors import LbshapeError
from lbshape.live.display import virtual_display
from lbshape.live.events import LiveEvent, read_events
from lbshape.live.session import LiveSession
from lbshape.live.window import LiveWindow
from lbshape.pipeline.precompute import precompute
from lbshape.scene import load_scene

REPOSITORY = Path(__file__).resolve().parents[2]
#: steps of the deterministic runs (paused, stepped by events): 0.3 s of the demo
STEPS = 300


@pytest.fixture(scope="module")
def display():
    """An X display: ``$DISPLAY``, else a virtual X server (``Xvfb``) for this module."""
    if not os.environ.get("DISPLAY") and shutil.which("Xvfb") is None:
        pytest.skip("no DISPLAY and no Xvfb (Debian package xvfb, installed by scripts/setup)")
    with virtual_display() as name:
        yield name


@pytest.fixture(scope="module")
def demo():
    scene = load_scene("demo")
    return scene, precompute(scene, progress=False)


def _corner(points: np.ndarray) -> int:
    """The demo bar's free bottom corner (lowest z, then largest x + y)."""
    low = np.flatnonzero(points[:, 2] < points[:, 2].min() + 1e-9)
    return int(low[np.argmax(points[low, 0] + points[low, 1])])


def _stepped(demo, events, *, screenshot=None, **session_options):
    """A paused window stepped :data:`STEPS` steps after ``events`` (all at t = 0);
    returns the session and the stats."""
    scene, pre = demo
    session = LiveSession(scene, pre, **session_options)
    script = [LiveEvent(0.0, "pause"), *events, LiveEvent(0.0, "step", steps=STEPS)]
    stats = LiveWindow(session, seconds=0.3, screenshot=screenshot, events=script,
                       window_size=(480, 360)).run()
    assert session.steps == STEPS and stats["steps"] == STEPS
    return session, stats


def test_a_drag_pulls_the_vertex_towards_the_target(display, demo):
    _, pre = demo
    vertex = _corner(pre.mesh.points)
    target = pre.mesh.points[vertex] + np.array([0.25, 0.0, 0.0])
    dragged, stats = _stepped(demo, [LiveEvent(0.0, "drag", vertex=vertex,
                                               to=tuple(target))], drag_stiffness=4e5)
    free, _ = _stepped(demo, [])
    with_drag = np.linalg.norm(dragged.vertex_position(vertex) - target)
    without = np.linalg.norm(free.vertex_position(vertex) - target)
    # against the examples' pull
    assert with_drag < golden("live.drag_distance_ratio").limit * without
    assert stats["drags"] == 1
    # the drawn vertex is the simulated one
    assert np.allclose(dragged.points()[vertex], dragged.vertex_position(vertex))


def test_the_examples_switch_changes_shape_and_picture(display, demo, tmp_path):
    on, _ = _stepped(demo, [], screenshot=tmp_path / "on.png")
    off, stats = _stepped(demo, [LiveEvent(0.0, "toggle-examples")],
                          screenshot=tmp_path / "off.png")
    assert stats["examples_on"] is False
    rest = demo[1].mesh.points
    u_on, u_off = on.points() - rest, off.points() - rest
    change = np.linalg.norm(u_on - u_off, axis=1).max()
    # the largest vertex change against the largest displacement without examples
    ratio = golden("live.examples_switch_change").limit
    assert change > ratio * np.linalg.norm(u_off, axis=1).max()
    import matplotlib.image

    a = matplotlib.image.imread(str(tmp_path / "on.png"))[..., :3]
    b = matplotlib.image.imread(str(tmp_path / "off.png"))[..., :3]
    assert a.shape == b.shape == (360, 480, 3)
    changed = np.mean(np.abs(a - b).max(axis=2) > 0.1)
    assert changed > golden("live.examples_switch_pixels").limit


def test_reset_returns_to_rest_and_keeps_the_switch(display, demo):
    session, _ = _stepped(demo, [LiveEvent(0.0, "toggle-examples")])
    assert np.abs(session.points() - demo[1].mesh.points).max() > 1e-3
    session.reset()
    assert session.time == 0.0 and not session.examples_on
    assert np.abs(session.points() - demo[1].mesh.points).max() == 0.0


def test_the_mouse_picks_a_vertex_and_drags_it_in_the_view_plane(display, demo):
    scene, pre = demo
    session = LiveSession(scene, pre)
    window = LiveWindow(session, seconds=0.2, window_size=(480, 360))
    plotter = window.plotter
    plotter.show(auto_close=False, interactive_update=True)
    try:
        window._install_mouse()
        iren = plotter.iren.interactor
        points = session.points()
        camera = np.array(plotter.camera.position)
        surface = np.unique(window._ids)
        vertex = int(surface[np.argmin(np.linalg.norm(points[surface] - camera, axis=1))])
        x, y, depth = window._display(points[vertex])
        before = plotter.camera.position
        iren.SetEventPosition(int(round(x)), int(round(y)))
        iren.InvokeEvent("LeftButtonPressEvent")
        assert session.drag is not None and session.drag.vertex == vertex
        iren.SetEventPosition(int(round(x)) + 60, int(round(y)))
        iren.InvokeEvent("MouseMoveEvent")
        moved = window._display(session.drag.target)
        assert moved[0] == pytest.approx(round(x) + 60, abs=1.0)
        assert moved[1] == pytest.approx(round(y), abs=1.0)
        assert moved[2] == pytest.approx(depth, abs=1e-6)  # the plane facing the camera
        assert plotter.camera.position == before  # the press did not turn the camera
        iren.InvokeEvent("LeftButtonReleaseEvent")
        assert session.drag is None
    finally:
        window.close()


def _cli(args, env_display, tmp_path):
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    if env_display is None:
        env.pop("DISPLAY", None)
    else:
        env["DISPLAY"] = env_display
    return subprocess.run([sys.executable, "-m", "lbshape.cli", "live", *args], cwd=tmp_path,
                          env={**env, "PYTHONPATH": str(REPOSITORY)}, capture_output=True,
                          text=True, timeout=300)


@pytest.mark.slow
def test_scripted_run_prints_paced_stats_and_a_screenshot(display, demo, tmp_path):
    shot = tmp_path / "live.png"
    result = _cli(["demo", "--seconds", "2", "--screenshot", str(shot), "--json"], display,
                  tmp_path)
    assert result.returncode == 0, result.stderr
    stats = json.loads(result.stdout)
    assert list(stats)[:5] == ["frames", "fps", "sim_time_s", "wall_time_s", "t_total_ms"]
    assert stats["frames"] >= 3 and stats["fps"] > 0
    assert 2.0 <= stats["wall_time_s"] < 10.0
    assert stats["fps"] == pytest.approx(stats["frames"] / stats["wall_time_s"])
    # paced: never ahead of the clock; behind it only by the capped first frames
    paced = golden("live.paced_sim_time").limit
    assert paced * stats["wall_time_s"] <= stats["sim_time_s"] <= stats["wall_time_s"] + 1e-9
    assert stats["sim_time_s"] == pytest.approx(stats["steps"] * stats["dt"])
    assert 0.0 < stats["t_total_ms"] < golden("live.step_ms").limit
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
def test_a_divergence_stops_the_window_with_the_step(display, demo, tmp_path):
    vertex = _corner(demo[1].mesh.points)
    events = tmp_path / "events.json"
    events.write_text(json.dumps([{"t": 0, "type": "pause"},
                                  {"t": 0, "type": "drag", "vertex": vertex,
                                   "to": [50.0, 0.0, 0.0]},
                                  {"t": 0, "type": "step", "steps": 200}]))
    result = _cli(["demo", "--seconds", "5", "--events", str(events), "--drag-stiffness",
                   "1e9"], display, tmp_path)
    assert result.returncode == 3
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("error: simulation stopped:") and "at step" in last


def test_without_a_display_it_refuses_in_one_line(tmp_path):
    result = _cli(["demo", "--seconds", "1"], None, tmp_path)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [result.stderr.strip()]
    assert "DISPLAY" in result.stderr and "xvfb-run" in result.stderr


def test_events_are_read_and_checked(tmp_path):
    path = tmp_path / "events.json"
    path.write_text(json.dumps([{"t": 1.5, "type": "release"},
                                {"t": 0.5, "type": "drag", "vertex": 3, "to": [0, 0, 1]},
                                {"t": 2, "type": "screenshot", "file": "a.png"}]))
    events = read_events(path)
    assert [e.type for e in events] == ["drag", "release", "screenshot"]
    assert events[0].to == (0.0, 0.0, 1.0) and events[2].file == str(tmp_path / "a.png")
    for bad, words in (([{"t": 0, "type": "jump"}], "type must be one of"),
                       ([{"t": -1, "type": "pause"}], "t must be"),
                       ([{"t": 0, "type": "drag", "to": [0, 0, 0]}], "integer vertex"),
                       ([{"t": 0, "type": "move", "to": [0, 0]}], "to = [x, y, z]"),
                       ([{"t": 0, "type": "pause", "speed": 2}], "unknown keys"),
                       ({"t": 0}, "list of events")):
        path.write_text(json.dumps(bad))
        with pytest.raises(LbshapeError) as error:
            read_events(path)
        assert words in str(error.value)


def test_a_vertex_out_of_range_is_a_user_error(demo):
    session = LiveSession(*demo)
    with pytest.raises(LbshapeError, match="vertex must be an index"):
        session.grab(session.pre.mesh.n_vertices)


def test_a_free_body_moves_in_view_with_its_planes(display):
    scene = load_scene("car")
    session = LiveSession(scene, precompute(scene, progress=False))
    window = LiveWindow(session, seconds=0.2, window_size=(480, 360))
    plotter = window.plotter
    plotter.show(auto_close=False, interactive_update=True)
    try:
        # the floor and the wall drawn as rectangles reaching far beyond the car
        bounds = [getattr(actor, "GetBounds", lambda: None)()
                  for actor in plotter.renderer.actors.values()]
        sizes = [np.ptp(np.reshape(b, (3, 2)), axis=1).max() for b in bounds
                 if b is not None and len(b) == 6]
        assert sum(size > 10.0 for size in sizes) == 2
        window._draw()
        start, focus = session.center(), np.array(plotter.camera.focal_point)
        for _ in range(600):  # thrown into the wall and back (0.6 s)
            session.step_once()
        window._draw()
        shift = session.center() - start
        assert np.linalg.norm(shift) > golden("live.free_body_shift").limit
        assert np.allclose(np.array(plotter.camera.focal_point) - focus, shift, atol=1e-9)
        # the contact planes hold it: the floor at z = 0, the wall at x = 1.2 m
        points = session.points()
        assert points[:, 2].min() > -0.05 and points[:, 0].max() < 1.25
    finally:
        window.close()
