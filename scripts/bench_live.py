"""Frame rate and step cost of ``lbshape live`` while it renders, and a screenshot sequence
of a drag on the teddy's left leg; writes ``live.md``, ``live.json`` and ``live/*.png``.

Usage: ``.venv/bin/python scripts/bench_live.py [--seconds S] [--out-dir results]
[--before FILE.json ... --before-commit C]``.

Each scene runs in the live window (:func:`lbshape.interactive.window.run_live`) for S seconds of
wall time, paced to the clock, on the display set in ``DISPLAY`` or else a virtual X
server started for the run (:func:`lbshape.interactive.display.virtual_display`; OpenGL is then
Mesa's software renderer). ``teddy-global`` (the paper's Figure 6 object) is dragged by
its left leg's foot during the timed run (grab, two moves, release); ``demo`` and ``car``
(a free body thrown over a floor into a wall, the planes drawn) run untouched, and so does
``demo-3k``, the demo scene on a finer bar (about 3k vertices, :func:`demo_3k`). A second,
untimed teddy run takes the screenshots. Single-threaded numerics. ``--before``: the
``lbshape live SCENE --seconds 5 --json`` outputs of an earlier commit
(``--before-commit``), tabulated beside this run's.
"""

from __future__ import annotations

import os

if __name__ == "__main__":  # single-threaded BLAS for the timings, set before numpy loads
    for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import argparse
import json
import subprocess
import sys
import tomllib
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from lbshape.interactive.display import virtual_display
from lbshape.interactive.events import LiveEvent
from lbshape.interactive.session import LiveSession
from lbshape.interactive.window import run_live
from lbshape.io.atomic import write_json_atomic, write_text_atomic
from lbshape.io.machine import load_text, machine_description, machine_text
from lbshape.io.paths import REPOSITORY, RESULTS_DIR
from lbshape.pipeline.precompute import precompute
from lbshape.scene import load_scene
from lbshape.scene.reader import scene_from_dict

#: the scenes timed; the first is dragged
SCENES = ("teddy-global", "demo", "demo-3k", "car")
#: the mesh size (m) of :func:`demo_3k`'s bar: 3038 vertices
FINE_SIZE = 0.025
#: wall times (s) of the screenshots of the drag sequence, and of its drag events
SHOT_TIMES = (0.5, 1.5, 2.5, 3.5, 4.5, 6.0)
#: the foot is pulled up and forward by these offsets (m), at these wall times (s)
DRAG_PATH = ((1.0, (0.0, -0.05, 0.15)), (2.0, (0.0, -0.10, 0.30)), (3.0, (0.0, -0.10, 0.40)))
RELEASE_AT = 4.0


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0,
                        help="wall time of each timed run (s)")
    parser.add_argument("--out-dir", type=Path, default=RESULTS_DIR)
    parser.add_argument("--before", type=Path, nargs="*", default=[],
                        help="stats (--json) of `lbshape live` runs on an earlier commit")
    parser.add_argument("--before-commit", default="",
                        help="the commit of the --before runs")
    return parser.parse_args(argv)


def demo_3k():
    """The demo scene (``demo.toml``) on its bar meshed at :data:`FINE_SIZE` (about 3k
    vertices): a larger object for the window's frame rate."""
    path = REPOSITORY / "lbshape" / "scene" / "builtin" / "demo.toml"
    data = tomllib.loads(path.read_text())
    data["name"] = "demo-3k"
    data["description"] = ("The demo scene on a finer bar (about 3k vertices): the live "
                           "window's frame-rate check.")
    data["object"] = {**data["object"], "size": FINE_SIZE}
    return scene_from_dict(data, name="demo-3k")


def scene_named(name: str):
    return demo_3k() if name == "demo-3k" else load_scene(name)


