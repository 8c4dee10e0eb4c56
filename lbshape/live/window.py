"""The on-screen window of ``lbshape live``: a :class:`~lbshape.live.session.LiveSession`
stepped to the wall clock and drawn with pyvista/VTK (imported inside functions).

A repeating VTK timer calls :meth:`LiveWindow.frame`: it feeds the scripted events that
are due, advances the session by the wall time since the last frame
(:meth:`~lbshape.live.session.LiveSession.advance`: whole steps of the scene's dt,
capped), moves the drawn surface's points in place, updates the corner text (simulated
time, mean step cost, frame rate) and renders. Contact planes are the off-screen
pictures' rectangles (:func:`lbshape.report.render.plane_rectangles`), reaching far, drawn
as grids of lines (:func:`plane_grid`); the camera follows a free body's centre of mass.

Interaction (:data:`KEYS`): the left mouse button on the object picks the nearest
vertex of the picked cell and drags it (the cursor is mapped to the plane through the
vertex facing the camera; a spring pulls the vertex there, drawn as a line); elsewhere
the left button turns the camera as usual. Keys pause, step, switch the examples and
reset. Scripted events (:func:`lbshape.live.events.read_events`) go through the same
methods.

The window needs an X display: a desktop, or a virtual one (``xvfb-run -a lbshape live
...``); without ``DISPLAY`` :func:`run_live` refuses with one line. Off-screen batch
pictures stay in :mod:`lbshape.report.render`.
"""

from __future__ import annotations

import math
import os
import time
from pathlib import Path

import numpy as np

from lbshape.errors import LbshapeError, SolverError
from lbshape.io.atomic import write_atomic
from lbshape.live.display import require_display
from lbshape.live.events import LiveEvent
from lbshape.live.session import LiveSession
from lbshape.report.figures import view_vector_of
from lbshape.report.render import (
    PLANE_COLOR,
    bounds_of,
    plane_rectangles,
    quiet_vtk,
    scene_planes,
    set_camera,
    to_grid,
)

#: key → what it does (besides pyvista's and VTK's own: q quits, r frames the camera)
KEYS = {"space": "pause / resume", "n": "one step (paused)", "x": "examples on / off",
        "z": "reset to rest"}
#: the timer's period (ms): frames follow as fast as the rendering allows
TIMER_MS = 5
#: the window's size in pixels
WINDOW_SIZE = (960, 720)
#: contact planes reach this many times the size of the object and the planes' points
#: beyond them (a free body moves far in a live run; the camera follows it)
PLANE_REACH = 10.0
#: contact planes are drawn as grids of lines this many object diagonals apart (a
#: translucent plane filling a software-rendered window tripled a frame's cost)
GRID_SPACING = 0.5
#: the camera's zoom after framing the object and the planes' points at rest
CAMERA_ZOOM = 1.0
#: the order of the stats of a live run (``--json``); the first five are the contract's
STATS_KEYS = ("frames", "fps", "sim_time_s", "wall_time_s", "t_total_ms", "scene", "steps",
              "dt", "realtime_ratio", "render_ms", "examples_on", "drags", "paused",
              "n_vertices", "r", "threads", "window", "gl_renderer")


def plane_grid(pv, corners: np.ndarray, spacing: float, *, most: int = 200):
    """A ``pyvista.PolyData`` of lines covering the rectangle ``corners`` (4, 3) (in order
    around it) about ``spacing`` m apart (at most ``most`` lines each way)."""
    corners = np.asarray(corners, dtype=float)
    origin, e1, e2 = corners[0], corners[1] - corners[0], corners[3] - corners[0]
    counts = [min(most, max(1, math.ceil(np.linalg.norm(e) / spacing))) for e in (e1, e2)]
    ends = []
    for count, along, across in ((counts[0], e1, e2), (counts[1], e2, e1)):
        for step in np.linspace(0.0, 1.0, count + 1):
            ends.append((origin + step * along, origin + step * along + across))
    points = np.array([point for pair in ends for point in pair])
    lines = np.hstack([[2, 2 * k, 2 * k + 1] for k in range(len(ends))])
    return pv.PolyData(points, lines=lines)


