"""Impact columns on the free bodies: the designed impacts, the whole runs and the step.

Usage: ``.venv/bin/python scripts/bench_impact_columns.py [--columns 26] [--repeats 3]
[--out-dir results] [--scenes car bar-s-cuboid bar-s-cylinder]``.

``reduced.impact_columns`` (:mod:`lbshape.pipeline.impact_columns`) off (0) and on
(a scene's own ``impact_columns``: the car 16, the bars 26; ``--columns`` for the
designed impacts and a scene without), side by side in one process, the
columns either throughout or switched on at each impact and off once the body rests
(:mod:`lbshape.dynamics.impact_switch`, the engine the scenes run):

* **designed impacts** (:func:`lbshape.studies.free_bodies.designed_impacts`, the Figure
  4 bar): the reduced body restarted from the full reference's state just before a face,
  edge or corner hit at 1.5 and 3 m/s, with and without examples; the targets of issue
  41: restitution, Δp and ΔL within 5 % without examples, 10 % with;
* **whole runs**: each scene's own steps, with and without its examples: Table 2's
  ``max_t ‖u − u_full‖_M / max_t ‖u_full‖_M`` against one full-space run;
* **the step**: the reduced runs' mean and median ms per step (the per-step totals) and
  the mean over the last third of the run (the body resting, or about to), the three
  variants interleaved ``--repeats`` times (median over the repeats), against the 1 ms
  budget; r, the steps the columns took and the ``impact-basis`` stage's seconds.

Writes ``impact_columns.md`` and ``impact_columns.json`` (atomically).
"""

from __future__ import annotations

import os

if __name__ == "__main__":  # single-threaded BLAS for the timings, set before numpy loads
    for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import argparse
import dataclasses
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
from lbshape.pipeline.simulate import reduced_simulation
from lbshape.pipeline.simulation import Simulation
from lbshape.scene.reader import load_scene
from lbshape.scene.variants import without_examples
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


def with_columns(scene, count: int):
    """The scene with ``reduced.impact_columns`` = count."""
    return dataclasses.replace(scene, reduced=dataclasses.replace(scene.reduced,
                                                                  impact_columns=count))


def impacts(count: int) -> dict:
    """The designed impacts of the Figure 4 bar on both bases."""
    base = load_scene(IMPACT_BODY)
    out = {}
    for label, scene in (("off", with_columns(base, 0)), ("on", with_columns(base, count))):
        pre = precompute(scene)
        rows = designed_impacts(base, pre)
        out[label] = {"r": pre.r, "rows": rows}
    return out


#: the variants of a scene's reduced run: (impact columns on, switched at the impacts)
VARIANTS = {"off": (False, False), "throughout": (True, False), "switched": (True, True)}