def foot_vertex(pre) -> int:
    """The teddy's left-leg vertex farthest from its fixed back (the foot's tip)."""
    points = pre.mesh.points
    leg = np.asarray(pre.mesh.vertex_groups["left_leg"])
    back = points[np.asarray(pre.mesh.vertex_groups["back"])].mean(axis=0)
    return int(leg[np.argmax(np.linalg.norm(points[leg] - back, axis=1))])


def drag_events(pre, *, start: float = 0.0) -> list[LiveEvent]:
    """Grab the foot and pull it along :data:`DRAG_PATH`, release at :data:`RELEASE_AT`."""
    vertex = foot_vertex(pre)
    rest = pre.mesh.points[vertex]
    events = []
    for index, (t, offset) in enumerate(DRAG_PATH):
        to = tuple(float(v) for v in rest + np.array(offset))
        events.append(LiveEvent(start + t, "drag" if index == 0 else "move",
                                vertex=vertex if index == 0 else None, to=to))
    events.append(LiveEvent(start + RELEASE_AT, "release"))
    return events


def timed_run(name: str, seconds: float) -> dict:
    scene = scene_named(name)
    pre = precompute(scene)
    events = drag_events(pre) if name == "teddy-global" else []
    stats = run_live(LiveSession(scene, pre), seconds=seconds, events=events)
    stats["dragged"] = bool(events)
    return stats


def screenshot_run(out_dir: Path) -> list[Path]:
    scene = load_scene("teddy-global")
    pre = precompute(scene)
    folder = out_dir / "live"
    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / f"teddy_drag_{index}.png" for index in range(len(SHOT_TIMES))]
    shots = [LiveEvent(t, "screenshot", file=str(path))
             for t, path in zip(SHOT_TIMES, paths, strict=True)]
    events = sorted(drag_events(pre) + shots, key=lambda event: event.t)
    run_live(LiveSession(scene, pre), seconds=SHOT_TIMES[-1] + 0.2, events=events)
    return paths


def commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPOSITORY,
                              capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def read_before(paths: list[Path]) -> list[dict]:
    """The ``--json`` stats of ``lbshape live`` runs given with ``--before``."""
    return [json.loads(Path(path).read_text()) for path in paths]


def _table(rows: list[dict]) -> list[str]:
    lines = ["| scene | vertices | r | frames | fps | step (ms, mean) | drawing (ms / frame) "
             "| points / text / render (ms) | CPU (ms / frame) | steps per frame "
             "| simulated / wall time "
             "| frames behind |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        lines.append(
            f"| {row['scene']}{' (dragged)' if row.get('dragged') else ''} "
            f"| {row['n_vertices']} | {row['r']} | {row['frames']} | {row['fps']:.1f} "
            f"| {row['t_total_ms']:.3f} | {row['render_ms']:.1f} "
            f"| {row['points_ms']:.2f} / {row['text_ms']:.2f} / {row['gl_ms']:.1f} "
            f"| {row['cpu_ms']:.1f} | {row['steps_per_frame']:.0f} "
            f"| {row['realtime_ratio']:.2f} "
            f"| {row['behind_frames']} |")
    return lines


def _before_table(rows: list[dict], commit_label: str) -> list[str]:
    lines = [f"Before (code at commit {commit_label or 'unstated'}: the status text a corner "
             "annotation refitted at every frame, the surface's points array replaced each "
             "frame, at most 0.1 s of simulated time per frame), `lbshape live SCENE "
             "--seconds 5 --json`:", "",
             "| scene | vertices | window | frames | fps | step (ms, mean) "
             "| drawing (ms / frame) | simulated / wall time |",
             "|---|---|---|---|---|---|---|---|"]
    for row in rows:
        lines.append(f"| {row['scene']} | {row['n_vertices']} | {row['window'][0]}x"
                     f"{row['window'][1]} | {row['frames']} | {row['fps']:.1f} "
                     f"| {row['t_total_ms']:.3f} | {row['render_ms']:.1f} "
                     f"| {row['realtime_ratio']:.2f} |")
    return lines


