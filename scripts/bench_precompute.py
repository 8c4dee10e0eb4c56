"""Per-stage elastic precompute time on the paper's meshes at the paper's r and s.

Writes ``results/precompute_stages.md`` and ``.csv`` (atomically). Stages: mesh,
linear modes, modal derivatives, basis (mass-PCA), cubature (training forces +
greedy NNLS). Target: every scene's whole elastic precompute in <= 60 s.

Usage: ``.venv/bin/python scripts/bench_precompute.py``
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

RESULTS = Path(__file__).resolve().parents[1] / "results"

#: (label, shape, fixed selection or None, r, s) as in the paper's Table 2
CASES = (
    ("bar", "bar-cuboid", {"region": "z > 0.999"}, 30, 60),
    ("cross", "cross", {"group": "centre"}, 42, 21),
    ("car", "car", None, 20, 23),
    ("teddy", "teddy", {"group": "back"}, 30, 30),
)
STAGES = ("mesh", "modes", "derivatives", "basis", "cubature")


def run(repeats: int = 1) -> list[dict]:
    """Precompute each case from scratch ``repeats`` times; rows of stage seconds."""
    os.environ["LBSHAPE_CACHE"] = tempfile.mkdtemp(prefix="lbshape-bench-")
    from lbshape.pipeline.precompute import precompute
    from lbshape.scene import scene_from_dict

    rows = []
    for label, shape, fixed, r, s in CASES:
        data = {"object": {"shape": shape}, "reduced": {"r": r, "s": s},
                "simulation": {"steps": 1}}
        if fixed is not None:
            data["fixed"] = fixed
        scene = scene_from_dict(data, name=f"bench-{label}")
        for _ in range(repeats):
            pre = precompute(scene, force=True)
            rows.append({"case": label, "n_vertices": pre.mesh.n_vertices,
                         "n_tets": pre.mesh.n_tets, "r": r, "s": s,
                         "free": fixed is None,
                         **{k: pre.stages.seconds.get(k, 0.0) for k in STAGES},
                         "total": sum(pre.stages.seconds.values()),
                         "cubature_holdout": pre.elastic.cubature_errors.get("holdout")})
    return rows


def write(rows: list[dict]) -> None:
    from lbshape.io.atomic import write_text_atomic
    from lbshape.io.machine import machine_text

    header = ["case", "n_vertices", "n_tets", "r", "s", "free", *STAGES, "total",
              "cubature_holdout"]
    csv = [",".join(header)] + [",".join(str(row[h]) for h in header) for row in rows]
    write_text_atomic(RESULTS / "precompute_stages.csv", "\n".join(csv) + "\n")
    lines = [
        "# Elastic precompute time per stage (s)", "",
        f"Wall clock, one process, {machine_text()}; every run from "
        "scratch (cache bypassed). Target: whole elastic precompute <= 60 s per scene.", "",
        "| case | vertices | tets | r | s | free | " + " | ".join(STAGES)
        + " | total | cubature held-out error |",
        "|" + "---|" * (len(STAGES) + 8),
    ]
    for row in rows:
        lines.append(
            f"| {row['case']} | {row['n_vertices']} | {row['n_tets']} | {row['r']} | "
            f"{row['s']} | {'yes' if row['free'] else 'no'} | "
            + " | ".join(f"{row[k]:.2f}" for k in STAGES)
            + f" | {row['total']:.2f} | {row['cubature_holdout']:.3f} |")
    worst = max(row["total"] for row in rows)
    lines += ["", f"Slowest scene: {worst:.1f} s — target {'met' if worst <= 60 else 'NOT met'}."]
    write_text_atomic(RESULTS / "precompute_stages.md", "\n".join(lines) + "\n")


if __name__ == "__main__":
    write(run())
