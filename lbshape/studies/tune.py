"""``lbshape tune``: the cheapest reduced settings (m, r, s, force model) whose error
against ``full`` is ≤ E within a per-step time budget.

:func:`tune_scene` runs the ``full`` reference once (the scene as written, its own
m), then tries candidates (m, r, s, forces) in increasing order of an a-priori cost
estimate (:func:`estimate`): each candidate is a precompute (built or loaded from the
cache) and ``repeats`` ``reduced`` runs; its per-step time is the median ``t_total_ms``
after the warm-up steps and its error the trajectory error against the reference,
``max_t ‖u(t) − u_full(t)‖_M / max_t ‖u_full(t)‖_M``.

The force model is a searched dimension (:func:`candidate_grid`): for StVK both
``polynomial`` (the exact reduced force over every element; s is not searched — it
only sizes the cubature trained beside the polynomials, and the scene's own s is kept)
and ``cubature`` (s weighted elements); other materials only have the cubature. The
default r values reach above the scene's r (:data:`R_FRACTIONS`), capped by the free
degrees of freedom of the mesh.

Candidates skipped without running (:func:`search`, the reason in the table's note):

* a candidate at least as large in m and r (and, for the cubature, s) as one of the
  same force model that already meets E cannot be cheaper;
* a ``polynomial`` candidate whose force product alone — P² multiply-adds, P =
  r(r+1)/2, at an optimistic :data:`POLYNOMIAL_RATE` per second, once per step — is
  above the budget (:func:`screen`), or whose coefficient build (7 t P², t elements)
  is above :data:`~lbshape.elastic.polynomial_forces.POLYNOMIAL_BUILD_FLOPS`, the
  largest that ``forces = "auto"`` builds.

The winner (:func:`select`) is the candidate with the smallest measured per-step
time among those with error ≤ E **and** per-step time ≤ the budget
(:data:`DEFAULT_BUDGET_MS` by default). When none qualifies, :func:`verdict_line`
says so plainly and names the closest candidate (the smallest
``max(error / E, time / budget)``).

:func:`write_tune` writes the winner as a scene file (the original TOML with the new
``[reduced]`` m, r, s and forces; relative mesh paths made absolute; the scene's name
kept so that its cached precompute is reused) beside a Markdown table of every
candidate.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import sys
import tomllib
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from lbshape.analysis.norms import trajectory_error
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.elastic.polynomial_forces import (
    FORCE_MODELS,
    POLYNOMIAL_BUILD_FLOPS,
    check_force_choice,
    polynomial_build_flops,
)
from lbshape.errors import LbshapeError
from lbshape.io.atomic import write_text_atomic
from lbshape.io.machine import load_text, machine_description, machine_text
from lbshape.io.paths import output_root
from lbshape.io.toml_writer import dumps
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import WARMUP_STEPS, force_elements, simulate
from lbshape.scene.variants import with_reduced

log = logging.getLogger(__name__)

#: default per-step time budget (ms): a reduced step must fit in it
DEFAULT_BUDGET_MS = 1.0
#: default candidate values as fractions of the scene's own r, s and m
R_FRACTIONS = (1 / 3, 1 / 2, 2 / 3, 1.0, 4 / 3, 5 / 3)
S_FRACTIONS = (1 / 2, 1.0, 2.0)
M_FRACTIONS = (1 / 2, 1.0)
#: an optimistic rate (multiply-adds per second) of the polynomial force product, for
#: skipping candidates whose product alone cannot fit in the budget
POLYNOMIAL_RATE = 1e10


def default_out() -> Path:
    """Tune's default folder: ``tune/`` under :func:`lbshape.io.paths.output_root`
    (``results/tune`` in the repository's root, else ``./lbshape-results/tune``)."""
    return output_root() / "tune"


class Candidate(NamedTuple):
    """One setting to try: m, r, s (cubature elements asked for; for ``polynomial``
    the scene's s, kept unchanged) and the force model."""

    m: int
    r: int
    s: int
    forces: str


@dataclass(frozen=True)
class Trial:
    """One candidate of the search.

    Attributes:
        m, r, s_max: the settings tried (s_max: cubature elements asked for; with the
            polynomial forces the scene's s, not searched).
        s: elements the reduced force sums over — the cubature's selected elements
            (training may stop at its tolerance first), every element with the
            polynomial forces (0 when not run).
        t_interp_ms, t_total_ms: per-step medians over the repeats (ms; None when not run).
        error_vs_full: trajectory error against the reference (None when not run or
            the run stopped).
        note: why it was not run or failed ('' when it ran).
        forces: the reduced force model (``"polynomial"`` or ``"cubature"``).
    """

    m: int
    r: int
    s_max: int
    s: int = 0
    t_interp_ms: float | None = None
    t_total_ms: float | None = None
    error_vs_full: float | None = None
    note: str = ""
    forces: str = "cubature"

    @property
    def candidate(self) -> Candidate:
        return Candidate(self.m, self.r, self.s_max, self.forces)

    def meets(self, error: float) -> bool:
        return self.error_vs_full is not None and self.error_vs_full <= error

    def within(self, budget_ms: float) -> bool:
        return self.t_total_ms is not None and self.t_total_ms <= budget_ms

    def qualifies(self, error: float, budget_ms: float) -> bool:
        """Error ≤ ``error`` and per-step time ≤ ``budget_ms``."""
        return self.meets(error) and self.within(budget_ms)

    def label(self) -> str:
        """``m=…, r=…, s=…, cubature`` (no s for the polynomial forces)."""
        s = "" if self.forces == "polynomial" else f", s={self.s_max}"
        return f"m={self.m}, r={self.r}{s}, {self.forces}"


def miss_factor(trial: Trial, *, error: float, budget_ms: float) -> float:
    """``max(error / E, time / budget)`` of a trial that ran (≤ 1: it qualifies)."""
    return max(trial.error_vs_full / error, trial.t_total_ms / budget_ms)


@dataclass(frozen=True)
class TuneResult:
    """The outcome of :func:`tune_scene`.

    Attributes:
        scene: scene name.
        error: the target E.
        steps, repeats: per run; runs per candidate.
        full_t_total_ms: per-step time of the ``full`` reference (ms).
        trials: every candidate, in the order tried.
        best: the cheapest candidate meeting E within the budget, or None.
        machine: the conditions of the timings (:func:`~lbshape.io.machine.machine_description`
            at the end of the search).
        budget_ms: the per-step time budget (ms).
    """

    scene: str
    error: float
    steps: int
    repeats: int
    full_t_total_ms: float
    trials: tuple[Trial, ...]
    best: Trial | None
    machine: dict = dataclasses.field(default_factory=dict)
    budget_ms: float = DEFAULT_BUDGET_MS

    @property
    def closest(self) -> Trial | None:
        """The finished candidate nearest to qualifying (smallest :func:`miss_factor`;
        None if no run finished)."""
        ran = [t for t in self.trials if t.error_vs_full is not None]
        return min(ran, key=lambda t: miss_factor(t, error=self.error, budget_ms=self.budget_ms),
                   default=None)


# ----------------------------------------------------------------------------- grid
def _fractions(value: int, fractions: Sequence[float], low: int,
               high: int | None = None) -> tuple[int, ...]:
    values = {max(low, int(round(value * f))) for f in fractions}
    if high is not None:
        values = {min(v, high) for v in values}
    return tuple(sorted(values))


def _check_values(name: str, values: Sequence[int]) -> None:
    bad = [v for v in values if isinstance(v, bool) or int(v) != v or v < 1]
    if bad:
        raise LbshapeError(f"{name} values must be integers >= 1, got {bad}")


def force_models(scene, forces: Sequence[str] | None = None) -> tuple[str, ...]:
    """The force models searched: ``forces`` (checked against the material), by default
    both for StVK and the cubature alone otherwise.

    Raises:
        LbshapeError: an unknown model, ``auto``, or ``polynomial`` for another material.
    """
    material = scene.material.model
    if not forces:
        return FORCE_MODELS if material == "stvk" else ("cubature",)
    for model in forces:
        if model not in FORCE_MODELS:
            raise LbshapeError(f"force models must be among {FORCE_MODELS}, got {model!r}")
        check_force_choice(model, material)
    return tuple(dict.fromkeys(forces))


def estimate(candidate: Candidate) -> float:
    """A-priori multiply-adds of one reduced step (orders the search): the force and
    tangent (``s r²`` for the cubature, ``P² + P r`` with P = r(r+1)/2 for the
    polynomials), the dense solve ``r³`` and the target ``9 m² r``."""
    m, r, s, forces = candidate
    if forces == "polynomial":
        pairs = r * (r + 1) // 2
        elastic = pairs * pairs + pairs * r
    else:
        elastic = s * r * r
    return float(elastic + r ** 3 + 9 * m * m * r)


def candidate_grid(scene, *, m_values: Sequence[int] | None = None,
                   r_values: Sequence[int] | None = None,
                   s_values: Sequence[int] | None = None,
                   forces: Sequence[str] | None = None,
                   max_r: int | None = None) -> list[Candidate]:
    """The candidates, cheapest :func:`estimate` first.

    Defaults are fractions of the scene's own values (:data:`R_FRACTIONS`,
    :data:`S_FRACTIONS`, :data:`M_FRACTIONS`); m is the scene's alone without examples
    (it changes nothing there); the force models are :func:`force_models`. Every
    (m, r, s) is a ``cubature`` candidate and every (m, r) one ``polynomial`` candidate
    at the scene's s (s is not searched for the polynomials).

    Args:
        max_r: the largest default r (the mesh's free degrees of freedom); given r
            values are not capped.

    Raises:
        LbshapeError: a value < 1, an empty list or a bad force model.
    """
    red = scene.reduced
    m_values = (tuple(m_values) if m_values else
                _fractions(red.m, M_FRACTIONS, 2) if scene.has_examples else (red.m,))
    r_values = tuple(r_values) if r_values else _fractions(red.r, R_FRACTIONS, 2, max_r)
    s_values = tuple(s_values) if s_values else _fractions(red.s, S_FRACTIONS, 1)
    for name, values in (("m", m_values), ("r", r_values), ("s", s_values)):
        _check_values(name, values)
    models = force_models(scene, forces)
    grid: set[Candidate] = set()
    for model in models:
        for m in m_values:
            for r in r_values:
                if model == "polynomial":
                    grid.add(Candidate(int(m), int(r), int(red.s), model))
                else:
                    grid.update(Candidate(int(m), int(r), int(s), model) for s in s_values)
    return sorted(grid, key=lambda c: (estimate(c), c))


# ----------------------------------------------------------------------------- search
def _dominates(candidate: Candidate, trial: Trial) -> bool:
    """``candidate`` is at least as large as ``trial`` (same force model; s counts for
    the cubature only)."""
    m, r, s, forces = candidate
    return (forces == trial.forces and m >= trial.m and r >= trial.r
            and (forces == "polynomial" or s >= trial.s_max))


def screen(candidate: Candidate, *, budget_ms: float, n_tets: int | None = None) -> str:
    """Why ``candidate`` is skipped a priori ('' when it is run): see the module docstring
    (polynomial candidates only)."""
    if candidate.forces != "polynomial":
        return ""
    pairs = candidate.r * (candidate.r + 1) // 2
    floor_ms = 1e3 * pairs * pairs / POLYNOMIAL_RATE
    if floor_ms > budget_ms:
        return (f"skipped: the force product alone (P² = {pairs * pairs:.3g} multiply-adds "
                f"at {POLYNOMIAL_RATE:.0e}/s) takes {floor_ms:.3g} ms > the budget")
    if n_tets is not None:
        build = polynomial_build_flops(n_tets, candidate.r)
        if build > POLYNOMIAL_BUILD_FLOPS:
            return (f"skipped: building the polynomials (7 t P² = {build:.3g} multiply-adds) "
                    f"is above what forces = 'auto' builds ({POLYNOMIAL_BUILD_FLOPS:.0e})")
    return ""


def select(trials: Sequence[Trial], *, error: float, budget_ms: float) -> Trial | None:
    """The qualifying trial (error ≤ E, time ≤ budget) with the smallest per-step time."""
    good = [t for t in trials if t.qualifies(error, budget_ms)]
    return min(good, key=lambda t: t.t_total_ms) if good else None


def search(candidates: Iterable[Candidate], measure: Callable[[Candidate], Trial], *,
           error: float, budget_ms: float,
           skip: Callable[[Candidate], str] | None = None
           ) -> tuple[tuple[Trial, ...], Trial | None]:
    """Try ``candidates`` in order: skip the dominated ones and those ``skip`` names a
    reason for, ``measure`` the others; the trials and the winner (:func:`select`).

    Args:
        candidates: cheapest estimate first (:func:`candidate_grid`).
        measure: runs one candidate, returns its :class:`Trial`.
        error, budget_ms: the targets.
        skip: a-priori reason to skip a candidate ('' to run it), e.g. :func:`screen`.
    """
    trials: list[Trial] = []
    for candidate in candidates:
        candidate = Candidate(*candidate)
        passed = next((t for t in trials if t.meets(error) and _dominates(candidate, t)),
                      None)
        note = (f"skipped: not cheaper than {passed.label()}" if passed is not None
                else skip(candidate) if skip is not None else "")
        if note:
            trials.append(Trial(candidate.m, candidate.r, candidate.s, note=note,
                                forces=candidate.forces))
            continue
        trials.append(measure(candidate))
        log.info("tune: %s", trials[-1])
    return tuple(trials), select(trials, error=error, budget_ms=budget_ms)


def _check_budget(budget_ms) -> float:
    if not (isinstance(budget_ms, int | float) and not isinstance(budget_ms, bool)
            and math.isfinite(budget_ms) and budget_ms > 0):
        raise LbshapeError(f"the per-step time budget must be a number of ms > 0, "
                           f"got {budget_ms}")
    return float(budget_ms)


def tune_scene(scene, *, error: float, budget_ms: float = DEFAULT_BUDGET_MS,
               m_values: Sequence[int] | None = None,
               r_values: Sequence[int] | None = None, s_values: Sequence[int] | None = None,
               forces: Sequence[str] | None = None,
               steps: int | None = None, repeats: int = 3,
               progress: bool = False) -> TuneResult:
    """Search (m, r, s, forces) for the cheapest per-step time with error ≤ ``error`` and
    per-step time ≤ ``budget_ms`` (module docstring).

    Args:
        scene: the scene (its own m, r, s define the ``full`` reference's shape space).
        error: the target E (dimensionless, e.g. 0.05 for 5 %).
        budget_ms: the largest per-step time (ms) of the winner.
        m_values, r_values, s_values, forces: candidate values (default: see
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
    budget_ms = _check_budget(budget_ms)
    steps = scene.simulation.steps if steps is None else steps
    if isinstance(steps, bool) or int(steps) != steps or steps <= WARMUP_STEPS:
        raise LbshapeError(f"steps must be an integer > {WARMUP_STEPS} (the warm-up steps), "
                           f"got {steps}")
    if isinstance(repeats, bool) or int(repeats) != repeats or repeats < 1:
        raise LbshapeError(f"repeats must be an integer >= 1, got {repeats}")
    steps, repeats = int(steps), int(repeats)
    options = {"m_values": m_values, "r_values": r_values, "s_values": s_values,
               "forces": forces}
    candidate_grid(scene, **options)  # bad values fail before any work
    base = precompute(scene, progress=progress)
    free_dofs = 3 * (base.mesh.n_vertices - int(base.fixed_vertices.size))
    grid = candidate_grid(scene, **options,
                          max_r=free_dofs if base.fixed_vertices.size else free_dofs - 6)
    reference = simulate(scene, base, method="full", steps=steps)
    if reference.message:
        raise LbshapeError(f"the full reference run of {scene.name} stopped: "
                           f"{reference.message}")
    mass = mass_matrix(base.mesh, base.material.density)

    def measure(candidate: Candidate) -> Trial:
        return _trial(with_reduced(scene, *candidate), reference, mass, steps=steps,
                      repeats=repeats)

    def skip(candidate: Candidate) -> str:
        return screen(candidate, budget_ms=budget_ms, n_tets=base.mesh.n_tets)

    trials, best = search(
        tqdm(grid, desc=f"tune {scene.name}", disable=not progress, file=sys.stderr),
        measure, error=error, budget_ms=budget_ms, skip=skip)
    return TuneResult(scene.name, float(error), steps, repeats,
                      float(reference.stats["t_total_ms"]), trials, best,
                      machine_description(), budget_ms)


def _trial(variant, reference, mass, *, steps: int, repeats: int) -> Trial:
    red = variant.reduced
    forces = red.forces
    try:
        pre = precompute(variant)
    except LbshapeError as exc:
        return Trial(red.m, red.r, red.s, note=f"invalid: {exc}", forces=forces)
    runs = [simulate(variant, pre, method="reduced", steps=steps) for _ in range(repeats)]
    s = force_elements(pre)
    t_interp = float(np.median([run.stats["t_interp_ms"] for run in runs]))
    t_total = float(np.median([run.stats["t_total_ms"] for run in runs]))
    if runs[0].message:
        return Trial(red.m, red.r, red.s, s, t_interp, t_total,
                     note=f"stopped: {runs[0].message}", forces=pre.elastic.force_model)
    err = trajectory_error(runs[0].displacements, reference.displacements, mass,
                           times=runs[0].times, times_full=reference.times)
    return Trial(red.m, red.r, red.s, s, t_interp, t_total, float(err),
                 forces=pre.elastic.force_model)


# ----------------------------------------------------------------------------- output
def _fmt(value, spec: str) -> str:
    return "—" if value is None else format(value, spec)


def _percent(value: float) -> str:
    return f"{100 * value:.3g}%"


def target_text(error: float, budget_ms: float) -> str:
    """``error ≤ 5% within 1 ms per step``."""
    return f"error ≤ {_percent(error)} within {budget_ms:g} ms per step"


def verdict_line(result: TuneResult) -> str:
    """One plain line: the winner, or that no candidate qualifies and the closest."""
    target = target_text(result.error, result.budget_ms)
    if result.best is not None:
        b = result.best
        return (f"chosen: {b.label()}: {b.t_total_ms:.3f} ms per step, error "
                f"{b.error_vs_full:.2%} (meets {target})")
    closest = result.closest
    if closest is None:
        return f"no candidate meets {target}; closest: none (no run finished)"
    over = []
    if closest.error_vs_full > result.error:
        over.append(f"error {closest.error_vs_full / result.error:.2f}× the target")
    if closest.t_total_ms > result.budget_ms:
        over.append(f"time {closest.t_total_ms / result.budget_ms:.2f}× the budget")
    return (f"no candidate meets {target}; closest: {closest.label()}: "
            f"{closest.t_total_ms:.3f} ms per step, error {closest.error_vs_full:.2%} "
            f"({', '.join(over)})")


def tune_markdown(result: TuneResult) -> str:
    """The table of every candidate tried, with the choice and the conditions."""
    verdict = verdict_line(result)
    lines = [
        f"# Tuning {result.scene}: cheapest (m, r, s, forces) with "
        f"{target_text(result.error, result.budget_ms)}",
        "",
        f"{result.steps} steps per run, {result.repeats} reduced run(s) per candidate; "
        f"per-step times are medians after {WARMUP_STEPS} warm-up steps (ms, wall clock); "
        "error: `max_t ‖u(t) − u_full(t)‖_M / max_t ‖u_full(t)‖_M` against the full-space "
        f"run of the scene as written ({result.full_t_total_ms:.3f} ms per step). "
        f"The winner: the smallest measured t_total among the candidates with error ≤ E "
        f"and t_total ≤ {result.budget_ms:g} ms. Force models: `polynomial` (the exact "
        "StVK forces over every element: s is the element count; s asked is the scene's, "
        "kept for the cubature trained beside them, not searched) and `cubature` (s "
        "weighted elements). Skipped without running: a candidate at least as large in m "
        "and r (cubature: and s) as one of the same force model that already met E; a "
        "polynomial candidate whose force product alone (P² multiply-adds, P = r(r+1)/2, "
        f"at an optimistic {POLYNOMIAL_RATE:.0e} per second) is above the budget, or whose "
        f"build (7 t P²) is above {POLYNOMIAL_BUILD_FLOPS:.0e}, what forces = 'auto' builds.",
        "",
        *([f"Machine: {machine_text(result.machine)}; load average (1, 5, 15 min) at the end: "
           f"{load_text(result.machine)}.", ""] if result.machine else []),
        f"**{verdict[0].upper()}{verdict[1:]}.**",
        "",
        "| forces | m | r | s asked | s | t_interp (ms) | t_total (ms) | error vs full "
        "| ≤ E | ≤ budget | note |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for t in result.trials:
        chosen = " **chosen**" if t is result.best else ""
        polynomial = t.forces == "polynomial"
        s_asked = f"— ({t.s_max})" if polynomial else str(t.s_max)
        s = "—" if not t.s else f"{t.s} (all)" if polynomial else str(t.s)
        ran = t.t_total_ms is not None
        lines.append(
            f"| {t.forces} | {t.m} | {t.r} | {s_asked} | {s} | {_fmt(t.t_interp_ms, '.3f')} "
            f"| {_fmt(t.t_total_ms, '.3f')} | {_fmt(t.error_vs_full, '.2%')} "
            f"| {'yes' if t.meets(result.error) else 'no' if t.error_vs_full is not None else '—'} "
            f"| {('yes' if t.within(result.budget_ms) else 'no') if ran else '—'} "
            f"| {t.note}{chosen} |")
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


def tuned_scene_text(scene, trial: Trial, *, error: float,
                     budget_ms: float = DEFAULT_BUDGET_MS) -> str:
    """The scene's TOML with ``[reduced]`` m, r, s and forces of ``trial`` (see the module
    docstring)."""
    if scene.source is None:
        raise LbshapeError(f"scene {scene.name} has no source file to write a tuned copy of")
    source = Path(scene.source)
    try:
        data = tomllib.loads(source.read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise LbshapeError(f"cannot re-read the scene file {source.name}: {exc}") from None
    data = _absolute_paths(data, source.parent)
    reduced = dict(data.get("reduced", {}))
    reduced.update(m=trial.m, r=trial.r, s=trial.s_max, forces=trial.forces)
    if reduced.get("linear_modes", 0) > trial.r:
        del reduced["linear_modes"]
    data["name"] = scene.name
    data["reduced"] = reduced
    header = (f"# {scene.name} tuned: the cheapest (m, r, s, forces) tried whose error vs full "
              f"is <= {error:.3g} within {budget_ms:g} ms per step\n# ({trial.label()}: "
              f"{trial.t_total_ms:.3f} ms per step, error {trial.error_vs_full:.2%}).\n")
    return header + dumps({"name": data.pop("name"), **data})


def write_tune(result: TuneResult, scene, out_dir: str | Path) -> tuple[Path | None, Path]:
    """``SCENE-tuned.toml`` (when a candidate qualifies) and ``SCENE-tune.md`` in ``out_dir``.

    Returns:
        ``(scene file or None, table)``.
    """
    out_dir = Path(out_dir)
    text = (tuned_scene_text(scene, result.best, error=result.error,
                             budget_ms=result.budget_ms) if result.best else None)
    table = write_text_atomic(out_dir / f"{scene.name}-tune.md", tune_markdown(result))
    toml = write_text_atomic(out_dir / f"{scene.name}-tuned.toml", text) if text else None
    return toml, table
