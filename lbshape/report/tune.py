"""``lbshape tune``: the cheapest reduced settings (m, r, s) whose error against ``full`` is ≤ E.

:func:`tune_scene` runs the ``full`` reference once (the scene as written, its own
m), then tries candidate (m, r, s) in increasing order of an a-priori cost estimate:
each candidate is a precompute (built or loaded from the cache) and ``repeats``
``reduced`` runs; its per-step time is the median ``t_total_ms`` after the warm-up
steps and its error the trajectory error against the reference,
``max_t ‖u(t) − u_full(t)‖_M / max_t ‖u_full(t)‖_M``. A candidate at least as large in
all of m, r and s as one that already meets E cannot be cheaper and is skipped
without running. Among the candidates that meet E the one with the smallest measured
per-step time wins.

:func:`write_tune` writes the winner as a scene file (the original TOML with the new
``[reduced]`` m, r, s; relative mesh paths made absolute; the scene's name kept so
that its cached precompute is reused) beside a Markdown table of every candidate.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import sys
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lbshape.elastic.element_kernels import mass_matrix
from lbshape.errors import LbshapeError
from lbshape.io.atomic import write_text_atomic
from lbshape.io.paths import RESULTS_DIR
from lbshape.io.toml_writer import dumps
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import WARMUP_STEPS, simulate
from lbshape.report.bench import trajectory_error
from lbshape.report.machine import load_text, machine_description, machine_text

log = logging.getLogger(__name__)

#: repository-relative default output folder
DEFAULT_OUT = RESULTS_DIR / "tune"
#: default candidate values as fractions of the scene's own r, s and m
R_FRACTIONS = (1 / 3, 1 / 2, 2 / 3, 1.0)
S_FRACTIONS = (1 / 2, 1.0, 2.0)
M_FRACTIONS = (1 / 2, 1.0)


@dataclass(frozen=True)
class Trial:
    """One candidate of the search.

    Attributes:
        m, r, s_max: the settings tried (s_max: cubature elements asked for).
        s: cubature elements selected (training may stop at its tolerance first; 0
            when not run).
        t_interp_ms, t_total_ms: per-step medians over the repeats (ms; None when not run).
        error_vs_full: trajectory error against the reference (None when not run or
            the run stopped).
        note: why it was not run or failed ('' when it ran).
    """

    m: int
    r: int
    s_max: int
    s: int = 0
    t_interp_ms: float | None = None
    t_total_ms: float | None = None
    error_vs_full: float | None = None
    note: str = ""

    def meets(self, error: float) -> bool:
        return self.error_vs_full is not None and self.error_vs_full <= error


@dataclass(frozen=True)
class TuneResult:
    """The outcome of :func:`tune_scene`.

    Attributes:
        scene: scene name.
        error: the target E.
        steps, repeats: per run; runs per candidate.
        full_t_total_ms: per-step time of the ``full`` reference (ms).
        trials: every candidate, in the order tried.
        best: the cheapest candidate meeting E, or None.
        machine: the conditions of the timings (:func:`~lbshape.report.machine.machine_description`
            at the end of the search).
    """

    scene: str
    error: float
    steps: int
    repeats: int
    full_t_total_ms: float
    trials: tuple[Trial, ...]
    best: Trial | None
    machine: dict = dataclasses.field(default_factory=dict)

    @property
    def closest(self) -> Trial | None:
        """The candidate with the smallest error (None if no run finished)."""
        ran = [t for t in self.trials if t.error_vs_full is not None]
        return min(ran, key=lambda t: t.error_vs_full) if ran else None


def _fractions(value: int, fractions: Sequence[float], low: int) -> tuple[int, ...]:
    return tuple(sorted({max(low, int(round(value * f))) for f in fractions}))


def candidate_grid(scene, *, m_values: Sequence[int] | None = None,
                   r_values: Sequence[int] | None = None,
                   s_values: Sequence[int] | None = None) -> list[tuple[int, int, int]]:
    """The (m, r, s) candidates, cheapest estimate first.

    Defaults are fractions of the scene's own values (:data:`R_FRACTIONS`,
    :data:`S_FRACTIONS`, :data:`M_FRACTIONS`); m is the scene's alone without examples
    (it changes nothing there). The estimate of a reduced step's cost is
    ``s r² + r³ + 9 m² r`` (cubature force and tangent, the dense solve, the target).

    Raises:
        LbshapeError: a value < 1 or an empty list.
    """
    red = scene.reduced
    m_values = (tuple(m_values) if m_values else
                _fractions(red.m, M_FRACTIONS, 2) if scene.has_examples else (red.m,))
    r_values = tuple(r_values) if r_values else _fractions(red.r, R_FRACTIONS, 2)
    s_values = tuple(s_values) if s_values else _fractions(red.s, S_FRACTIONS, 1)
    for name, values in (("m", m_values), ("r", r_values), ("s", s_values)):
        bad = [v for v in values if isinstance(v, bool) or int(v) != v or v < 1]
        if bad:
            raise LbshapeError(f"{name} values must be integers >= 1, got {bad}")
    grid = {(int(m), int(r), int(s)) for m in m_values for r in r_values for s in s_values}
    return sorted(grid, key=lambda c: (c[2] * c[1] ** 2 + c[1] ** 3 + 9 * c[0] ** 2 * c[1], c))


def _variant(scene, m: int, r: int, s: int):
    red = scene.reduced
    linear = red.linear_modes if red.linear_modes <= r else 0
    return dataclasses.replace(scene, reduced=dataclasses.replace(
        red, m=m, r=r, s=s, linear_modes=linear))


def _dominates(candidate: tuple[int, int, int], trial: Trial) -> bool:
    m, r, s = candidate
    return m >= trial.m and r >= trial.r and s >= trial.s_max


def tune_scene(scene, *, error: float, m_values: Sequence[int] | None = None,
               r_values: Sequence[int] | None = None, s_values: Sequence[int] | None = None,
               steps: int | None = None, repeats: int = 3,
               progress: bool = False) -> TuneResult:
    """Search (m, r, s) for the cheapest per-step time with error ≤ ``error`` (module docstring).

    Args:
        scene: the scene (its own m, r, s define the ``full`` reference's shape space).
        error: the target E (dimensionless, e.g. 0.05 for 5 %).
        m_values, r_values, s_values: candidate values (default: see
            :func:`candidate_grid`).
        steps: steps per run (default: the scene's), > the warm-up steps.
        repeats: ``reduced`` runs per candidate (per-step time: their median).
        progress: a progress bar over the candidates on stderr.

    Raises:
        LbshapeError: bad arguments, or a ``full`` reference that stopped or never moves.
    """
    from tqdm import tqdm

    if not (isinstance(error, int | float) and math.isfinite(error) and error > 0):
        raise LbshapeError(f"the error target must be a number > 0, got {error}")
    steps = scene.simulation.steps if steps is None else steps
    if isinstance(steps, bool) or int(steps) != steps or steps <= WARMUP_STEPS:
        raise LbshapeError(f"steps must be an integer > {WARMUP_STEPS} (the warm-up steps), "
                           f"got {steps}")
    if isinstance(repeats, bool) or int(repeats) != repeats or repeats < 1:
        raise LbshapeError(f"repeats must be an integer >= 1, got {repeats}")
    steps, repeats = int(steps), int(repeats)
    grid = candidate_grid(scene, m_values=m_values, r_values=r_values, s_values=s_values)
    base = precompute(scene, progress=progress)
    reference = simulate(scene, base, method="full", steps=steps)
    if reference.message:
        raise LbshapeError(f"the full reference run of {scene.name} stopped: "
                           f"{reference.message}")
    mass = mass_matrix(base.mesh, base.material.density)
    trials: list[Trial] = []
    for m, r, s in tqdm(grid, desc=f"tune {scene.name}", disable=not progress, file=sys.stderr):
        passed = next((t for t in trials if t.meets(error) and _dominates((m, r, s), t)), None)
        if passed is not None:
            trials.append(Trial(m, r, s, note=f"skipped: not cheaper than m={passed.m}, "
                                              f"r={passed.r}, s={passed.s_max}"))
            continue
        trials.append(_trial(_variant(scene, m, r, s), reference, mass, steps=steps,
                             repeats=repeats))
        log.info("tune %s: %s", scene.name, trials[-1])
    meeting = [t for t in trials if t.meets(error)]
    best = min(meeting, key=lambda t: t.t_total_ms) if meeting else None
    return TuneResult(scene.name, float(error), steps, repeats,
                      float(reference.stats["t_total_ms"]), tuple(trials), best,
                      machine_description())


def _trial(variant, reference, mass, *, steps: int, repeats: int) -> Trial:
    red = variant.reduced
    try:
        pre = precompute(variant)
    except LbshapeError as exc:
        return Trial(red.m, red.r, red.s, note=f"invalid: {exc}")
    runs = [simulate(variant, pre, method="reduced", steps=steps) for _ in range(repeats)]
    s = int(pre.cubature_elements.size)
    t_interp = float(np.median([run.stats["t_interp_ms"] for run in runs]))
    t_total = float(np.median([run.stats["t_total_ms"] for run in runs]))
    if runs[0].message:
        return Trial(red.m, red.r, red.s, s, t_interp, t_total,
                     note=f"stopped: {runs[0].message}")
    err = trajectory_error(runs[0].displacements, reference.displacements, mass,
                           times=runs[0].times, times_full=reference.times)
    return Trial(red.m, red.r, red.s, s, t_interp, t_total, float(err))


# ----------------------------------------------------------------------------- output
def _fmt(value, spec: str) -> str:
    return "—" if value is None else format(value, spec)


def tune_markdown(result: TuneResult) -> str:
    """The table of every candidate tried, with the choice and the conditions."""
    lines = [
        f"# Tuning {result.scene}: cheapest (m, r, s) with error vs full ≤ {result.error:.3g}",
        "",
        f"{result.steps} steps per run, {result.repeats} reduced run(s) per candidate; "
        f"per-step times are medians after {WARMUP_STEPS} warm-up steps (ms, wall clock); "
        "error: `max_t ‖u(t) − u_full(t)‖_M / max_t ‖u_full(t)‖_M` against the full-space "
        f"run of the scene as written ({result.full_t_total_ms:.3f} ms per step).",
        "",
        *([f"Machine: {machine_text(result.machine)}; load average (1, 5, 15 min) at the end: "
           f"{load_text(result.machine)}.", ""] if result.machine else []),
        "| m | r | s asked | s | t_interp (ms) | t_total (ms) | error vs full | ≤ E | note |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for t in result.trials:
        chosen = " **chosen**" if t is result.best else ""
        lines.append(
            f"| {t.m} | {t.r} | {t.s_max} | {t.s or '—'} | {_fmt(t.t_interp_ms, '.3f')} "
            f"| {_fmt(t.t_total_ms, '.3f')} | {_fmt(t.error_vs_full, '.2%')} "
            f"| {'yes' if t.meets(result.error) else 'no'} | {t.note}{chosen} |")
    lines.append("")
    if result.best is not None:
        b = result.best
        lines.append(f"Chosen: m={b.m}, r={b.r}, s={b.s_max} ({b.t_total_ms:.3f} ms per step, "
                     f"error {b.error_vs_full:.2%}).")
    else:
        closest = result.closest
        lines.append("No candidate meets the target" + (
            "." if closest is None else
            f"; the smallest error was {closest.error_vs_full:.2%} (m={closest.m}, "
            f"r={closest.r}, s={closest.s_max})."))
    return "\n".join(lines) + "\n"


def _absolute_paths(value, base: Path):
    """Relative strings naming existing files under ``base`` made absolute (recursively)."""
    if isinstance(value, dict):
        return {k: _absolute_paths(v, base) for k, v in value.items()}
    if isinstance(value, list):
        return [_absolute_paths(v, base) for v in value]
    if isinstance(value, str) and value and not Path(value).is_absolute():
        try:
            candidate = base / value
            if candidate.is_file():
                return str(candidate.resolve())
        except OSError:
            pass
    return value


def tuned_scene_text(scene, trial: Trial, *, error: float) -> str:
    """The scene's TOML with ``[reduced]`` m, r, s of ``trial`` (see the module docstring)."""
    if scene.source is None:
        raise LbshapeError(f"scene {scene.name} has no source file to write a tuned copy of")
    source = Path(scene.source)
    try:
        data = tomllib.loads(source.read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise LbshapeError(f"cannot re-read the scene file {source.name}: {exc}") from None
    data = _absolute_paths(data, source.parent)
    reduced = dict(data.get("reduced", {}))
    reduced.update(m=trial.m, r=trial.r, s=trial.s_max)
    if reduced.get("linear_modes", 0) > trial.r:
        del reduced["linear_modes"]
    data["name"] = scene.name
    data["reduced"] = reduced
    header = (f"# {scene.name} tuned: the cheapest (m, r, s) tried whose error vs full is "
              f"<= {error:.3g}\n# (m={trial.m}, r={trial.r}, s={trial.s_max}: "
              f"{trial.t_total_ms:.3f} ms per step, error {trial.error_vs_full:.2%}).\n")
    return header + dumps({"name": data.pop("name"), **data})


def write_tune(result: TuneResult, scene, out_dir: str | Path) -> tuple[Path | None, Path]:
    """``SCENE-tuned.toml`` (when a candidate meets E) and ``SCENE-tune.md`` in ``out_dir``.

    Returns:
        ``(scene file or None, table)``.
    """
    out_dir = Path(out_dir)
    text = tuned_scene_text(scene, result.best, error=result.error) if result.best else None
    table = write_text_atomic(out_dir / f"{scene.name}-tune.md", tune_markdown(result))
    toml = write_text_atomic(out_dir / f"{scene.name}-tuned.toml", text) if text else None
    return toml, table
