"""The benchmark's written tables: Table 2 (Markdown + JSON) and the sweep (CSV).

* :func:`write_table2` — ``table2.md`` (the paper's Table 2 layout, plus speed-ups,
  errors, the spread of the times, the paper's settings beside lbshape's, a free
  body's error split into rigid motion and deformation, the conditions of the
  measurement and the targets) and ``table2.json``;
* :func:`write_sweep` — ``speed_vs_error.csv`` and its plot ``speed_vs_error.png``.

Every file is written atomically.
"""

from __future__ import annotations

import csv
import dataclasses
import io
from collections.abc import Sequence
from pathlib import Path

from lbshape.errors import LbshapeError
from lbshape.io.atomic import write_json_atomic, write_text_atomic
from lbshape.io.machine import load_text, machine_description, threads_text
from lbshape.report.plots import speed_error_plot
from lbshape.studies.bench import (
    DEFAULT_OUT,
    ROW_EXTRA_KEYS,
    SETTINGS_TARGET_ERROR,
    TARGET_ERROR,
    TARGET_INTERP_SPEEDUP,
    TARGET_T_TOTAL_MS,
    SceneBenchmark,
    SettingResult,
)
from lbshape.studies.realtime import breakdown_lines
from lbshape.studies.sweep import SweepPoint

_INTRO = (
    "Columns as in the paper's Table 2: DOFs (3 × vertices) and tetrahedra of the "
    "object, vertices of the last example, m LB eigenfunctions, r reduced "
    "coordinates, s the elements the reduced elastic force sums over (every element with "
    "the exact polynomial StVK force, else the cubature's); per-step times in ms for the "
    "Euclidean "
    "baseline (Zhu et al. 2015: target found in LB space with the energy over all "
    "elements, reduced dynamics) and the reduced method (the paper's); speed-ups "
    "euclidean / reduced; the full-space reference's per-step time; and the error "
    "of each method against it, `max_t ‖u(t) − u_full(t)‖_M / max_t ‖u_full(t)‖_M` "
    "(M the consistent elastic mass)."
)
_INFLUENCE_INTRO = (
    "Each scene with examples is run again without them (same method, steps and "
    "precompute): influence `‖u_ex(T) − u_none(T)‖_M / ‖u_none(T)‖_M` at the last step "
    "and `max_t ‖u_ex − u_none‖_M / max_t ‖u_none‖_M`; the eq. 5 residual is the "
    "distance of the final shape's LB descriptor to the convex hull of the example "
    "descriptors, over the largest example descriptor (0: on the example manifold). "
    "Frame `world`: u is the world displacement (fixed objects); `body`: u is the "
    "deformation, the displacement after the mass-weighted best rigid fit (free bodies, "
    "whose world displacement is mostly the rigid motion); the world-displacement "
    "influence at T is listed for every scene."
)
_SETTINGS_INTRO = (
    "Each scene's reduced method at two settings, timed in the same run, the repeats "
    "interleaved with the other methods: `paper`, the paper's Table 2 m, r, s with its "
    "cubature forces (a scene the paper has no row for: the scene's m, r, s with "
    "cubature forces), and `lbshape`, the scene as written (its force model resolved: "
    "the exact polynomial StVK forces sum over every element). Per setting: the reduced "
    "per-step total time, median [min, max] over the repeats (ms); the error against "
    "the full-space reference with the scene's examples, and without them (`k_ex = 0` "
    "in both runs; each full reference runs once and serves both settings; a scene "
    "without examples has one run, so both errors are the same); whether "
    f"≤ {TARGET_T_TOTAL_MS:g} ms per step and an error (with examples) ≤ "
    f"{SETTINGS_TARGET_ERROR:.0%} are met. Free bodies: the error with examples split "
    "into the centre-of-mass path, the rotation and the body-frame deformation (next "
    "section)."
)
_FREE_BODY_INTRO = (
    "A free body's whole-field error is dominated by its rigid motion. Beside it, from "
    "the same runs: the centre-of-mass path error `max_t |c(t) − c_full(t)| / max_t "
    "|c_full(t) − c_full(0)|` (c the mass-weighted centre of the deformed mesh), the "
    "largest rotation between the mass-weighted best rigid fits `max_t angle(R(t) "
    "R_full(t)ᵀ)` (degrees), and the body-frame deformation error `max_t ‖d − d_full‖_M "
    "/ max_t ‖d_full‖_M` (d the displacement after the best rigid fit); a difference in "
    "rigid motion alone leaves the last at 0."
)
_COLUMNS = (
    "| model | DOFs | tets | ex. | m | r | s | euclidean t_interp | euclidean t_total "
    "| reduced t_interp | reduced t_total | speed-up interp | speed-up total "
    "| full t_total | error reduced | error euclidean |"
)


