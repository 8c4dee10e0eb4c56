"""``lbshape precompute SCENE… [--force] [-j N] [--json]``: build or reuse the cached
precompute.

One scene: progress bars per stage and a summary of the artifact (``--json``: the
summary as one JSON object on stdout, with the time and the number of ranks of each
stage). Several scenes (names, TOML paths or globs): one job per scene in ``-j``
worker processes, then one summary table; a failed scene is listed and does not stop
the others (exit code non-zero at the end). Under ``mpirun`` (one scene) the solver
stages are distributed over the ranks (:func:`lbshape.pipeline.precompute.precompute`
with ``MPI.COMM_WORLD``); only rank 0 prints and writes the cache.
"""

from __future__ import annotations

import functools
import json
import sys

from mpi4py import MPI

from lbshape.api import expand_scenes, load_scene, precompute, run_jobs, summary_table
from lbshape.cli._mpi import errors_on_rank_zero, require_one_rank
from lbshape.errors import LbshapeError


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "precompute", help="build or reuse the cached precompute of scenes")
    parser.add_argument("scenes", nargs="+", metavar="SCENE",
                        help="built-in scene names, TOML paths or globs")
    parser.add_argument("--force", action="store_true", help="recompute even if cached")
    parser.add_argument("-j", "--jobs", type=int, default=1,
                        help="worker processes for several scenes (default 1)")
    parser.add_argument("--json", action="store_true",
                        help="print the summary of one scene as JSON (stage times and ranks)")
    parser.set_defaults(func=run)


def run(args) -> int:
    if args.jobs < 1:
        raise LbshapeError(f"-j/--jobs must be >= 1, got {args.jobs}")
    scenes, unmatched = expand_scenes(args.scenes)
    if len(scenes) == 1 and not unmatched:
        return run_one(scenes[0], force=args.force, as_json=args.json)
    require_one_rank("precompute of several scenes")
    if args.json:
        raise LbshapeError("--json summarises one scene: give exactly one")
    results = unmatched + run_jobs(functools.partial(precompute_summary, force=args.force),
                                   scenes, jobs=args.jobs, progress=True, desc="precompute")
    print(summary_table(results, ("origin", "vertices", "tets", "m", "r", "s", "stages (s)"),
                        lambda v: (v["origin"], str(v["n_vertices"]), str(v["n_tets"]),
                                   v["m"], str(v["r"]), str(v["s"]),
                                   f"{v['stage_seconds']:.1f}")))
    failed = [r for r in results if not r.ok]
    if failed:
        print(f"error: {len(failed)} of {len(results)} scenes failed: "
              f"{', '.join(r.scene for r in failed)}", file=sys.stderr)
        return max(r.exit_code for r in failed)
    return 0


def precompute_summary(name: str, *, force: bool = False) -> dict:
    """Precompute one scene (no progress bars) and return its one-row summary."""
    scene = load_scene(name)
    pre = precompute(scene, force=force)
    return {"scene": scene.name, "origin": "cache" if pre.stages.from_cache else "computed",
            "key": pre.key, "n_vertices": pre.mesh.n_vertices, "n_tets": pre.mesh.n_tets,
            "m": "—" if pre.shape is None else str(pre.shape.eigenvalues.size), "r": pre.r,
            "s": int(pre.elastic.cubature_elements.size),
            "stage_seconds": float(sum(pre.stages.seconds.values()))}


def precompute_record(pre) -> dict:
    """The JSON summary of one precompute: sizes, cubature errors, and per stage the wall
    time (s), the peak memory (MB, summed over the ranks) and the number of MPI ranks it
    ran on (of the run that built the artifact)."""
    return {"scene": pre.scene, "origin": "cache" if pre.stages.from_cache else "computed",
            "key": pre.key, "n_vertices": pre.mesh.n_vertices, "n_tets": pre.mesh.n_tets,
            "m": None if pre.shape is None else int(pre.shape.eigenvalues.size), "r": pre.r,
            "s": int(pre.elastic.cubature_elements.size), "forces": pre.elastic.force_model,
            "cubature_errors": pre.elastic.cubature_errors,
            "stage_seconds": dict(pre.stages.seconds),
            "stage_peak_mb": dict(pre.stages.peak_mb),
            "stage_ranks": dict(pre.stages.ranks),
            "stages_from_cache": list(pre.stages.cached),
            "total_seconds": float(sum(pre.stages.seconds.values())),
            "example_stiffness": (None if pre.auto_stiffness is None
                                  else pre.auto_stiffness.to_dict())}


def run_one(name: str, *, force: bool = False, as_json: bool = False) -> int:
    comm = MPI.COMM_WORLD
    with errors_on_rank_zero():
        scene = load_scene(name)
        pre = precompute(scene, force=force, progress=comm.rank == 0, comm=comm)
    if comm.rank != 0:
        return 0
    if as_json:
        print(json.dumps(precompute_record(pre), indent=2))
        return 0
    origin = "cache" if pre.stages.from_cache else "computed"
    errors = pre.elastic.cubature_errors
    print(f"precompute {scene.name} ({origin}, key {pre.key[:16]}): n={pre.mesh.n_vertices} "
          f"vertices, {pre.mesh.n_tets} tets, r={pre.r}, s={pre.elastic.cubature_elements.size}, "
          f"cubature error train {errors.get('train', float('nan')):.3g} / "
          f"held-out {errors.get('holdout', float('nan')):.3g}; reduced forces: "
          + ("exact polynomials (every element)" if pre.elastic.force_model == "polynomial"
             else "the cubature"))
    if pre.auto_stiffness is not None:
        print(f"  {pre.auto_stiffness.summary()}")
    if pre.has_examples:
        residuals = ", ".join(f"{r:.3f}" for r in pre.examples.alignment_residuals)
        methods = ", ".join(pre.examples.alignment_methods)
        print(f"  shape space: m={pre.shape.m}, {len(pre.shape.example_names)} examples, "
              f"alignment residuals [{residuals}], methods [{methods}]")
    if pre.has_local_examples:
        for region in pre.local.regions:
            residuals = ", ".join(f"{r:.3f}" for r in region.alignment_residuals)
            print(f"  region {region.name}: {region.vertices.size} vertices, "
                  f"m={region.m}, examples {[int(k) for k in region.examples]}, "
                  f"alignment residuals [{residuals}], methods [{', '.join(region.methods)}]")
    total = sum(pre.stages.seconds.values())
    print("  stage times (s): " + ", ".join(
        f"{name} {seconds:.2f}" for name, seconds in pre.stages.seconds.items())
        + f"; total {total:.2f}" + (" (when computed)" if pre.stages.from_cache else ""))
    if pre.stages.cached and not pre.stages.from_cache:
        print(f"  stages from the cache: {', '.join(pre.stages.cached)}")
    if pre.stages.peak_mb:
        print("  stage peak memory (MB): " + ", ".join(
            f"{name} {mb:.0f}" for name, mb in pre.stages.peak_mb.items())
            + f"; peak {max(pre.stages.peak_mb.values()):.0f}")
    print("  " + stage_ranks_text(pre.stages.ranks))
    return 0


def stage_ranks_text(stage_ranks: dict) -> str:
    """One line: which stages ran distributed over how many MPI ranks."""
    size = max(stage_ranks.values(), default=1)
    if size <= 1:
        return "stages ran on one process"
    shared = [name for name, count in stage_ranks.items() if count == size]
    alone = [name for name, count in stage_ranks.items() if count < size]
    return (f"distributed over {size} MPI ranks: {', '.join(shared)}; on rank 0: "
            f"{', '.join(alone) or 'none'}")
