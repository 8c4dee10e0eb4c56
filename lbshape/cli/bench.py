"""``lbshape bench [SCENE…] [--json] [--steps N] [--repeats K] [--out-dir DIR] [-j N]
[--no-paper-settings] [--free-eval] [--sweep] [--scaling [--sizes H…] [--ranks N]]
[--free-bodies]``.

Runs ``full``, ``euclidean`` and ``reduced`` side by side in one process per scene
(default scenes: bar-cuboid, bar-cylinder; names, TOML paths or globs) and writes
``table2.md`` and ``table2.json``. The reduced method also runs at the paper's
setting (its Table 2 m, r, s with cubature forces,
:func:`lbshape.studies.bench.paper_setting`) beside the scene as written, each with its
error with and without the examples; ``--no-paper-settings`` leaves that out. Several
scenes run in ``-j`` worker processes and end with a summary table (on stderr with
``--json``); a failed scene is listed and does not stop the others (exit code non-zero
at the end).
With ``--sweep`` it sweeps r, s and m of the reduced method per scene instead
(:mod:`lbshape.studies.pareto`) and writes ``pareto.md``, ``pareto.json`` and
``pareto.png``.
With ``--scaling`` it measures the cost growth with mesh size instead
(:mod:`lbshape.studies.scaling`): one built-in scene (default bar-cylinder) at several
object sizes, each precomputed from scratch in a fresh process (``--ranks N``: under
``mpirun -n N``), then the reduced per-step time of all sizes interleaved; writes
``scaling.csv``, ``scaling.md`` and ``scaling.png``.
With ``--free-eval`` a free body's Table 2 rows gain the field's evaluation
(:data:`lbshape.studies.free_bodies.KEYS`: the error before the first contact, the rest
pose's symmetric surface distance, the reference's noise floor and the error over it).
With ``--free-bodies`` it evaluates the free bodies instead (default car, bar-s-cuboid,
bar-s-cylinder; :mod:`lbshape.studies.free_bodies`: those keys with and without
examples, and the designed impacts of the bar from a synchronised pre-impact state) and
writes ``free_bodies.md`` and ``free_bodies.json`` (errors only, no timings).
"""

from __future__ import annotations

import functools
import sys
from pathlib import Path

import numpy as np

from lbshape.api import (
    WARMUP_STEPS,
    expand_scenes,
    load_scene,
    precompute,
    run_jobs,
    summary_table,
)
from lbshape.cli._output import print_json
from lbshape.errors import LbshapeError
from lbshape.studies import free_bodies, pareto, scaling
from lbshape.studies.bench import DEFAULT_OUT, DEFAULT_SCENES, bench_scene, paper_setting
from lbshape.studies.realtime import PAPER_TABLE2
from lbshape.studies.tables import settings_payload, write_table2


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "bench", help="the methods side by side: per-step times and error vs full (Table 2)")
    parser.add_argument("scenes", nargs="*", metavar="SCENE",
                        help="built-in scene names, TOML paths or globs (default: bar-cuboid "
                             "bar-cylinder)")
    parser.add_argument("--json", action="store_true", help='print {"rows": [...]} as JSON')
    parser.add_argument("--steps", type=int, default=None,
                        help="steps per run (default: each scene's)")
    parser.add_argument("--repeats", type=int, default=3, help="runs per method (default 3)")
    parser.add_argument("--out-dir", type=Path, default=None,
                        help="folder of table2.md and table2.json (default: results)")
    parser.add_argument("-j", "--jobs", type=int, default=1,
                        help="worker processes for several scenes (default 1; concurrent "
                             "jobs share the machine's cores, which their timings include)")
    parser.add_argument("--no-paper-settings", dest="paper_settings", action="store_false",
                        help="leave out the reduced method at the paper's m, r, s with "
                             "cubature forces (run by default beside the scene as written, "
                             "with its own precompute)")
    parser.add_argument("--free-eval", action="store_true",
                        help="free bodies: add the error before first contact, the rest "
                             "pose's surface distance, the reference's noise floor and the "
                             "error over it to Table 2 (re-runs full 5 times per scene)")
    parser.add_argument("--free-bodies", action="store_true",
                        help="instead: evaluate the free bodies (default car bar-s-cuboid "
                             "bar-s-cylinder) before contact, per designed impact, at rest "
                             "and against the reference's noise floor; write "
                             "free_bodies.md/.json")
    parser.add_argument("--sweep", action="store_true",
                        help="instead: sweep r, s and m per scene (default: bar-cuboid "
                             "bar-cylinder demo) and write pareto.md/.json/.png")
    parser.add_argument("--scaling", action="store_true",
                        help="instead: precompute and per-step cost against mesh size of one "
                             "built-in scene (default bar-cylinder) at several object sizes; "
                             "write scaling.csv/.md/.png")
    parser.add_argument("--sizes", type=float, nargs="+", default=None, metavar="H",
                        help="object sizes h in m for --scaling (default: "
                             f"{' '.join(f'{h:g}' for h in scaling.DEFAULT_SIZES)})")
    parser.add_argument("--ranks", type=int, default=1,
                        help="MPI processes of each --scaling precompute (default 1: serial; "
                             "N > 1 runs it under mpirun -n N)")
    parser.set_defaults(func=run)


