"""Impact columns on the free bodies: the designed impacts, the whole runs and the step.

Usage: ``.venv/bin/python scripts/bench_impact_columns.py [--repeats 3]
[--out-dir results] [--scenes car bar-s-cuboid bar-s-cylinder]``.

Four arrangements of ``reduced.impact_columns`` (:mod:`lbshape.pipeline.impact_columns`)
side by side in one process, all switched on at each impact and off once the body rests
(:mod:`lbshape.dynamics.impact_switch`):

* ``off``: none (the plain basis);
* ``body``: one set for the whole body (:data:`BODY_COLUMNS`: the car 16, the bars 26);
* ``feature``: ``impact_columns_per = "feature"``, the scene's own count for each hull
  feature (3), the set of the feature a hit touches switched on;
* ``feature-pair``: the scene's own, ``impact_columns_per = "feature-pair"`` (both
  features' columns for each pair of neighbouring hull features, the set of the pair
  nearest a hit switched on).

Measured:

* **designed impacts** (:func:`lbshape.studies.free_bodies.designed_impacts`, the Figure
  4 bar): the reduced body restarted from the full reference's state just before a face,
  edge or corner hit at 1.5 and 3 m/s, with and without examples; the targets of issue
  41: restitution, Δp and ΔL within 5 % without examples, 10 % with;
* **whole runs**: each scene's own steps, with and without its examples: Table 2's
  ``max_t ‖u − u_full‖_M / max_t ‖u_full‖_M`` against one full-space run;
* **the step**: the reduced runs' per-step totals: mean, median, 95th percentile, the
  steps over the 1 ms budget (each step advances 1 ms: slower than real time) and the
  mean over the run's last third, the three arrangements interleaved ``--repeats`` times
  (median over the repeats); r stepping on the columns, the steps the columns took and
  the ``impact-basis`` stage's seconds.

Writes ``impact_columns.md`` and ``impact_columns.json`` (atomically).
"""

from __future__ import annotations

import os

if __name__ == "__main__":  # single-threaded BLAS for the timings, set before numpy loads
    for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import argparse
import datetime
import subprocess
import sys
from pathlib import Path

import numpy as np

from lbshape.analysis.norms import trajectory_error
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.io.atomic import write_json_atomic, write_text_atomic
from lbshape.io.machine import load_text, machine_description, machine_text
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulation import Simulation
from lbshape.scene.reader import load_scene
from lbshape.scene.variants import with_impact_columns, without_examples
from lbshape.studies.free_bodies import (
    IMPACT_BODY,
    designed_impacts,
    impact_lines,
    impacts_summary,
)

#: the free bodies measured by default
SCENES = ("bar-s-cuboid", "bar-s-cylinder", "car")
#: the step budget (ms per 1 ms step)
BUDGET_MS = 1.0


#: the columns of one set for the whole body (``body``): the bars' and the car's counts
#: before their sets per feature
BODY_COLUMNS = {"car": 16}
#: ... and every other body's
BODY_COLUMNS_DEFAULT = 26
#: the arrangements compared
ARRANGEMENTS = ("off", "body", "feature", "feature-pair")


def arranged(scene, arrangement: str):
    """The scene with its impact columns as ``arrangement`` (:data:`ARRANGEMENTS`;
    ``feature-pair``: the scene's own, which must be per pair of features)."""
    if scene.reduced.impact_columns_per != "feature-pair":
        raise SystemExit(f"{scene.name}: its impact columns are not per pair of features")
    if arrangement == "feature-pair":
        return scene
    if arrangement == "feature":
        return with_impact_columns(scene, scene.reduced.impact_columns, "feature")
    return with_impact_columns(scene, 0 if arrangement == "off" else BODY_COLUMNS.get(
        scene.name, BODY_COLUMNS_DEFAULT))


def stepping_r(pre) -> int:
    """The coordinates a step on the columns solves for: r, or r₀ + one set's."""
    sets = pre.elastic.impact_column_sets()
    return pre.r if len(sets) < 2 else pre.elastic.leading + len(sets[0])


def impacts() -> dict:
    """The designed impacts of the Figure 4 bar in each arrangement."""
    base = load_scene(IMPACT_BODY)
    out = {}
    for label in ARRANGEMENTS:
        pre = precompute(arranged(base, label))
        out[label] = {"r": stepping_r(pre), "rows": designed_impacts(arranged(base, label), pre)}
    return out