def scene_rows(name: str, count: int, repeats: int) -> list[dict]:
    """Whole-run error and step times of one free body, with and without its examples,
    on the plain basis and with its own impact columns (``count`` for a scene without)
    throughout or switched."""
    base = load_scene(name)
    count = base.reduced.impact_columns or count  # a scene's own count, if it has one
    pres = {False: precompute(with_columns(base, 0)), True: precompute(with_columns(base, count))}
    mass = mass_matrix(pres[False].mesh, pres[False].material.density)
    rows = []
    for examples in (True, False):
        scenes = {on: with_columns(base if examples else without_examples(base),
                                   count if on else 0) for on in (False, True)}
        steps = base.simulation.steps
        full = Simulation(scenes[False], pres[False], method="full")
        full_record = full.run(steps)
        u_full = full.displacements(full_record)
        times = {label: [] for label in VARIANTS}
        errors, column_steps = {}, {}
        for repeat in range(repeats):
            order = list(VARIANTS) if repeat % 2 == 0 else list(VARIANTS)[::-1]
            for label in order:
                on, switched = VARIANTS[label]
                engine = reduced_simulation(scenes[on], pres[on], impact_switch=switched)
                sim = Simulation(scenes[on], pres[on], method="reduced", engine=engine)
                record = sim.run(steps)
                if not record.stable:
                    raise SystemExit(f"{name} ({label}): {record.message}")
                totals = np.asarray(record.t_total_ms)
                times[label].append((float(totals.mean()), float(np.median(totals)),
                                     float(totals[-(steps // 3):].mean())))
                column_steps[label] = getattr(engine, "column_steps", steps if on else 0)
                if label not in errors:
                    u = sim.displacements(record)
                    count_ = min(len(u), len(u_full))
                    errors[label] = float(trajectory_error(u[:count_], u_full[:count_], mass))
        for label, (on, _) in VARIANTS.items():
            means, medians, lasts = zip(*times[label], strict=True)
            rows.append({
                "scene": name, "examples": examples, "columns": label,
                "r": pres[on].r, "steps": steps, "full_stable": bool(full_record.stable),
                "error": errors[label], "mean_ms": float(np.median(means)),
                "median_ms": float(np.median(medians)), "last_ms": float(np.median(lasts)),
                "column_steps": int(column_steps[label]),
                "stage_s": pres[on].stages.seconds.get("impact-basis") if on else None,
            })
    return rows


def _pct(value) -> str:
    return "—" if value is None else f"{100 * value:.2f}%"


def markdown(payload: dict) -> str:
    count = payload["columns"]
    lines = [
        "# Impact columns on the free bodies",
        "",
        f"`reduced.impact_columns` off (0) and on (the scene's own: the car 16, the bars "
        f"26; {count} for the designed impacts and a scene without) "
        "(`lbshape.pipeline.impact_columns`: throws at the convex hull's sides, creases and "
        "corners; the columns' own energy exact, their coupling linear), side by side in one "
        "process. The built-in free bodies run them switched: on from each impact's onset "
        "until the body rests (`lbshape.dynamics.impact_switch`). A designed impact "
        "restarts the body on the columns.",
        "",
        f"Command: `{payload['command']}`  ",
        f"Commit: `{payload['commit']}`, {payload['date']}  ",
        f"Machine: {payload['machine_text']}; load average at the end "
        f"{payload['load']}",
        "",
        "## Designed impacts (the Figure 4 bar, from a synchronised pre-impact state)",
        "",
    ]
    for label in ("off", "on"):
        block = payload["impacts"][label]
        lines += [f"### Impact columns {label} (r {block['r']}): {block['summary']}", ""]
        lines += block["lines"] + [""]
    lines += [
        "## Whole runs and the step",
        "",
        "Error: `max_t ‖u − u_full‖_M / max_t ‖u_full‖_M` over the scene's own steps "
        "against one full-space run. Step: the reduced run's per-step totals, mean and "
        f"median, and the mean over the run's last third, median over {payload['repeats']} "
        f"interleaved repeats; budget {BUDGET_MS:g} ms (the mean). Impact columns: off "
        "(r of the plain basis), throughout, or switched (on from each impact until the "
        "body rests); column steps: the steps taken on the columns.",
        "",
        "| scene | examples | impact columns | r | steps | column steps | error vs full | "
        "mean ms/step | median ms/step | last third ms/step | within budget | "
        "impact-basis stage (s) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in payload["scenes"]:
        stage = "—" if row["stage_s"] is None else f"{row['stage_s']:.1f}"
        lines.append(
            f"| {row['scene']} | {'yes' if row['examples'] else 'no'} | {row['columns']} | "
            f"{row['r']} | {row['steps']} | {row['column_steps']} | {_pct(row['error'])} | "
            f"{row['mean_ms']:.3f} | {row['median_ms']:.3f} | {row['last_ms']:.3f} | "
            f"{'yes' if row['mean_ms'] <= BUDGET_MS else '**no**'} | {stage} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> list[Path]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--columns", type=int, default=26)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--scenes", nargs="+", default=list(SCENES))
    parser.add_argument("--out-dir", type=Path, default=Path("results"))
    args = parser.parse_args(argv)
    blocks = impacts(args.columns)
    rows = [row for name in args.scenes for row in scene_rows(name, args.columns, args.repeats)]
    machine = machine_description()
    payload = {
        "command": "python scripts/bench_impact_columns.py " + " ".join(
            argv if argv is not None else sys.argv[1:]),
        "commit": subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True,
                                 text=True, check=False).stdout.strip() or "unknown",
        "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "machine": machine, "machine_text": machine_text(machine), "load": load_text(machine),
        "columns": args.columns, "repeats": args.repeats, "scenes": rows,
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
