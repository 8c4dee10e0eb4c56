"""``lbshape tune SCENE --error E [--m LIST] [--r LIST] [--s LIST] [--steps N] [--repeats K]
[--out DIR]``: the cheapest (m, r, s) whose error against ``full`` is at most E.

Writes ``DIR/SCENE-tuned.toml`` (the scene with the chosen settings) beside
``DIR/SCENE-tune.md`` (every candidate tried). If no candidate meets E the table is
still written and the command fails with the smallest error found.
"""

from __future__ import annotations

from pathlib import Path

from lbshape.errors import LbshapeError
from lbshape.report.tune import DEFAULT_OUT, tune_scene, write_tune
from lbshape.scene import load_scene


def _int_list(text: str) -> tuple[int, ...]:
    try:
        values = tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise LbshapeError(f"expected comma-separated integers, got '{text}'") from None
    if not values:
        raise LbshapeError(f"expected comma-separated integers, got '{text}'")
    return values


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "tune", help="the cheapest (m, r, s) whose error vs full is at most E")
    parser.add_argument("scene", help="built-in scene name or path to a TOML file")
    parser.add_argument("--error", type=float, required=True, metavar="E",
                        help="largest trajectory error vs full, e.g. 0.05 for 5%%")
    for name in ("m", "r", "s"):
        parser.add_argument(f"--{name}", default=None, metavar="LIST",
                            help=f"candidate {name} values, comma-separated "
                                 "(default: fractions of the scene's)")
    parser.add_argument("--steps", type=int, default=None,
                        help="steps per run (default: the scene's)")
    parser.add_argument("--repeats", type=int, default=3,
                        help="reduced runs per candidate (default 3)")
    parser.add_argument("--out", type=Path, default=None,
                        help="output folder (default: results/tune)")
    parser.set_defaults(func=run)


def run(args) -> int:
    values = {name: _int_list(getattr(args, name)) if getattr(args, name) else None
              for name in ("m", "r", "s")}
    scene = load_scene(args.scene)
    result = tune_scene(scene, error=args.error, m_values=values["m"], r_values=values["r"],
                        s_values=values["s"], steps=args.steps, repeats=args.repeats,
                        progress=True)
    toml, table = write_tune(result, scene, args.out or DEFAULT_OUT)
    print(f"tune {scene.name}: {len(result.trials)} candidates, table {table}")
    if result.best is None:
        closest = result.closest
        best = ("no run finished" if closest is None else
                f"the best error was {closest.error_vs_full:.2%} at m={closest.m}, "
                f"r={closest.r}, s={closest.s_max}")
        raise LbshapeError(f"no (m, r, s) tried has error vs full <= {args.error:.3g}; {best}")
    b = result.best
    print(f"tune {scene.name}: m={b.m}, r={b.r}, s={b.s_max}: {b.t_total_ms:.3f} ms per step "
          f"(full {result.full_t_total_ms:.3f} ms), error vs full {b.error_vs_full:.2%} "
          f"<= {args.error:.3g}; scene file {toml}")
    return 0