def _fmt(value: float | None, spec: str = ".3f") -> str:
    return "—" if value is None else format(value, spec)


def _ratio(numerator: float | None, denominator: float | None) -> float | None:
    if numerator is None or not denominator:
        return None
    return numerator / denominator


def _cost_row(result: SceneBenchmark) -> str:
    """One row of the main table: sizes, per-step times, speed-ups and errors."""
    any_row = result.rows[0]
    euclid, reduced, full = (result.row(m) or {} for m in ("euclidean", "reduced", "full"))
    r = reduced.get("r", euclid.get("r"))
    s = reduced.get("s", euclid.get("s"))
    return (
        f"| {result.scene} | {3 * any_row['n_vertices']} | {any_row['n_tets']} "
        f"| {any_row['example_vertices']} | {any_row['m']} | {_fmt(r, 'd')} | {_fmt(s, 'd')} "
        f"| {_fmt(euclid.get('t_interp_ms'))} | {_fmt(euclid.get('t_total_ms'))} "
        f"| {_fmt(reduced.get('t_interp_ms'))} | {_fmt(reduced.get('t_total_ms'))} "
        f"| {_fmt(_ratio(euclid.get('t_interp_ms'), reduced.get('t_interp_ms')), '.1f')}× "
        f"| {_fmt(_ratio(euclid.get('t_total_ms'), reduced.get('t_total_ms')), '.1f')}× "
        f"| {_fmt(full.get('t_total_ms'), '.2f')} "
        f"| {_fmt(reduced.get('error_vs_full'), '.2%')} "
        f"| {_fmt(euclid.get('error_vs_full'), '.2%')} |"
    )


def _spread_rows(result: SceneBenchmark) -> list[str]:
    """Median [min, max] of the per-step times of each method over the repeats."""
    rows = []
    for timing in result.timings:
        ti, tt = timing.summary("t_interp_ms"), timing.summary("t_total_ms")
        status = "yes" if timing.stable else f"no: {timing.message}"
        rows.append(
            f"| {result.scene} | {timing.method} | {len(timing.t_total_ms)} "
            f"| {ti['median']:.3f} [{ti['min']:.3f}, {ti['max']:.3f}] "
            f"| {tt['median']:.3f} [{tt['min']:.3f}, {tt['max']:.3f}] | {status} |"
        )
    return rows


#: how the conditions name each reduced force model
_FORCE_LABELS = {"polynomial": "exact polynomials (every element)", "cubature": "cubature"}


def _conditions(results: Sequence[SceneBenchmark], machine: dict) -> list[str]:
    """The run settings of each scene, the machine and its load."""
    lines = [
        f"- {result.scene}: dt = {result.dt:g} s, {result.steps} steps per run, "
        f"{result.repeats} repeats per method (methods interleaved), the first "
        f"{result.warmup} steps of each run left out of the per-step means; reduced "
        f"elastic force: {_FORCE_LABELS.get(result.force_model, result.force_model)}."
        for result in results
    ]
    return lines + [
        f"- Machine: {machine['cpu']}, {machine['cores']} cores, Python {machine['python']}, "
        f"numpy {machine['numpy']}; threads: {threads_text(machine)}; one process, wall clock.",
        f"- Load average (1, 5, 15 min) when written: {load_text(machine)} — other processes "
        "may have shared the cores; the min is the closest to an unloaded machine.",
    ]


def _verdict(label: str, value: float | None, met: bool, spec: str, unit: str) -> str:
    return f"{label}: {_fmt(value, spec)}{unit if value is not None else ''} " \
           f"**{'met' if met else 'NOT met'}**"


