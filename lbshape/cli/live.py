"""``lbshape live SCENE [--seconds S] [--screenshot FILE.png] [--json] [--events FILE.json]
[--drag-stiffness K]``.

An on-screen window stepping the scene's reduced simulation paced to the wall clock
(:mod:`lbshape.live.window`): drag a vertex with the left mouse button, ``space`` pause,
``n`` one step, ``x`` examples on/off, ``z`` reset, ``q`` quit. The precompute comes from
the shared cache (its progress is shown first when the scene is not cached).

Scripted: ``--seconds S`` closes the window after S seconds of wall time,
``--screenshot`` saves its last frame, ``--events`` feeds timed user actions through the
same code as the mouse and keys, ``--json`` prints one JSON object (``frames``, ``fps``,
``sim_time_s``, ``wall_time_s``, ``t_total_ms``, …). Needs an X display (on a headless
machine: ``xvfb-run -a lbshape live …``). A simulation that diverges stops the window
and exits with status 3 and the engine's one-line message naming the step.
"""

from __future__ import annotations

import sys
from pathlib import Path

from lbshape.cli._mpi import require_one_rank
from lbshape.cli._output import print_json
from lbshape.errors import LbshapeError
from lbshape.live.display import require_display
from lbshape.live.events import read_events
from lbshape.live.session import LiveSession
from lbshape.live.window import run_live
from lbshape.pipeline.precompute import precompute
from lbshape.scene import load_scene


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "live", help="on-screen window stepping the reduced simulation in real time")
    parser.add_argument("scene", help="built-in scene name or path to a TOML file")
    parser.add_argument("--seconds", type=float, default=None,
                        help="close after S seconds of wall time (default: when closed)")
    parser.add_argument("--screenshot", type=Path, default=None,
                        help="write the last frame to this PNG")
    parser.add_argument("--json", action="store_true",
                        help="print the run's stats as one JSON object")
    parser.add_argument("--events", type=Path, default=None,
                        help="scripted events: a JSON list of {\"t\": s, \"type\": drag|move|"
                        "release|toggle-examples|pause|step|reset|screenshot, \"vertex\": i, "
                        "\"to\": [x, y, z], \"file\": PNG, \"steps\": k}")
    parser.add_argument("--drag-stiffness", type=float, default=None,
                        help="the drag spring's stiffness in N/m (default: 2000 N/m per kg "
                        "of the object)")
    parser.set_defaults(func=run)


def run(args) -> int:
    require_one_rank("live")
    if args.seconds is not None and not args.seconds > 0:
        raise LbshapeError(f"--seconds must be > 0, got {args.seconds}")
    if args.screenshot is not None and args.screenshot.suffix.lower() != ".png":
        raise LbshapeError(f"--screenshot must name a .png file, got {args.screenshot}")
    require_display()  # before the precompute
    events = read_events(args.events) if args.events is not None else []
    scene = load_scene(args.scene)
    pre = precompute(scene, progress=True)
    session = LiveSession(scene, pre, drag_stiffness=args.drag_stiffness)
    stats = run_live(session, seconds=args.seconds, screenshot=args.screenshot, events=events)
    if args.json:
        print_json(stats)
    else:
        print(f"live {stats['scene']}: {stats['frames']} frames in {stats['wall_time_s']:.2f} s "
              f"({stats['fps']:.1f} fps), {stats['sim_time_s']:.3f} s simulated, step "
              f"{stats['t_total_ms']:.3f} ms, drawing {stats['render_ms']:.1f} ms per frame")
    if args.screenshot is not None:
        print(f"live {stats['scene']}: {args.screenshot}",
              file=sys.stderr if args.json else sys.stdout)
    return 0