def markdown(rows: list[dict], shots: list[Path], machine: dict, args, out_dir: Path,
             *, before: list[dict], end_load: str, date: str) -> str:
    command = "OMP_NUM_THREADS=1 python scripts/bench_live.py" + (
        f" --seconds {args.seconds:g}" if args.seconds != 10.0 else "")
    first = rows[0]
    lines = [
        "# lbshape live: frame rate and step cost while rendering",
        "",
        f"Made by `{command}` (code at commit {commit()}) on {date}, "
        f"{machine_text(machine)}; load average at the start {load_text(machine)}, at the "
        f"end {end_load} (the 2 cores were shared with other jobs: a frame's wall time is "
        "several times its CPU time here). Display: "
        f"{'the one in DISPLAY' if os.environ.get('DISPLAY') else 'a virtual X server (Xvfb)'}"
        f"; OpenGL renderer `{first['gl_renderer']}` (software), window "
        f"{first['window'][0]}x{first['window'][1]} px, multi-sampling off. Each scene "
        f"runs {args.seconds:g} s of wall time paced to the clock: every frame steps the "
        "simulated time the elapsed wall time owes (a slow frame is made up by more steps, "
        "never dropped), within 0.1 s of stepping per frame; teddy-global's left foot is "
        "dragged (grab at 1 s, moves at 2 s and 3 s, release at 4 s; examples on); "
        f"demo-3k is the demo scene on a bar meshed at {FINE_SIZE} m.",
        "",
        *_table(rows),
        "",
        "The step cost is the mean wall time of a reduced step (after 10 warm-up steps) "
        "measured inside the live loop; the drawing time is the rest of a frame, split into "
        "moving the surface's points (written in place into the drawn VTK array), the "
        "corner text (a fixed-size text actor, touched only when its text changes, its "
        "numbers refreshed every 0.25 s) and the render itself, which is nearly all of it "
        "and grows with the window's pixels (a software renderer). The CPU time per frame "
        "is this process's (steps and drawing, every thread, the X server's excluded): "
        "with the cores to itself a frame would take about that long. Simulated / wall time "
        "is 1 while the steps keep up: a renderer slower than the steps draws fewer "
        "frames, each covering more steps, and the corner says \"drawing every k-th step\" "
        "below 30 fps; \"simulation behind the clock\" only when the steps themselves "
        "cannot keep up (frames behind > 0).",
        "",
    ]
    if before:
        lines += [*_before_table(before, args.before_commit), ""]
    lines += [
        "Screenshot sequence of the drag (teddy-global, a separate untimed run; the red line "
        "joins the foot to the cursor point it is pulled towards), at "
        + ", ".join(f"{t:g} s" for t in SHOT_TIMES) + " of wall time:",
        "",
    ]
    lines += [f"![{path.stem}]({path.relative_to(out_dir).as_posix()})" for path in shots]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> tuple[Path, Path]:
    args = parse_args(argv)
    machine = machine_description()
    date = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    before = read_before(args.before)
    with virtual_display():
        rows = [timed_run(name, args.seconds) for name in SCENES]
        shots = screenshot_run(args.out_dir)
    end_load = load_text(machine_description())
    payload = {"command": "OMP_NUM_THREADS=1 python scripts/bench_live.py",
               "commit": commit(), "date": date, "machine": machine,
               "load_average_end": end_load, "seconds": args.seconds, "runs": rows,
               "before": {"commit": args.before_commit, "runs": before},
               "screenshots": [str(p.relative_to(args.out_dir)) for p in shots]}
    json_path = write_json_atomic(args.out_dir / "live.json", payload)
    md_path = write_text_atomic(args.out_dir / "live.md",
                                markdown(rows, shots, machine, args, args.out_dir,
                                         before=before, end_load=end_load, date=date))
    return md_path, json_path


if __name__ == "__main__":
    for written in main(sys.argv[1:]):
        print(written)