def _timings(totals: np.ndarray, steps: int) -> tuple:
    """(mean, median, 95th percentile, steps over the budget, last third's mean) in ms."""
    return (float(totals.mean()), float(np.median(totals)), float(np.percentile(totals, 95)),
            int(np.count_nonzero(totals > BUDGET_MS)), float(totals[-(steps // 3):].mean()))


def scene_rows(name: str, repeats: int) -> list[dict]:
    """Whole-run error and step times of one free body, with and without its examples,
    in each arrangement (the runs without examples on the precompute with them, as Table
    2's)."""
    base = load_scene(name)
    pres = {label: precompute(arranged(base, label)) for label in ARRANGEMENTS}
    mass = mass_matrix(pres["off"].mesh, pres["off"].material.density)
    rows = []
    for examples in (True, False):
        scenes = {label: arranged(base if examples else without_examples(base), label)
                  for label in ARRANGEMENTS}
        steps = base.simulation.steps
        full = Simulation(scenes["off"], pres["off"], method="full")
        full_record = full.run(steps)
        u_full = full.displacements(full_record)
        times = {label: [] for label in ARRANGEMENTS}
        errors, column_steps = {}, {}
        for repeat in range(repeats):
            order = list(ARRANGEMENTS) if repeat % 2 == 0 else list(ARRANGEMENTS)[::-1]
            for label in order:
                sim = Simulation(scenes[label], pres[label], method="reduced")
                record = sim.run(steps)
                if not record.stable:
                    raise SystemExit(f"{name} ({label}): {record.message}")
                times[label].append(_timings(np.asarray(record.t_total_ms), steps))
                column_steps[label] = getattr(sim.engine, "column_steps", 0)
                if label not in errors:
                    u = sim.displacements(record)
                    count_ = min(len(u), len(u_full))
                    errors[label] = float(trajectory_error(u[:count_], u_full[:count_], mass))
        for label in ARRANGEMENTS:
            mean, median, p95, over, last = np.median(np.array(times[label]), axis=0)
            pre = pres[label]
            rows.append({
                "scene": name, "examples": examples, "columns": label,
                "r": pre.r, "r_stepping": stepping_r(pre), "steps": steps,
                "full_stable": bool(full_record.stable), "error": errors[label],
                "mean_ms": float(mean), "median_ms": float(median), "p95_ms": float(p95),
                "steps_over_budget": int(round(over)), "last_ms": float(last),
                "column_steps": int(column_steps[label]),
                "stage_s": pre.stages.seconds.get("impact-basis") if label != "off" else None,
            })
    return rows


def _pct(value) -> str:
    return "—" if value is None else f"{100 * value:.2f}%"


def markdown(payload: dict) -> str:
    lines = [
        "# Impact columns on the free bodies",
        "",
        "`reduced.impact_columns` (`lbshape.pipeline.impact_columns`: throws at the convex "
        "hull's sides, creases and corners; the columns' own energy exact, their coupling "
        "linear) in four arrangements, side by side in one process, each switched on at "
        "an impact's onset and off once the body rests (`lbshape.dynamics.impact_switch`): "
        "off (the plain basis); `body`, one set for the whole body (the car 16 columns, the "
        "bars 26); `feature`, 3 columns for each hull feature, the set of the feature a hit "
        "touches switched on; `feature-pair`, the built-in scenes' own: one set of 6 for "
        "each pair of neighbouring features (both features' 3), the set of the pair "
        "nearest a hit switched on. A designed impact restarts the body "
        "in flight, 3 steps before its contact.",
        "",
        f"Command: `{payload['command']}`  ",
        f"Commit: `{payload['commit']}`, {payload['date']}  ",
        f"Machine: {payload['machine_text']}; load average at the end "
        f"{payload['load']}",
        "",
        "## Designed impacts (the Figure 4 bar, from a synchronised pre-impact state)",
        "",
    ]
    for label in ARRANGEMENTS:
        block = payload["impacts"][label]
        lines += [f"### Impact columns {label} (r {block['r']} stepping): {block['summary']}",
                  ""]
        lines += block["lines"] + [""]
    lines += [
        "## Whole runs and the step",
        "",
        "Error: `max_t ‖u − u_full‖_M / max_t ‖u_full‖_M` over the scene's own steps "
        "against one full-space run (the runs without examples on the precompute with "
        "them, as in Table 2). Step: the reduced run's per-step totals: mean, median, 95th "
        f"percentile, the steps over the {BUDGET_MS:g} ms budget (a step advances 1 ms: "
        "those are slower than real time) and the mean over the run's last third, median "
        f"over {payload['repeats']} interleaved repeats. r: the precompute's basis; "
        "stepping: what a step on the columns solves for (r₀ + one set's: 3 per feature, "
        "6 per pair); "
        "column steps: the steps taken on the columns.",
        "",
        "| scene | examples | impact columns | r | r stepping | steps | column steps | "
        "error vs full | mean ms/step | median ms/step | 95th percentile ms | steps over "
        f"{BUDGET_MS:g} ms | last third ms/step | impact-basis stage (s) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in payload["scenes"]:
        stage = "—" if row["stage_s"] is None else f"{row['stage_s']:.1f}"
        lines.append(
            f"| {row['scene']} | {'yes' if row['examples'] else 'no'} | {row['columns']} | "
            f"{row['r']} | {row['r_stepping']} | {row['steps']} | {row['column_steps']} | "
            f"{_pct(row['error'])} | {row['mean_ms']:.3f} | {row['median_ms']:.3f} | "
            f"{row['p95_ms']:.3f} | {row['steps_over_budget']} | {row['last_ms']:.3f} | "
            f"{stage} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> list[Path]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--scenes", nargs="+", default=list(SCENES))
    parser.add_argument("--out-dir", type=Path, default=Path("results"))
    args = parser.parse_args(argv)
    blocks = impacts()
    rows = [row for name in args.scenes for row in scene_rows(name, args.repeats)]
    machine = machine_description()
    payload = {
        "command": "python scripts/bench_impact_columns.py " + " ".join(
            argv if argv is not None else sys.argv[1:]),
        "commit": subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True,
                                 text=True, check=False).stdout.strip() or "unknown",
        "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "machine": machine, "machine_text": machine_text(machine), "load": load_text(machine),
        "body_columns": {**BODY_COLUMNS, "default": BODY_COLUMNS_DEFAULT},
        "repeats": args.repeats, "scenes": rows,
        "impacts": {label: {"r": block["r"],
                            "stats": [impact.stats() for impact in block["rows"]],
                            "lines": impact_lines(block["rows"]),
                            "summary": impacts_summary(block["rows"])}
                    for label, block in blocks.items()},
    }
    args.out_dir.mkdir(parents=True, exist_ok=True)
    md, js = args.out_dir / "impact_columns.md", args.out_dir / "impact_columns.json"
    write_text_atomic(md, markdown(payload))
    write_json_atomic(js, {k: v for k, v in payload.items() if k != "machine_text"})
    print(md)
    return [md, js]


if __name__ == "__main__":
    main()