def run(args) -> int:
    if args.steps is not None and args.steps <= WARMUP_STEPS:
        raise LbshapeError(f"--steps must be > {WARMUP_STEPS} (the warm-up steps), "
                           f"got {args.steps}")
    if args.repeats < 1:
        raise LbshapeError(f"--repeats must be >= 1, got {args.repeats}")
    if args.jobs < 1:
        raise LbshapeError(f"-j/--jobs must be >= 1, got {args.jobs}")
    if sum((args.sweep, args.scaling, args.free_bodies)) > 1:
        raise LbshapeError("--sweep, --scaling and --free-bodies are different benchmarks: "
                           "give one")
    if args.free_eval and (args.sweep or args.scaling or args.free_bodies):
        raise LbshapeError("--free-eval belongs to the Table 2 benchmark")
    if (args.sizes is not None or args.ranks != 1) and not args.scaling:
        raise LbshapeError("--sizes and --ranks belong to --scaling")
    if not args.paper_settings and (args.sweep or args.scaling):
        raise LbshapeError("--no-paper-settings belongs to the Table 2 benchmark, not to "
                           "--sweep or --scaling")
    if args.free_bodies:
        return _free_bodies(args)
    if args.sweep:
        return _sweep(args)
    if args.scaling:
        return _scaling(args)
    names, unmatched = expand_scenes(args.scenes or DEFAULT_SCENES)
    if len(names) == 1 and not unmatched:  # one scene: errors as a one-line error
        jobs = []
        results = [bench_one(names[0], steps=args.steps, repeats=args.repeats,
                             paper_settings=args.paper_settings, progress=not args.json,
                             free_eval=args.free_eval)]
    else:
        jobs = unmatched + run_jobs(
            functools.partial(bench_one, steps=args.steps, repeats=args.repeats,
                              paper_settings=args.paper_settings, free_eval=args.free_eval),
            names, jobs=args.jobs, progress=not args.json, desc="bench")
        results = [job.value for job in jobs if job.ok]
    if not results:
        _print_summary(jobs, file=sys.stderr)
        raise LbshapeError(f"no scene could be benchmarked ({len(jobs)} failed)")
    md, js = write_table2(results, args.out_dir or DEFAULT_OUT)
    rows = [row for result in results for row in result.rows]
    if args.json:
        payload = {"rows": rows}
        if args.paper_settings:
            payload["paper_vs_lbshape"] = settings_payload(results)
        print_json(payload)
    else:
        for row in rows:
            error = row["error_vs_full"]
            print(f"bench {row['scene']} [{row['method']}]: t_interp {row['t_interp_ms']:.3f} ms, "
                  f"t_total {row['t_total_ms']:.3f} ms per step, error vs full "
                  f"{'—' if error is None else f'{error:.2%}'}")
        for result in results:
            for timing in result.timings:
                phases = timing.phase_summary()
                if phases:
                    parts = ", ".join(f"{name} {ms:.3f}" for name, ms in phases.items())
                    print(f"bench {result.scene} [{timing.method}]: step by part (median ms): "
                          f"{parts}")
            for setting in result.settings:
                print(f"bench {result.scene} [reduced, {setting.label} setting: m {setting.m}, "
                      f"r {setting.r}, s {setting.s}, {setting.forces}]: t_total "
                      f"{_ms((setting.t_total() or {}).get('median'))} ms per step, error vs "
                      f"full {_percent(setting.error_vs_full)} with examples, "
                      f"{_percent(setting.error_vs_full_no_examples)} without")
        print(f"bench: {md} and {js}")
    if jobs:
        _print_summary(jobs, file=sys.stderr if args.json else sys.stdout)
    failed = [f"{r.scene} {t.method}: {t.message}" for r in results for t in r.timings
              if not t.stable]
    errors = [job for job in jobs if not job.ok]
    if errors:
        print(f"error: {len(errors)} of {len(jobs)} scenes failed: "
              f"{', '.join(job.scene for job in errors)}", file=sys.stderr)
    if failed:
        print(f"error: simulation stopped: {'; '.join(failed)}", file=sys.stderr)
        return 3
    return max((job.exit_code for job in errors), default=0)


