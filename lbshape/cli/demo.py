"""``lbshape demo``: the default job end to end on the built-in demo scene."""

from __future__ import annotations

from pathlib import Path

from lbshape.studies.demo import run_demo


def register(subparsers) -> None:
    parser = subparsers.add_parser("demo", help="run the default job on the demo scene")
    parser.add_argument("--out", type=Path, default=None,
                        help="output folder (default: results/demo when run from the lbshape "
                             "repository's root, else ./lbshape-results/demo)")
    parser.set_defaults(func=run)


def run(args) -> int:
    import json

    path = run_demo(args.out)
    summary = json.loads(path.read_text())["simulation"]
    reduced = summary["reduced"]
    print(f"demo: {reduced['n_vertices']} vertices, m={reduced['m']} r={reduced['r']} "
          f"s={reduced['s']}, {reduced['steps']} steps of {reduced['dt']} s")
    print(f"demo: {summary['headline']}")
    print(f"demo: pictures and summary in {path.parent}")
    return 0
