"""``lbshape simulate SCENE [--method reduced|euclidean|full] [--steps N] [--out DIR] [--json]
[--no-influence]``.

A scene with examples is run a second time without them for the example influence
(its own progress bar says so); ``--no-influence`` skips that run and its stats keys.

Runs on one process: under ``mpirun`` with several ranks it refuses with one error
line (printed by rank 0) before reading the scene or writing anything.

``DIR`` is replaced as a whole once the run ends (an earlier run's files never stay
beside the new ones; a folder holding other files is refused before the run). A run
that stops on a solver failure exits with status 3 and leaves ``DIR`` holding only
``FAILED.txt`` (the message and the stats up to the stop): no result files.
"""

from __future__ import annotations

import sys
from pathlib import Path

from lbshape.cli._mpi import require_one_rank
from lbshape.cli._output import print_json
from lbshape.errors import LbshapeError
from lbshape.io.atomic import FAILED_MARKER, check_replaceable
from lbshape.io.paths import output_root
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import METHODS, RUN_FILES, simulate
from lbshape.scene import load_scene


def register(subparsers) -> None:
    parser = subparsers.add_parser("simulate", help="simulate a scene")
    parser.add_argument("scene", help="built-in scene name or path to a TOML file")
    parser.add_argument("--method", choices=METHODS, default="reduced")
    parser.add_argument("--steps", type=int, default=None, help="override the scene's steps")
    parser.add_argument("--out", type=Path, default=None,
                        help="output folder, replaced as a whole (default: "
                        "results/runs/SCENE-METHOD when run from the lbshape repository's "
                        "root, else ./lbshape-results/runs/SCENE-METHOD); a run that stops "
                        "(exit 3) leaves only FAILED.txt in it")
    parser.add_argument("--json", action="store_true", help="print stats as JSON")
    parser.add_argument("--no-influence", action="store_true",
                        help="skip the second run without examples (the example influence "
                        "keys are then absent)")
    parser.set_defaults(func=run)


def closest_text(closest) -> str:
    """``closest_example`` as text: ``rest``, ``example 1``, or per region
    ``left → example 1, right → rest``."""
    def one(value) -> str:
        return "rest" if value == "rest" else f"example {value}"
    if isinstance(closest, dict):
        return ", ".join(f"{region} → {one(value)}" for region, value in closest.items())
    return one(closest)


def run(args) -> int:
    require_one_rank("simulate")
    if args.steps is not None and args.steps < 1:
        raise LbshapeError(f"--steps must be >= 1, got {args.steps}")
    scene = load_scene(args.scene)
    out = args.out or output_root() / "runs" / f"{scene.name}-{args.method}"
    check_replaceable(out, RUN_FILES)  # before the precompute
    pre = precompute(scene, progress=not args.json)
    if pre.auto_stiffness is not None and not args.json:
        print(pre.auto_stiffness.summary())
    result = simulate(scene, pre, method=args.method, steps=args.steps, out=out,
                      influence=not args.no_influence, progress=not args.json)
    if args.json:
        print_json(result.stats)
    else:
        s = result.stats
        print(f"simulate {s['scene']} [{s['method']}]: {s['steps']} steps of {s['dt']} s, "
              f"t_interp {s['t_interp_ms']:.3f} ms, t_total {s['t_total_ms']:.3f} ms per step, "
              f"max displacement {s['max_displacement']:.4g} m -> "
              f"{out / FAILED_MARKER if result.message else out}")
        if "example_influence" in s:
            final, peak = (("undefined" if s[k] is None else f"{s[k]:.3f}")
                           for k in ("example_influence", "example_influence_max"))
            print(f"simulate {s['scene']}: example influence {final} (ratio of the maxima "
                  f"over time {peak}, {s['influence_frame']} frame) against the same scene "
                  "without examples")
        if s.get("visible_change") is not None:
            print(f"simulate {s['scene']}: visible change {100 * s['visible_change']:.1f} % "
                  f"of the bounding-box diagonal, closest: "
                  f"{closest_text(s['closest_example'])}")
    if result.message:
        print(f"error: simulation stopped: {result.message}", file=sys.stderr)
        return 3
    return 0
