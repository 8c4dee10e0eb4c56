"""``lbshape demo``: the default job end to end on the built-in demo scene."""

from __future__ import annotations

from pathlib import Path


def register(subparsers) -> None:
    parser = subparsers.add_parser("demo", help="run the default job on the demo scene")
    parser.add_argument("--out", type=Path, default=None, help="output folder (results/demo)")
    parser.set_defaults(func=run)


def run(args) -> int:
    from lbshape.demo import run_demo

    summary = run_demo(args.out)
    print(f"demo: wrote {summary.parent}")
    return 0
