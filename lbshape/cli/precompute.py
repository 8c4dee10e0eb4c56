"""``lbshape precompute SCENE [--force]``: build or reuse the cached precompute."""

from __future__ import annotations

from lbshape.pipeline.precompute import precompute
from lbshape.scene import load_scene


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "precompute", help="build or reuse the cached precompute of a scene")
    parser.add_argument("scene", help="built-in scene name or path to a TOML file")
    parser.add_argument("--force", action="store_true", help="recompute even if cached")
    parser.set_defaults(func=run)


def run(args) -> int:
    scene = load_scene(args.scene)
    pre = precompute(scene, force=args.force, progress=True)
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
    return 0
