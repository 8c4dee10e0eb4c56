"""``lbshape render SCENE [--out DIR] [--steps N] [--method M]``: off-screen PNGs of a scene."""

from __future__ import annotations

import sys
from pathlib import Path

from lbshape.errors import LbshapeError
from lbshape.pipeline.simulate import METHODS
from lbshape.report.figures import DEFAULT_OUT, FIGURE3_SCENES, FIGURE3_STEPS, figure3, render_scene
from lbshape.scene import load_scene


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "render", help="off-screen PNGs: simulation, examples, eigenfunctions (and Figure 3)")
    parser.add_argument("scene", help="built-in scene name or path to a TOML file")
    parser.add_argument("--out", type=Path, default=None,
                        help="output folder (default: results/figures/SCENE)")
    parser.add_argument("--steps", type=int, default=None,
                        help="steps of the runs (default: the scene's; Figure 3: "
                             "at most 400)")
    parser.add_argument("--method", choices=METHODS, default="reduced",
                        help="method of the simulation frames (default: reduced)")
    parser.set_defaults(func=run)


def run(args) -> int:
    if args.steps is not None and args.steps < 1:
        raise LbshapeError(f"--steps must be >= 1, got {args.steps}")
    scene = load_scene(args.scene)
    out = args.out or DEFAULT_OUT / scene.name
    created = not out.exists()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise LbshapeError(f"cannot create output folder {out}: {exc.strerror}") from None
    try:
        rendered = render_scene(scene, out, steps=args.steps, method=args.method, progress=True)
        for path in rendered.paths:
            print(f"render {scene.name}: {path}")
        if scene.name in FIGURE3_SCENES:
            same, other = (load_scene(name) for name in FIGURE3_SCENES)
            steps = args.steps or min(FIGURE3_STEPS, same.simulation.steps)
            result = figure3(same, other, out / "figure3.png", steps=steps, progress=True)
            print(f"render {scene.name}: {result.path} (reduced vs full final frame: "
                  f"{result.reduced_vs_full_final:.2%})")
    except LbshapeError:
        if created and out.is_dir() and not any(out.iterdir()):
            out.rmdir()  # leave nothing behind on bad input
        raise
    if rendered.message:
        print(f"error: simulation stopped: {rendered.message}", file=sys.stderr)
        return 3
    return 0
