"""``lbshape simulate SCENE [--method reduced|euclidean|full] [--steps N] [--out DIR] [--json]
[--no-influence] [--compare full]``.

``--compare full`` runs the full-space reference once and prints one more line, the
speed-up and the error against it (the trajectory error Table 2 uses and the final
frame's); ``stats.json`` gains ``error_vs_full``, ``final_error_vs_full``,
``full_t_total_ms``, ``speed_up`` and ``compare_message`` (a reference that stops is
reported there, the run's own result is still written and the exit code is 0).

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

from lbshape.api import METHODS, RUN_FILES, load_scene, precompute, simulate
from lbshape.cli._mpi import require_one_rank
from lbshape.cli._output import print_json
from lbshape.errors import LbshapeError
from lbshape.io.atomic import FAILED_MARKER, check_replaceable
from lbshape.io.paths import output_root


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
    parser.add_argument("--compare", choices=("full",), default=None,
                        help="also run the full-space reference once and report the speed-up "
                        "and the error against it (one line; keys error_vs_full, "
                        "final_error_vs_full, full_t_total_ms, speed_up in stats.json)")
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
                      influence=not args.no_influence, progress=not args.json,
                      compare=args.compare)
    if args.json:
        print_json(result.stats)
    else:
        s = result.stats
        print(f"simulate {s['scene']} [{s['method']}]: {s['steps']} steps of {s['dt']} s, "
              f"t_interp {s['t_interp_ms']:.3f} ms, t_total {s['t_total_ms']:.3f} ms per step"
              f"{spread_phrase(s)}, max displacement {s['max_displacement']:.4g} m, "
              f"{estimate_phrase(s)} -> "
              f"{out / FAILED_MARKER if result.message else out}")
        if s.get("influence_message"):
            print(f"simulate {s['scene']}: example influence unavailable: "
                  f"{s['influence_message']}")
        elif "example_influence" in s:
            final, peak = (("undefined" if s[k] is None else f"{s[k]:.3f}")
                           for k in ("example_influence", "example_influence_max"))
            print(f"simulate {s['scene']}: example influence {final} (ratio of the maxima "
                  f"over time {peak}, {s['influence_frame']} frame) against the same scene "
                  "without examples")
        if s.get("visible_change") is not None:
            print(f"simulate {s['scene']}: visible change {100 * s['visible_change']:.1f} % "
                  f"of the bounding-box diagonal, closest: "
                  f"{closest_text(s['closest_example'])}")
        if args.compare is not None and not result.message:
            print(compare_line(s))
    if result.message:
        print(f"error: simulation stopped: {result.message}", file=sys.stderr)
        return 3
    return 0


def compare_line(stats: dict) -> str:
    """The one line of ``--compare full``: speed-up and error against the reference, or
    why the reference is unavailable."""
    head = f"simulate {stats['scene']} [{stats['method']}] vs full"
    if stats.get("error_vs_full") is None:
        return f"{head}: {stats.get('compare_message') or 'unavailable'}"
    final = stats["final_error_vs_full"]
    speed = "" if stats["speed_up"] is None else f"{stats['speed_up']:.1f}x faster "
    line = (f"{head}: {speed}(t_total {stats['t_total_ms']:.3f} vs "
            f"{stats['full_t_total_ms']:.3f} ms per step), error {stats['error_vs_full']:.2%} "
            f"over the trajectory, {'undefined' if final is None else f'{final:.2%}'} at the "
            "final frame")
    if "com_path_error" in stats:
        parts = [f"centre path {_percent(stats['com_path_error'])}",
                 f"rotation {stats['rotation_error_deg']:.3g} deg",
                 f"deformation {_percent(stats['body_deformation_error'])}"]
        line += f" ({', '.join(parts)})"
    return line


def _percent(value) -> str:
    return "undefined" if value is None else f"{value:.2%}"


def estimate_phrase(stats: dict) -> str:
    """The summary's words on the error estimate: ``error estimate 1.23%`` or why none."""
    value = stats.get("error_estimate")
    if value is not None:
        return f"error estimate {100 * value:.2f}%"
    return f"no error estimate ({stats.get('error_estimate_message') or 'not computed'})"


def spread_phrase(stats: dict) -> str:
    """The summary's words on the slow steps: `` (95th percentile 0.41, largest 1.20 ms;
    3 of 990 steps slower than dt)``, or nothing without timed steps."""
    if stats.get("t_max_ms") is None:
        return ""
    return (f" (95th percentile {stats['t_p95_ms']:.3f}, largest {stats['t_max_ms']:.3f} ms; "
            f"{stats['steps_over_dt']} of {stats['timed_steps']} steps slower than dt)")
