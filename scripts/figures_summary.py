"""Writes ``results/figures/README.md``: what a person sees in each scene's figures.

Reads the JSON files that ``lbshape render SCENE`` writes beside its pictures
(``comparison.json``, ``local_examples.json``, ``runs_by_example.json``,
``summary.json``) and tabulates, per scene: the visible change the examples make
(largest vertex distance between the final shapes with and without examples over the
rest bounding-box diagonal; free bodies: deformations), the shape each run ends closest
to, and the run's largest displacement over the object's size. Run after
``lbshape render`` of the scenes::

    python scripts/figures_summary.py [--figures results/figures]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from lbshape.pipeline.precompute import precompute
from lbshape.scene import load_scene


def _load(path: Path) -> dict | None:
    return json.loads(path.read_text()) if path.exists() else None


def _closest(value) -> str:
    if isinstance(value, dict):
        return ", ".join(f"{name} → {k}" for name, k in value.items())
    return str(value)


def rows(figures: Path) -> list[str]:
    lines = []
    for folder in sorted(p for p in figures.iterdir() if p.is_dir()):
        summary = _load(folder / "summary.json")
        if summary is None:
            continue
        scene = load_scene(folder.name)
        points = precompute(scene).mesh.points
        extent = np.ptp(points, axis=0)
        diagonal = float(np.linalg.norm(extent))
        largest = summary["simulation"].get("max_displacement")
        size = (f"{largest:.3f} m = {100 * largest / extent.max():.1f} % of the longest "
                f"side ({extent.max():.2f} m)" if largest is not None and not scene.is_free
                else "— (a free body's displacement is its flight)")
        for name in ("comparison.json", "local_examples.json"):
            data = _load(folder / name)
            if data is not None and "visible_change" in data:
                lines.append(f"| {folder.name} | {name.split('.')[0]} | "
                             f"{100 * data['visible_change']:.1f} % of {diagonal:.2f} m | "
                             f"{_closest(data['closest_example'])} | {size} |")
        runs = _load(folder / "runs_by_example.json")
        if runs is not None and "visible_change" in runs:
            for run in runs["runs"][1:]:
                lines.append(f"| {folder.name} | runs_by_example: {run} | "
                             f"{100 * runs['visible_change'][run]:.1f} % of {diagonal:.2f} m | "
                             f"{runs['closest_example'][run]} | — |")
    return lines


def figure6_lines(figures: Path) -> list[str]:
    """Figure 6's table from ``figure6.json`` (``lbshape render teddy-local``): per region,
    its largest displacement in each run and the local-vs-global distance, as shares
    of the object's height; empty without the file."""
    data = next((d for d in (_load(folder / "figure6.json") for folder in
                             sorted(p for p in figures.iterdir() if p.is_dir()))
                 if d is not None), None)
    if data is None:
        return []
    moved, apart = data["largest_displacement_over_height"], data["local_vs_global_over_height"]
    runs = list(moved)
    lines = ["", f"## Figure 6: {data['scenes'][1]} against {data['scenes'][0]} "
             f"(`figure6.png`, `figure6_difference.png`)", "",
             f"Largest vertex displacement per region at t = {data['time_s']:.2f} s, and the "
             "largest distance between the local and the global run, as shares of the "
             f"object's height ({data['height_m']:.2f} m). Over the whole object the two "
             f"runs are up to {100 * data['local_vs_global_max_m']:.1f} cm apart "
             f"({data['local_vs_global_max_where']}).", "",
             "| region | " + " | ".join(runs) + " | local vs global |",
             "|---|" + "---|" * (len(runs) + 1)]
    for region in apart:
        cells = " | ".join(f"{100 * moved[run][region]:.1f} %" for run in runs)
        lines.append(f"| {region} | {cells} | {100 * apart[region]:.1f} % |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--figures", type=Path, default=Path("results/figures"))
    args = parser.parse_args()
    table = rows(args.figures)
    text = "\n".join([
        "# What the figures show",
        "",
        "Made by `python scripts/figures_summary.py` from the JSON files that `lbshape render "
        "SCENE` wrote beside each scene's pictures (reduced runs, the scenes' own steps).",
        "*Visible change*: the largest vertex distance between the final shapes with and "
        "without examples, over the rest bounding-box diagonal (free bodies: their "
        "deformations, best rigid fit removed). *Closest*: the shape the final shape is "
        "closest to in shape space — `rest` or an example's index in the scene (local "
        "examples: per region, among the rest shape and the region's own examples; Figure "
        "5's rows: among all the car's examples, 0 arc, 1 s-bend, 2 twist).",
        "",
        "| scene | figure | visible change | closest | largest displacement (examples run) |",
        "|---|---|---|---|---|",
        *table, *figure6_lines(args.figures), "",
    ])
    out = args.figures / "README.md"
    out.write_text(text)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