def _targets(result: SceneBenchmark) -> list[str]:
    """The verdicts on the targets (time per step, interpolation speed-up, error)."""
    reduced, euclid = result.row("reduced"), result.row("euclidean")
    if reduced is None:
        return []
    checks = [_verdict(f"reduced t_total ≤ {TARGET_T_TOTAL_MS:g} ms per step",
                       reduced["t_total_ms"], reduced["t_total_ms"] <= TARGET_T_TOTAL_MS,
                       ".3f", " ms")]
    if euclid is not None:
        speedup = _ratio(euclid["t_interp_ms"], reduced["t_interp_ms"])
        checks.append(_verdict(
            f"interpolation speed-up ≥ {TARGET_INTERP_SPEEDUP:g}×", speedup,
            speedup is not None and speedup >= TARGET_INTERP_SPEEDUP, ".1f", "×"))
    error = reduced["error_vs_full"]
    checks.append(_verdict(f"reduced error vs full ≤ {TARGET_ERROR:.0%}", error,
                           error is not None and error <= TARGET_ERROR, ".2%", ""))
    return [f"- {result.scene}: " + "; ".join(checks) + "."]


def _influence_rows(result: SceneBenchmark) -> list[str]:
    """The example influence of each method with its eq. 5 residuals (or why it is
    unavailable)."""
    return [
        f"| {result.scene} | {method} | unavailable: {stats['influence_message']} "
        "| — | — | — | — | — |" if stats.get("influence_message") else
        f"| {result.scene} | {method} | {stats['influence_frame']} "
        f"| {_fmt(stats['example_influence'])} "
        f"| {_fmt(stats['example_influence_max'])} | {_fmt(stats['example_influence_world'])} "
        f"| {_fmt(stats['example_residual'])} | {_fmt(stats['example_residual_none'])} |"
        for method, stats in result.influence
    ]


def _met(met: bool) -> str:
    return "yes" if met else "**no**"


def _free_body_cell(stats: dict | None) -> str:
    """``centre path / rotation / deformation`` of a free body's split error, else —."""
    if stats is None:
        return "—"
    return (f"{_fmt(stats['com_path_error'], '.2%')} / "
            f"{_fmt(stats['rotation_error_deg'], '.2f')}° / "
            f"{_fmt(stats['body_deformation_error'], '.2%')}")


def _setting_row(scene: str, setting: SettingResult) -> str:
    """One row of the settings comparison."""
    total = setting.t_total()
    time = ("—" if total is None else
            f"{total['median']:.3f} [{total['min']:.3f}, {total['max']:.3f}]")
    if not setting.timing.stable:
        time += f" (stopped: {setting.timing.message})"
    s = f"{setting.s} (every element)" if setting.forces == "polynomial" else f"{setting.s}"
    none = (_fmt(setting.error_vs_full_no_examples, ".2%") if setting.examples
            else "same run (no examples)")
    return (
        f"| {scene} | {setting.label} ({setting.source}) | {setting.m} | {setting.r} | {s} "
        f"| {setting.forces} | {time} | {_fmt(setting.error_vs_full, '.2%')} | {none} "
        f"| {_met(setting.meets_time())} | {_met(setting.meets_error())} "
        f"| {_free_body_cell(setting.free_body)} |"
    )


def _settings_lines(results: Sequence[SceneBenchmark]) -> list[str]:
    """The section "Paper settings vs lbshape settings" (empty when none was run)."""
    if not any(result.settings for result in results):
        return []
    lines = ["", "## Paper settings vs lbshape settings", "", _SETTINGS_INTRO, "",
             "| model | setting | m | r | s | forces | reduced ms/step median [min, max] "
             "| error, examples | error, no examples "
             f"| ≤ {TARGET_T_TOTAL_MS:g} ms | ≤ {SETTINGS_TARGET_ERROR:.0%} "
             "| free body: centre path / rotation / deformation |",
             "|---|" + "---|" * 11]
    return lines + [_setting_row(result.scene, setting)
                    for result in results for setting in result.settings]


