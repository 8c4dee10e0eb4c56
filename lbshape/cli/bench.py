"""``lbshape bench [SCENE…] [--json] [--steps N] [--repeats K] [--out-dir DIR] [--sweep]``.

Runs ``full``, ``euclidean`` and ``reduced`` side by side in one process (default
scenes: bar-cuboid, bar-cylinder) and writes ``table2.md`` and ``table2.json``.
With ``--sweep`` it sweeps r, s and m of the reduced method per scene instead
(:mod:`lbshape.report.pareto`) and writes ``pareto.md``, ``pareto.json`` and
``pareto.png``.
"""

from __future__ import annotations

import sys
from pathlib import Path

from lbshape.cli._output import print_json
from lbshape.errors import LbshapeError
from lbshape.pipeline.simulate import WARMUP_STEPS
from lbshape.report import pareto
from lbshape.report.bench import DEFAULT_OUT, DEFAULT_SCENES, bench_scene
from lbshape.report.tables import write_table2
from lbshape.scene import load_scene


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "bench", help="the methods side by side: per-step times and error vs full (Table 2)")
    parser.add_argument("scenes", nargs="*", metavar="SCENE",
                        help="built-in scene names or TOML paths (default: bar-cuboid "
                             "bar-cylinder)")
    parser.add_argument("--json", action="store_true", help='print {"rows": [...]} as JSON')
    parser.add_argument("--steps", type=int, default=None,
                        help="steps per run (default: each scene's)")
    parser.add_argument("--repeats", type=int, default=3, help="runs per method (default 3)")
    parser.add_argument("--out-dir", type=Path, default=None,
                        help="folder of table2.md and table2.json (default: results)")
    parser.add_argument("--sweep", action="store_true",
                        help="instead: sweep r, s and m per scene (default: bar-cuboid "
                             "bar-cylinder demo) and write pareto.md/.json/.png")
    parser.set_defaults(func=run)


def run(args) -> int:
    if args.steps is not None and args.steps <= WARMUP_STEPS:
        raise LbshapeError(f"--steps must be > {WARMUP_STEPS} (the warm-up steps), "
                           f"got {args.steps}")
    if args.repeats < 1:
        raise LbshapeError(f"--repeats must be >= 1, got {args.repeats}")
    if args.sweep:
        return _sweep(args)
    scenes = [load_scene(name) for name in (args.scenes or DEFAULT_SCENES)]
    results = [bench_scene(scene, steps=args.steps, repeats=args.repeats,
                           progress=not args.json) for scene in scenes]
    md, js = write_table2(results, args.out_dir or DEFAULT_OUT)
    rows = [row for result in results for row in result.rows]
    if args.json:
        print_json({"rows": rows})
    else:
        for row in rows:
            error = row["error_vs_full"]
            print(f"bench {row['scene']} [{row['method']}]: t_interp {row['t_interp_ms']:.3f} ms, "
                  f"t_total {row['t_total_ms']:.3f} ms per step, error vs full "
                  f"{'—' if error is None else f'{error:.2%}'}")
        print(f"bench: {md} and {js}")
    failed = [f"{r.scene} {t.method}: {t.message}" for r in results for t in r.timings
              if not t.stable]
    if failed:
        print(f"error: simulation stopped: {'; '.join(failed)}", file=sys.stderr)
        return 3
    return 0


def _sweep(args) -> int:
    scenes = [load_scene(name) for name in (args.scenes or pareto.DEFAULT_SCENES)]
    sweeps = [pareto.sweep_scene(scene, steps=args.steps, repeats=args.repeats,
                                 progress=not args.json) for scene in scenes]
    paths = pareto.write_pareto(sweeps, args.out_dir or DEFAULT_OUT)
    if args.json:
        print_json(pareto.pareto_payload(sweeps, {}))
    else:
        for sweep in sweeps:
            front = pareto.pareto_front(sweep.points)
            print(f"bench --sweep {sweep.scene}: {len(sweep.points)} settings, "
                  f"{len(front)} on the Pareto front; {pareto.verdict(sweep)}")
        print(f"bench --sweep: {', '.join(str(p) for p in paths)}")
    return 0