class LiveWindow:
    """The window of a :class:`~lbshape.live.session.LiveSession` (see the module
    docstring). Make it, then :meth:`run`.

    Args:
        session: the session to step and draw.
        seconds: close after this much wall time (s); ``None``: when the user closes it.
        screenshot: a PNG of the last frame.
        events: scripted events (:func:`lbshape.live.events.read_events`).
        window_size: (width, height) in pixels.
    """

    def __init__(self, session: LiveSession, *, seconds: float | None = None,
                 screenshot: str | Path | None = None, events=(),
                 window_size: tuple[int, int] = WINDOW_SIZE):
        import pyvista as pv

        # an on-screen window even after off-screen renders in the same process
        # (lbshape.report.render sets pyvista's global OFF_SCREEN for batch work, and
        # show() then returns without running the window's event loop)
        pv.OFF_SCREEN = False
        self.session, self.seconds = session, seconds
        self.screenshot_path = None if screenshot is None else Path(screenshot)
        self.events = list(events)
        self.frames, self.render_seconds = 0, 0.0
        self.error: Exception | None = None
        self._clock = time.perf_counter
        self._start = self._last = None
        self._drag_depth = None
        self.gl_renderer = ""
        self._followed = None  # the centre of mass the camera was last moved with
        self.window_size = tuple(int(v) for v in window_size)
        scene, mesh = session.scene, session.pre.mesh
        with quiet_vtk():
            self.plotter = plotter = pv.Plotter(off_screen=False, window_size=window_size,
                                                title=f"lbshape live {scene.name}")
        plotter.disable_anti_aliasing()  # multi-sampling triples a software frame's cost
        base = to_grid(mesh).extract_surface(algorithm="dataset_surface")
        self._ids = np.asarray(base.point_data["vtkOriginalPointIds"])
        self.surface = base.copy()
        self.surface.points = session.points()[self._ids]
        self.actor = plotter.add_mesh(self.surface, color="#c8d2e0", show_edges=True,
                                      edge_color="#333333", line_width=0.3)
        self._line = pv.PolyData(np.zeros((2, 3)), lines=np.array([2, 0, 1]))
        self._line_actor = plotter.add_mesh(self._line, color="#d62728", line_width=3,
                                            point_size=10, render_points_as_spheres=True,
                                            style="wireframe", pickable=False)
        self._line_actor.GetProperty().SetVertexVisibility(True)
        self._line_actor.GetProperty().SetVertexColor(0.84, 0.15, 0.16)
        self._line_actor.SetVisibility(False)
        rest = session.points()
        planes = scene_planes(scene)
        extent = np.vstack([rest, *(point[None] for point, _ in planes)])
        rectangles = plane_rectangles(planes, extent, margin=PLANE_REACH) if planes else []
        spacing = GRID_SPACING * float(np.linalg.norm(np.ptp(rest, axis=0)))
        for corners in rectangles:
            plotter.add_mesh(plane_grid(pv, corners, spacing), color=PLANE_COLOR,
                             lighting=False, line_width=1.0, pickable=False)
        self._status = plotter.add_text("", position="upper_left", font_size=10)
        help_text = "left mouse on the object: drag a vertex | " + " | ".join(
            f"{key}: {what}" for key, what in KEYS.items()) + " | q: quit"
        plotter.add_text(help_text, position="lower_left", font_size=8)
        set_camera(plotter, view_vector_of(mesh), bounds=bounds_of(extent), zoom=CAMERA_ZOOM)
        plotter.renderer.ResetCameraClippingRange()  # the planes reach far beyond the bounds
        for key, action in (("space", lambda: session.pause()), ("n", self._step_key),
                            ("x", lambda: session.set_examples()), ("z", self.reset)):
            plotter.add_key_event(key, self._guarded(action))

    # ----------------------------------------------------------- actions
    def _guarded(self, action):
        """``action`` for a VTK callback: an exception stops the loop instead of being
        printed and lost by VTK."""
        def call():
            if self.error is not None:
                return
            try:
                action()
            except Exception as exc:  # re-raised by run()
                self._stop(exc)
        return call

    def _step_key(self) -> None:
        if self.session.paused:
            self.session.step_once()

    def reset(self) -> None:
        """Back to rest; the drag is released."""
        self.session.reset()
        self._line_actor.SetVisibility(False)
        self._drag_depth = None

    def start_drag(self, vertex: int, target=None) -> None:
        """Grab ``vertex`` and pull it towards ``target`` (3,) (default: where it is)."""
        self.session.grab(vertex, target)
        self._show_drag()

    def move_drag(self, target) -> None:
        """Pull the grabbed vertex towards ``target`` (3,) world (m)."""
        self.session.move(target)
        self._show_drag()

    def release_drag(self) -> None:
        self.session.release()
        self._drag_depth = None
        self._line_actor.SetVisibility(False)

    def _show_drag(self) -> None:
        drag = self.session.drag
        if drag is None:
            return
        self._line.points = np.array([self.session.vertex_position(drag.vertex), drag.target])
        self._line_actor.SetVisibility(True)

    def apply(self, event: LiveEvent) -> None:
        """Do what a scripted event says, through the methods the mouse and keys use."""
        session = self.session
        if event.type == "drag":
            self.start_drag(event.vertex, np.array(event.to))
        elif event.type == "move":
            self.move_drag(np.array(event.to))
        elif event.type == "release":
            self.release_drag()
        elif event.type == "toggle-examples":
            session.set_examples()
        elif event.type == "pause":
            session.pause()
        elif event.type == "step":
            for _ in range(event.steps):
                session.step_once()
        elif event.type == "reset":
            self.reset()
        elif event.type == "screenshot":
            self._draw()
            self.save_screenshot(event.file)

    # ------------------------------------------------------------- mouse
    def _install_mouse(self) -> None:
        """Observers ahead of the camera style: a left press on the object starts a drag
        (and is not passed on), a move drags, the release lets go."""
        from vtkmodules.vtkRenderingCore import vtkCellPicker

        iren = self.plotter.iren.interactor
        self._picker = picker = vtkCellPicker()
        picker.SetTolerance(0.002)
        picker.PickFromListOn()
        picker.AddPickList(self.actor)
        tags = {}

        def swallow(event):
            iren.GetCommand(tags[event]).SetAbortFlag(1)

        def press(_obj, _event):
            x, y = iren.GetEventPosition()
            if not picker.Pick(x, y, 0, self.plotter.renderer):
                return
            point = int(picker.GetPointId())
            if point < 0:
                return
            self._guarded(lambda: self.start_drag(int(self._ids[point])))()
            self._drag_depth = self._display(self.session.drag.target)[2] \
                if self.session.drag is not None else None
            swallow("LeftButtonPressEvent")

        def move(_obj, _event):
            if self._drag_depth is None:
                return
            x, y = iren.GetEventPosition()
            target = self._world(x, y, self._drag_depth)
            self._guarded(lambda: self.move_drag(target))()
            swallow("MouseMoveEvent")

        def release(_obj, _event):
            if self._drag_depth is None:
                return
            self._guarded(self.release_drag)()
            swallow("LeftButtonReleaseEvent")

        for event, call in (("LeftButtonPressEvent", press), ("MouseMoveEvent", move),
                            ("LeftButtonReleaseEvent", release)):
            tags[event] = iren.AddObserver(event, call, 10.0)

    def _display(self, point) -> np.ndarray:
        """(3,) display coordinates (x, y pixels, depth) of a world point."""
        renderer = self.plotter.renderer
        renderer.SetWorldPoint(*np.asarray(point, dtype=float), 1.0)
        renderer.WorldToDisplay()
        return np.array(renderer.GetDisplayPoint())

    def _world(self, x: float, y: float, depth: float) -> np.ndarray:
        """(3,) the world point at display (x, y) and ``depth`` (the plane through the
        grabbed vertex facing the camera)."""
        renderer = self.plotter.renderer
        renderer.SetDisplayPoint(float(x), float(y), float(depth))
        renderer.DisplayToWorld()
        world = np.array(renderer.GetWorldPoint())
        return world[:3] / world[3]

    # -------------------------------------------------------------- loop
    def _draw(self) -> None:
        """Move the surface to the current state, update the texts and render."""
        session = self.session
        started = self._clock()
        self.surface.points = session.points()[self._ids]
        self._follow()
        self._show_drag()
        wall = (self._last - self._start) if self._start is not None else 0.0
        fps = self.frames / wall if wall > 0 else 0.0
        state = "examples on" if session.examples_on else (
            "examples off" if session.has_examples else "no examples")
        self._status.SetText(2, f"{session.scene.name}  t = {session.time:.3f} s\n"
                                f"step {session.mean_step_ms():.3f} ms   {fps:.1f} fps\n"
                                f"{state}{'   PAUSED' if session.paused else ''}")
        with quiet_vtk():
            self.plotter.render()
        self.render_seconds += self._clock() - started

    def _follow(self) -> None:
        """A free body: the camera moves with its centre of mass (turning and zooming stay
        the user's)."""
        center = self.session.center()
        if center is None:
            return
        if self._followed is not None:
            shift = center - self._followed
            camera = self.plotter.camera
            camera.focal_point = tuple(np.asarray(camera.focal_point) + shift)
            camera.position = tuple(np.asarray(camera.position) + shift)
            self.plotter.renderer.ResetCameraClippingRange()
        self._followed = np.array(center)

    def frame(self, *_args) -> None:
        """One frame: due events, the steps the elapsed wall time owes, the drawing; the
        end after ``seconds``."""
        if self.error is not None:
            return
        now = self._clock()
        if self._start is None:
            self._start = self._last = now
        elapsed, self._last = now - self._last, now
        try:
            while self.events and self.events[0].t <= now - self._start:
                self.apply(self.events.pop(0))
            self.session.advance(elapsed)
            self._draw()
            self.frames += 1
        except Exception as exc:  # SolverError and the rest: re-raised by run()
            self._stop(exc)
            return
        if self.seconds is not None and self._clock() - self._start >= self.seconds:
            self._stop(None)

    def _stop(self, error: Exception | None) -> None:
        self.error = error
        self._wall = (self._clock() - self._start) if self._start is not None else 0.0
        self.plotter.iren.interactor.TerminateApp()

    def save_screenshot(self, path: str | Path) -> Path:
        """The window's current image as a PNG (written atomically)."""
        with quiet_vtk():
            return write_atomic(Path(path), lambda tmp: self.plotter.screenshot(str(tmp)))

    def run(self) -> dict:
        """Open the window and loop until ``seconds`` have passed or the user closes it;
        returns the stats (:data:`STATS_KEYS`).

        Raises:
            SolverError: the simulation diverged (the engine's message, naming the step);
                the screenshot, if asked, shows the last good frame.
        """
        plotter = self.plotter
        self._wall = None
        with quiet_vtk():
            plotter.show(auto_close=False, interactive_update=True)
        self._install_mouse()
        self.gl_renderer = gl_renderer(plotter)
        iren = plotter.iren.interactor
        iren.AddObserver("TimerEvent", self.frame)
        timer = iren.CreateRepeatingTimer(TIMER_MS)
        try:
            iren.Start()
        finally:
            iren.DestroyTimer(timer)
        if self._wall is None:  # the user closed the window
            self._wall = self._clock() - self._start if self._start is not None else 0.0
        try:
            if self.screenshot_path is not None and plotter.ren_win is not None:
                self.save_screenshot(self.screenshot_path)
        finally:
            self.close()
        if isinstance(self.error, SolverError):
            raise SolverError(f"simulation stopped: {self.error}")
        if self.error is not None:
            raise self.error
        return self.stats()

    def close(self) -> None:
        """Close the window and its X connection (the interactor's callbacks hold this
        object: they are removed first, so nothing keeps the connection open)."""
        if self.plotter.iren is not None:
            self.plotter.iren.interactor.RemoveAllObservers()
        self.plotter.close()

    def stats(self) -> dict:
        """The run's numbers (:data:`STATS_KEYS`): frames and their rate, simulated and
        wall time, the mean step cost after the warm-up (``t_total_ms``), the mean drawing
        time of a frame (``render_ms``), the switches."""
        session, wall = self.session, float(self._wall or 0.0)
        values = {
            "frames": self.frames,
            "fps": self.frames / wall if wall > 0 else 0.0,
            "sim_time_s": session.steps * session.dt,
            "wall_time_s": wall,
            "t_total_ms": session.mean_step_ms(),
            "scene": session.scene.name,
            "steps": session.steps,
            "dt": session.dt,
            "realtime_ratio": session.steps * session.dt / wall if wall > 0 else 0.0,
            "render_ms": 1e3 * self.render_seconds / self.frames if self.frames else 0.0,
            "examples_on": session.examples_on,
            "drags": session.drags,
            "paused": session.paused,
            "n_vertices": int(session.pre.mesh.n_vertices),
            "r": int(session.pre.r),
            "threads": os.environ.get("OMP_NUM_THREADS", "unset"),
            "window": list(self.window_size),
            "gl_renderer": self.gl_renderer,
        }
        return {key: values[key] for key in STATS_KEYS}


def gl_renderer(plotter) -> str:
    """The OpenGL renderer of a shown plotter's window (e.g. ``llvmpipe …``: software)."""
    for line in plotter.ren_win.ReportCapabilities().splitlines():
        if line.lower().startswith("opengl renderer string:"):
            return line.split(":", 1)[1].strip()
    return "unknown"


def run_live(session: LiveSession, *, seconds: float | None = None,
             screenshot: str | Path | None = None, events=(),
             window_size: tuple[int, int] = WINDOW_SIZE) -> dict:
    """Open the live window of ``session`` (:class:`LiveWindow`) and return its stats.

    Raises:
        LbshapeError: no X display (run under ``xvfb-run -a`` on a headless machine) or a
            bad argument.
        SolverError: the simulation diverged.
    """
    if seconds is not None and not (math.isfinite(seconds) and seconds > 0):
        raise LbshapeError(f"--seconds must be > 0, got {seconds}")
    require_display()
    return LiveWindow(session, seconds=seconds, screenshot=screenshot, events=events,
                      window_size=window_size).run()