def _free_body_rows(result: SceneBenchmark) -> list[str]:
    """The split error of each method but ``full`` (and of each setting) of a free body
    (none for a fixed one)."""
    runs = [(row["method"], row["error_vs_full"], {key: row[key] for key in ROW_EXTRA_KEYS})
            for row in result.rows
            if row["method"] != "full" and row.get("rotation_error_deg") is not None]
    for s in result.settings:
        runs.append((f"reduced, {s.label} setting, examples", s.error_vs_full, s.free_body))
        if s.examples:
            runs.append((f"reduced, {s.label} setting, no examples",
                         s.error_vs_full_no_examples, s.free_body_no_examples))
    return [
        f"| {result.scene} | {what} | {_fmt(error, '.2%')} "
        f"| {_fmt(stats['com_path_error'], '.2%')} | {_fmt(stats['rotation_error_deg'], '.2f')} "
        f"| {_fmt(stats['body_deformation_error'], '.2%')} |"
        for what, error, stats in runs if stats is not None
    ]


def _free_body_lines(results: Sequence[SceneBenchmark]) -> list[str]:
    """The section on free bodies' split errors (empty without a free body)."""
    rows = [row for result in results for row in _free_body_rows(result)]
    if not rows:
        return []
    return ["", "## Free bodies: rigid motion and deformation apart", "", _FREE_BODY_INTRO,
            "", "| model | run | error (whole field) | centre-of-mass path | rotation (°) "
            "| body-frame deformation |", "|---|---|---|---|---|---|", *rows]


_FREE_EVAL_INTRO = (
    "With `lbshape bench --free-eval`: each free body's whole-trajectory error beside the "
    "full reference's noise floor, the largest change of the reference's own trajectory "
    "when it is re-run with the throw ±1 %, the contact stiffness ±10 % and half the step "
    "(same norm; error / floor below about 1: inside what the reference does not "
    "determine); the error over the samples before the reference's first contact; the rest "
    "pose's symmetric Chamfer and Hausdorff distance between the final surfaces over the "
    "diagonal (blind to the object's symmetries). Per impact and in detail: "
    "`free_bodies.md`.")


def _free_eval_lines(results: Sequence[SceneBenchmark]) -> list[str]:
    """The free bodies' evaluation section (rows with a noise floor only)."""
    rows = [row for result in results for row in result.rows
            if row.get("noise_floor") is not None and row["method"] != "full"]
    if not rows:
        return []
    lines = ["", "## Free bodies: before contact, at rest, beside the reference's noise floor",
             "", _FREE_EVAL_INTRO, "",
             "| model | run | error (whole trajectory) | noise floor | error / floor | error "
             "before first contact | first contact (s) | rest pose Chamfer | rest pose "
             "Hausdorff |", "|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        lines.append(
            f"| {row['scene']} | {row['method']} | {_fmt(_pct(row['error_vs_full']), '')} | "
            f"{_fmt(_pct(row['noise_floor']), '')} | {_fmt(row['error_over_floor'], '.1f')} | "
            f"{_fmt(_pct(row['error_pre_contact']), '')} | {_fmt(row['first_contact_s'])} | "
            f"{_fmt(_pct(row['rest_pose_chamfer']), '')} | "
            f"{_fmt(_pct(row['rest_pose_hausdorff']), '')} |")
    return lines


def _pct(value: float | None) -> str | None:
    return None if value is None else f"{100 * value:.2f}%"


def table2_markdown(results: Sequence[SceneBenchmark], machine: dict) -> str:
    """The Markdown of ``table2.md`` (see :func:`write_table2`).

    Args:
        results: one benchmark per scene.
        machine: a :func:`~lbshape.io.machine.machine_description`.
    """
    lines = ["# Table 2: per-step cost and accuracy", "", _INTRO, "", _COLUMNS,
             "|---|" + "---|" * 15]
    lines += [_cost_row(result) for result in results]
    lines += ["", "## Spread of the per-step times (ms): median [min, max] over repeats", "",
              "| model | method | repeats | t_interp | t_total | stable |",
              "|---|---|---|---|---|---|"]
    lines += [row for result in results for row in _spread_rows(result)]
    lines += _settings_lines(results)
    lines += _free_body_lines(results)
    lines += _free_eval_lines(results)
    if any(result.influence for result in results):
        lines += ["", "## Example influence", "", _INFLUENCE_INTRO, "",
                  "| model | method | frame | influence at T | ratio of maxima over t "
                  "| world influence at T "
                  "| eq. 5 residual, examples | eq. 5 residual, no examples |",
                  "|---|---|---|---|---|---|---|---|"]
        lines += [row for result in results for row in _influence_rows(result)]
    lines += ["", "## Conditions", "", *_conditions(results, machine)]
    lines += ["", "## Targets (reported, not enforced)", ""]
    lines += [line for result in results for line in _targets(result)]
    lines += breakdown_lines(results)
    return "\n".join(lines) + "\n"


