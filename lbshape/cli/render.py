"""``lbshape render SCENE [--out DIR] [--steps N] [--method M] [--movie [--fps F]]``.

Off-screen PNGs of a scene (the bars add Figure 3, teddy-local Figure 6: its run beside
teddy-global's); ``--movie`` adds ``simulation.gif`` (and ``simulation.mp4``
where the encoder is installed): the method and the ``full`` reference side by side,
frames read from the trajectories written to ``OUT/runs/METHOD``.
"""

from __future__ import annotations

import sys
from pathlib import Path

from lbshape.errors import LbshapeError
from lbshape.pipeline.simulate import METHODS
from lbshape.scene import load_scene
from lbshape.studies.animation import simulation_movie
from lbshape.studies.figures import (
    FIGURE3_SCENES,
    FIGURE3_STEPS,
    FIGURE6_SCENES,
    default_out,
    figure3,
    figure6,
    render_scene,
)


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "render", help="off-screen PNGs: simulation, examples, eigenfunctions (and Figure 3)")
    parser.add_argument("scene", help="built-in scene name or path to a TOML file")
    parser.add_argument("--out", type=Path, default=None,
                        help="output folder (default: results/figures/SCENE when run "
                             "from the lbshape repository's root, else "
                             "./lbshape-results/figures/SCENE)")
    parser.add_argument("--steps", type=int, default=None,
                        help="steps of the runs (default: the scene's; Figure 3: "
                             "at most 400)")
    parser.add_argument("--method", choices=METHODS, default="reduced",
                        help="method of the simulation frames (default: reduced)")
    parser.add_argument("--movie", action="store_true",
                        help="also a GIF (and MP4) of the run beside the full reference")
    parser.add_argument("--fps", type=float, default=20.0,
                        help="frames per second of the movie (default 20)")
    parser.set_defaults(func=run)


def run(args) -> int:
    if args.steps is not None and args.steps < 1:
        raise LbshapeError(f"--steps must be >= 1, got {args.steps}")
    if not args.fps > 0:
        raise LbshapeError(f"--fps must be > 0, got {args.fps}")
    scene = load_scene(args.scene)
    out = args.out or default_out(scene.name)
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
        if scene.name == FIGURE6_SCENES[1]:
            figure = figure6(*(load_scene(name) for name in FIGURE6_SCENES),
                             out / "figure6.png", steps=args.steps, progress=True)
            print(f"render {scene.name}: {figure.path} and {figure.difference} (local vs "
                  f"global: up to {figure.difference_max:.3f} m = "
                  f"{figure.difference_max / figure.height:.1%} of the height; in the "
                  f"regions up to {max(figure.difference_by_region.values()):.1%})")
        if args.movie:
            movie = simulation_movie(scene, out, method=args.method, steps=args.steps,
                                     fps=args.fps, progress=True)
            for file in movie.movies:
                print(f"render {scene.name}: {file.path} ({file.frames} frames, "
                      f"{file.size[1]}x{file.size[0]} px, {' | '.join(movie.methods)})")
    except LbshapeError:
        if created and out.is_dir() and not any(out.iterdir()):
            out.rmdir()  # leave nothing behind on bad input
        raise
    message = "; ".join(filter(None, [rendered.message, movie.message if args.movie else ""]))
    if message:
        print(f"error: simulation stopped: {message}", file=sys.stderr)
        return 3
    return 0
