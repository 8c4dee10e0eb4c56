"""``lbshape precompute SCENE… [--force] [-j N]``: build or reuse the cached precompute.

One scene: progress bars per stage and a summary of the artifact. Several scenes
(names, TOML paths or globs): one job per scene in ``-j`` worker processes, then one
summary table; a failed scene is listed and does not stop the others (exit code
non-zero at the end). Under ``mpirun`` (one scene) every rank computes; only rank 0
prints and writes the cache.
"""

from __future__ import annotations

import functools
import sys

from lbshape.cli._mpi import errors_on_rank_zero, require_one_rank, world_rank_size
from lbshape.errors import LbshapeError
from lbshape.pipeline.batch import expand_scenes, run_jobs, summary_table
from lbshape.pipeline.precompute import precompute
from lbshape.scene import load_scene


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "precompute", help="build or reuse the cached precompute of scenes")
    parser.add_argument("scenes", nargs="+", metavar="SCENE",
                        help="built-in scene names, TOML paths or globs")
    parser.add_argument("--force", action="store_true", help="recompute even if cached")
    parser.add_argument("-j", "--jobs", type=int, default=1,
                        help="worker processes for several scenes (default 1)")
    parser.set_defaults(func=run)


def run(args) -> int:
    if args.jobs < 1:
        raise LbshapeError(f"-j/--jobs must be >= 1, got {args.jobs}")
    scenes, unmatched = expand_scenes(args.scenes)
    if len(scenes) == 1 and not unmatched:
        return run_one(scenes[0], force=args.force)
    require_one_rank("precompute of several scenes")
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
    return {"scene": scene.name, "origin": "cache" if pre.from_cache else "computed",
            "key": pre.key, "n_vertices": pre.mesh.n_vertices, "n_tets": pre.mesh.n_tets,
            "m": "—" if pre.eigenvalues is None else str(pre.eigenvalues.size), "r": pre.r,
            "s": int(pre.cubature_elements.size),
            "stage_seconds": float(sum(pre.stage_seconds.values()))}


def run_one(name: str, *, force: bool = False) -> int:
    rank, _ = world_rank_size()
    with errors_on_rank_zero():
        scene = load_scene(name)
        pre = precompute(scene, force=force, progress=rank == 0, save=rank == 0)
    if rank != 0:
        return 0
    origin = "cache" if pre.from_cache else "computed"
    print(f"precompute {scene.name} ({origin}, key {pre.key[:16]}): n={pre.mesh.n_vertices} "
          f"vertices, {pre.mesh.n_tets} tets, r={pre.r}, s={pre.cubature_elements.size}, "
          f"cubature error train {pre.cubature_errors.get('train', float('nan')):.3g} / "
          f"held-out {pre.cubature_errors.get('holdout', float('nan')):.3g}")
    if pre.has_examples:
        residuals = ", ".join(f"{r:.3f}" for r in pre.alignment_residuals)
        print(f"  shape space: m={pre.eigenvalues.size}, {len(pre.example_names)} examples, "
              f"alignment residuals [{residuals}]")
    if pre.has_local_examples:
        for region in pre.local.regions:
            residuals = ", ".join(f"{r:.3f}" for r in region.alignment_residuals)
            print(f"  region {region.name}: {region.vertices.size} vertices, "
                  f"m={region.m}, examples {[int(k) + 1 for k in region.examples]}, "
                  f"alignment residuals [{residuals}]")
    total = sum(pre.stage_seconds.values())
    print("  stage times (s): " + ", ".join(
        f"{name} {seconds:.2f}" for name, seconds in pre.stage_seconds.items())
        + f"; total {total:.2f}" + (" (when computed)" if pre.from_cache else ""))
    if pre.stage_peak_mb:
        print("  stage peak memory (MB): " + ", ".join(
            f"{name} {mb:.0f}" for name, mb in pre.stage_peak_mb.items())
            + f"; peak {max(pre.stage_peak_mb.values()):.0f}")
    return 0