def table2_payload(results: Sequence[SceneBenchmark], machine: dict) -> dict:
    """The document of ``table2.json``: the contract rows plus spreads and conditions.

    ``paper_vs_lbshape``: per scene with the settings comparison, ``{"scene",
    "settings": [paper, lbshape]}``, each :meth:`~lbshape.studies.bench.SettingResult.payload`.
    """
    return {
        "rows": [row for result in results for row in result.rows],
        "timings": [
            {"scene": result.scene, "method": t.method, "repeats": len(t.t_total_ms),
             "t_interp_ms": t.summary("t_interp_ms"), "t_total_ms": t.summary("t_total_ms"),
             "stable": t.stable, "message": t.message, "phase_ms": t.phase_summary()}
            for result in results for t in result.timings
        ],
        "settings": [
            {"scene": result.scene, "dt": result.dt, "steps": result.steps,
             "repeats": result.repeats, "warmup_steps": result.warmup}
            for result in results
        ],
        "influence": [
            {"scene": result.scene, "method": method, **stats}
            for result in results for method, stats in result.influence
        ],
        "paper_vs_lbshape": settings_payload(results),
        "machine": machine,
    }


def settings_payload(results: Sequence[SceneBenchmark]) -> list[dict]:
    """``[{"scene", "settings": [paper, lbshape]}]`` of the scenes with the settings
    comparison (the ``paper_vs_lbshape`` of ``table2.json`` and ``lbshape bench --json``)."""
    return [{"scene": result.scene, "settings": [s.payload() for s in result.settings]}
            for result in results if result.settings]


def write_table2(results: Sequence[SceneBenchmark], out_dir: str | Path = DEFAULT_OUT
                 ) -> tuple[Path, Path]:
    """Write ``table2.md`` and ``table2.json`` to ``out_dir`` atomically; their paths."""
    if not results:
        raise LbshapeError("no benchmark results to write")
    out_dir = Path(out_dir)
    machine = machine_description()
    md = write_text_atomic(out_dir / "table2.md", table2_markdown(results, machine))
    js = write_json_atomic(out_dir / "table2.json", table2_payload(results, machine))
    return md, js


def sweep_csv(points: Sequence[SweepPoint], *, scene: str, steps: int, repeats: int,
              dt: float) -> str:
    """The text of ``speed_vs_error.csv`` (one comment line, a header, one row per point)."""
    machine = machine_description()
    text = io.StringIO()
    text.write(f"# scene {scene}, reduced method, dt = {dt:g} s, {steps} steps, median of "
               f"{repeats} runs; error vs full with the same m; {machine['cpu']}, "
               f"{threads_text(machine)}\n")
    fields = [f.name for f in dataclasses.fields(SweepPoint)]
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(fields)
    for point in points:
        writer.writerow(["" if v is None else (f"{v:.6g}" if isinstance(v, float) else v)
                         for v in dataclasses.astuple(point)])
    return text.getvalue()


def write_sweep(points: Sequence[SweepPoint], out_dir: str | Path = DEFAULT_OUT, *,
                scene: str, steps: int, repeats: int, dt: float) -> tuple[Path, Path]:
    """Write ``speed_vs_error.csv`` and ``.png`` to ``out_dir`` atomically; their paths."""
    if not points:
        raise LbshapeError("no sweep points to write")
    out_dir = Path(out_dir)
    csv_path = write_text_atomic(out_dir / "speed_vs_error.csv",
                                 sweep_csv(points, scene=scene, steps=steps, repeats=repeats,
                                           dt=dt))
    png_path = speed_error_plot(points, out_dir / "speed_vs_error.png", scene=scene,
                                steps=steps, dt=dt, target_error=TARGET_ERROR,
                                target_ms=TARGET_T_TOTAL_MS)
    return csv_path, png_path