def bench_one(name: str, *, steps: int | None, repeats: int, paper_settings: bool = True,
              progress: bool = False, free_eval: bool = False):
    """:func:`~lbshape.studies.bench.bench_scene` of one scene argument (a batch job), with
    the settings comparison at :func:`~lbshape.studies.bench.paper_setting` unless
    ``paper_settings`` is False, and a free body's evaluation with ``free_eval``."""
    scene = load_scene(name)
    paper = paper_setting(scene, PAPER_TABLE2) if paper_settings else None
    return bench_scene(scene, steps=steps, repeats=repeats, paper=paper, progress=progress,
                       free_eval=free_eval)


def _free_bodies(args) -> int:
    """``--free-bodies``: the free bodies' evaluation (:mod:`lbshape.studies.free_bodies`)."""
    scenes = [load_scene(name) for name in (args.scenes or free_bodies.FREE_SCENES)]
    fixed = [scene.name for scene in scenes if not scene.is_free]
    if fixed:
        raise LbshapeError(f"--free-bodies takes free bodies; fixed: {', '.join(fixed)}")
    for scene in scenes:  # built once here, read from the cache by the workers
        precompute(scene)
    jobs = run_jobs(functools.partial(free_bodies.free_body_job, steps=args.steps),
                    [scene.name for scene in scenes] + free_bodies.impact_jobs(),
                    jobs=args.jobs, progress=not args.json, desc="free bodies")
    failed = [job for job in jobs if not job.ok]
    if failed:
        raise LbshapeError("--free-bodies: " + "; ".join(f"{job.scene}: {job.error}"
                                                          for job in failed))
    runs = [run for job in jobs if job.value[0] == "whole" for run in job.value[1]]
    impacts = [item for job in jobs if job.value[0] == "impacts" for item in job.value[1]]
    command = " ".join(["OMP_NUM_THREADS=1 lbshape bench --free-bodies", *args.scenes,
                        *([f"--steps {args.steps}"] if args.steps else []),
                        *([f"-j {args.jobs}"] if args.jobs > 1 else [])])
    md, js = free_bodies.write_free_bodies(runs, impacts, args.out_dir or DEFAULT_OUT,
                                           command=command)
    if args.json:
        print_json({"whole": [run.stats() for run in runs],
                    "impacts": [impact.stats() for impact in impacts]})
    else:
        for run in runs:
            print(f"bench --free-bodies {run.scene} (examples {'on' if run.examples else 'off'}"
                  f"): error {_percent(run.error)}, noise floor "
                  f"{_percent(run.keys['noise_floor'])}, before contact "
                  f"{_percent(run.keys['error_pre_contact'])}, rest pose "
                  f"{_percent(run.keys['rest_pose_chamfer'])}")
        print(f"bench --free-bodies: {md} and {js}")
    return 0


def _print_summary(jobs, *, file) -> None:
    def cells(result):
        reduced = result.row("reduced") or {}
        error = reduced.get("error_vs_full")
        stable = all(t.stable for t in result.timings)
        return (str(len(result.rows)), _ms(reduced.get("t_total_ms")),
                "—" if error is None else f"{error:.2%}", "yes" if stable else "no")

    print(summary_table(jobs, ("methods", "reduced t_total (ms)", "reduced error", "stable"),
                        cells), file=file)


def _ms(value) -> str:
    return "—" if value is None else f"{value:.3f}"


def _percent(value) -> str:
    return "—" if value is None else f"{value:.2%}"


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


def _scaling(args) -> int:
    if len(args.scenes) > 1:
        raise LbshapeError(f"--scaling takes one built-in scene, got {len(args.scenes)}")
    if args.ranks < 1:
        raise LbshapeError(f"--ranks must be >= 1, got {args.ranks}")
    points = scaling.run_scaling(
        args.sizes or scaling.DEFAULT_SIZES,
        scene=args.scenes[0] if args.scenes else scaling.DEFAULT_SCENE, ranks=args.ranks,
        steps=args.steps or scaling.DEFAULT_STEPS,
        repeats=args.repeats,
        progress=not args.json)
    paths = scaling.write_scaling(points, args.out_dir or DEFAULT_OUT)
    if args.json:
        print_json({"points": [scaling.point_payload(p) for p in points]})
    else:
        for p in points:
            print(f"bench --scaling: {p.n_vertices} vertices: precompute {p.wall_seconds:.1f} s, "
                  f"peak {p.peak_mb:.0f} MB, reduced t_total "
                  f"{float(np.median(p.t_total_ms)):.3f} ms")
        for line in scaling.verdicts(points):
            print(f"bench --scaling: {line}")
        print(f"bench --scaling: {', '.join(str(p) for p in paths)}")
    return 0
