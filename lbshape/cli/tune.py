"""``lbshape tune SCENE --error E [--budget-ms B] [--m LIST] [--r LIST] [--s LIST]
[--forces LIST] [--steps N] [--repeats K] [--out DIR]``: the cheapest (m, r, s, forces)
whose error against ``full`` is at most E and whose reduced step takes at most B ms
(default 1 ms).

Writes ``DIR/SCENE-tuned.toml`` (the scene with the chosen settings) beside
``DIR/SCENE-tune.md`` (every candidate tried). If no candidate meets E within the
budget the table is still written (without a scene file) and the command fails with
one line on stderr, ``error: no candidate meets error ≤ E within B ms per step;
closest: …``, and exit code 2 (as every user-facing error,
:class:`~lbshape.errors.LbshapeError`).
"""

from __future__ import annotations

import math
from pathlib import Path

from lbshape.errors import LbshapeError
from lbshape.scene import load_scene
from lbshape.studies.tune import (
    DEFAULT_BUDGET_MS,
    default_out,
    tune_scene,
    verdict_line,
    write_tune,
)


def _int_list(text: str) -> tuple[int, ...]:
    try:
        values = tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise LbshapeError(f"expected comma-separated integers, got '{text}'") from None
    if not values:
        raise LbshapeError(f"expected comma-separated integers, got '{text}'")
    return values


def _name_list(text: str) -> tuple[str, ...]:
    values = tuple(v.strip() for v in text.split(",") if v.strip())
    if not values:
        raise LbshapeError(f"expected comma-separated force models, got '{text}'")
    return values


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "tune", help="the cheapest (m, r, s, forces) whose error vs full is at most E "
                     "within a per-step time budget")
    parser.add_argument("scene", help="built-in scene name or path to a TOML file")
    parser.add_argument("--error", type=float, required=True, metavar="E",
                        help="largest trajectory error vs full, e.g. 0.05 for 5%%")
    parser.add_argument("--budget-ms", type=float, default=DEFAULT_BUDGET_MS, metavar="B",
                        help="largest reduced per-step time of the winner in ms "
                             f"(default {DEFAULT_BUDGET_MS:g})")
    for name in ("m", "r", "s"):
        parser.add_argument(f"--{name}", default=None, metavar="LIST",
                            help=f"candidate {name} values, comma-separated "
                                 "(default: fractions of the scene's)")
    parser.add_argument("--forces", default=None, metavar="LIST",
                        help="force models searched, comma-separated: polynomial, cubature "
                             "(default: both for StVK, else cubature)")
    parser.add_argument("--steps", type=int, default=None,
                        help="steps per run (default: the scene's)")
    parser.add_argument("--repeats", type=int, default=3,
                        help="reduced runs per candidate (default 3)")
    parser.add_argument("--out", type=Path, default=None,
                        help="output folder (default: results/tune when run from the "
                             "lbshape repository's root, else ./lbshape-results/tune)")
    parser.set_defaults(func=run)


def run(args) -> int:
    if not (math.isfinite(args.budget_ms) and args.budget_ms > 0):
        raise LbshapeError(f"--budget-ms must be a number of ms > 0, got {args.budget_ms:g}")
    values = {name: _int_list(getattr(args, name)) if getattr(args, name) else None
              for name in ("m", "r", "s")}
    forces = _name_list(args.forces) if args.forces is not None else None
    scene = load_scene(args.scene)
    result = tune_scene(scene, error=args.error, budget_ms=args.budget_ms,
                        m_values=values["m"], r_values=values["r"], s_values=values["s"],
                        forces=forces, steps=args.steps, repeats=args.repeats, progress=True)
    toml, table = write_tune(result, scene, args.out or default_out())
    print(f"tune {scene.name}: {len(result.trials)} candidates, table {table}")
    if result.best is None:
        raise LbshapeError(verdict_line(result))
    print(f"tune {scene.name}: {verdict_line(result)}; full {result.full_t_total_ms:.3f} ms "
          f"per step; scene file {toml}")
    return 0
