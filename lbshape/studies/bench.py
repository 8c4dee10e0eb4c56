"""Speed against accuracy: measuring the methods side by side (the paper's Table 2).

The error of a run against ``full`` is :func:`lbshape.analysis.norms.trajectory_error`,
``max_t ‖u(t) − u_full(t)‖_M / max_t ‖u_full(t)‖_M`` with M the consistent elastic mass
(kg), over the same sample times, computed by :func:`lbshape.pipeline.simulate.run_error`
(the one path ``lbshape simulate --compare full`` uses too).

* :func:`bench_scene` — ``full``, ``euclidean`` and ``reduced`` runs of one scene in
  one process, repeated (interleaved, so that load from other processes spreads
  evenly over the methods); per-step times are the means after the simulation's
  warm-up steps (:data:`lbshape.pipeline.simulate.WARMUP_STEPS`), summarised by the median
  and the range over repeats; the error of each method against ``full``;
* the settings comparison of :func:`bench_scene` (``paper=``): the reduced method at
  the paper's (m, r, s) with its cubature forces (:func:`paper_setting`) beside the
  scene as written, both timed in the same interleaved repeats, each with its error
  against ``full`` with and without the scene's examples (:class:`SettingResult`);
* free bodies: beside the whole-field error, the centre-of-mass path, the rotation
  and the body-frame deformation errors (:mod:`lbshape.analysis.free_body`); with
  ``free_eval`` also the error before the first contact, the rest pose's symmetric
  surface distance and the reference's noise floor (:mod:`lbshape.studies.free_bodies`);
* the speed/error sweep over r, s (and m) is :mod:`lbshape.studies.sweep`.

Timings are wall clock. The tables are written by :mod:`lbshape.studies.tables`, the
plots drawn by :mod:`lbshape.report.plots`, the machine described by
:mod:`lbshape.io.machine`.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from lbshape.analysis.free_body import KEYS as FREE_BODY_KEYS
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.errors import LbshapeError
from lbshape.io.paths import RESULTS_DIR
from lbshape.pipeline.influence import STATS_KEYS, has_example_force, is_free_body
from lbshape.pipeline.meshes import build_mesh
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import (
    METHODS,
    WARMUP_STEPS,
    example_influence,
    run_error,
    simulate,
)
from lbshape.scene.variants import with_reduced, without_examples
from lbshape.studies.free_bodies import KEYS as FREE_EVAL_KEYS
from lbshape.studies.free_bodies import noise_floor, whole_run

log = logging.getLogger(__name__)

#: the keys of one ``lbshape bench --json`` row, in contract order
ROW_KEYS: tuple[str, ...] = (
    "scene", "method", "n_vertices", "n_tets", "example_vertices", "m", "r", "s",
    "t_interp_ms", "t_total_ms", "error_vs_full",
)
#: the keys every row has after :data:`ROW_KEYS`: a free body's error split into its
#: centre-of-mass path, rotation (degrees) and body-frame deformation
#: (:mod:`lbshape.analysis.free_body`; None for a fixed object)
ROW_EXTRA_KEYS: tuple[str, ...] = FREE_BODY_KEYS
#: the keys every row has after :data:`ROW_EXTRA_KEYS`: a free body's evaluation with
#: ``free_eval`` (:data:`lbshape.studies.free_bodies.KEYS`: error before the first contact,
#: its time, the rest pose's symmetric surface distances, the reference's noise floor and
#: the error over it; None for a fixed object or without ``free_eval``)
ROW_FREE_EVAL_KEYS: tuple[str, ...] = FREE_EVAL_KEYS
#: scenes benchmarked by default (the paper's first two Table 2 rows)
DEFAULT_SCENES: tuple[str, ...] = ("bar-cuboid", "bar-cylinder")
#: methods benchmarked by default
DEFAULT_METHODS: tuple[str, ...] = ("full", "euclidean", "reduced")
#: repository-relative default output folder
DEFAULT_OUT = RESULTS_DIR
#: the targets Table 2 reports against (never asserted)
TARGET_T_TOTAL_MS = 1.0
TARGET_INTERP_SPEEDUP = 20.0
TARGET_ERROR = 0.10
#: the error the settings comparison checks each setting against (never asserted)
SETTINGS_TARGET_ERROR = 0.05
#: how a setting's (m, r, s) were chosen
PAPER_SOURCE = "paper's Table 2 m, r, s, cubature"
SCENE_SOURCE = "scene's m, r, s, cubature"
LBSHAPE_SOURCE = "the scene as written"


# ----------------------------------------------------------------------------- error


# ------------------------------------------------------------------------ benchmark
@dataclass(frozen=True)
class MethodTiming:
    """Per-step times of one method over the repeats.

    Attributes:
        method: ``full``, ``euclidean`` or ``reduced``.
        t_interp_ms: (repeats,) per-step mean interpolation time of each run (ms).
        t_total_ms: (repeats,) per-step mean total time of each run (ms).
        stable: False if a run stopped on a solver failure.
        message: the failure message ('' if stable).
        phase_ms: reduced methods: per repeat, the median time per step of each part of
            the step (ms; the one phase record,
            :func:`~lbshape.pipeline.simulate.phase_medians`: a fixed object's
            :data:`~lbshape.dynamics.reduced.PHASES`, a free body's
            :data:`~lbshape.dynamics.free_body.PHASES`).
        step_median_ms: (repeats,) per run, the median wall time of a step after the
            warm-up (ms).
    """

    method: str
    t_interp_ms: tuple[float, ...]
    t_total_ms: tuple[float, ...]
    stable: bool
    message: str = ""
    phase_ms: tuple[dict, ...] = ()
    step_median_ms: tuple[float, ...] = ()

    def phase_summary(self) -> dict | None:
        """Per part of the step, the median over the repeats (ms); None without phases."""
        if not self.phase_ms:
            return None
        return {name: float(np.median([p[name] for p in self.phase_ms]))
                for name in self.phase_ms[0]}

    def summary(self, which: str) -> dict:
        """``{"median", "min", "max"}`` of ``t_interp_ms`` or ``t_total_ms`` (ms)."""
        values = np.asarray(getattr(self, which), dtype=float)
        return {"median": float(np.median(values)), "min": float(values.min()),
                "max": float(values.max())}


@dataclass(frozen=True)
class SceneBenchmark:
    """The benchmark of one scene.

    Attributes:
        scene: scene name.
        dt: time step (s).
        steps: steps per run.
        repeats: runs per method.
        warmup: steps per run left out of the timings.
        rows: one dict per method with exactly the keys :data:`ROW_KEYS` and then
            :data:`ROW_EXTRA_KEYS` (times: medians over repeats; ``error_vs_full`` None
            when undefined; the free-body keys None for a fixed object).
        timings: the spread of the times, one per method (same order as ``rows``).
        influence: ``(method, stats)`` pairs: the example influence keys
            (:data:`lbshape.pipeline.influence.STATS_KEYS`) of the ``reduced`` and
            ``full`` runs against the same scene without examples (empty without
            examples).
        force_model: the reduced elastic force of the reduced methods (``"polynomial"``:
            s counts every element; ``"cubature"``).
        settings: the settings comparison (``paper`` then ``lbshape``; empty when it was
            not run): :class:`SettingResult`.
        plain_r: a free body with impact columns: r₀, its plain basis, which every step
            solves for (the columns only around impacts); None: r.
    """

    scene: str
    dt: float
    steps: int
    repeats: int
    warmup: int
    rows: tuple[dict, ...]
    timings: tuple[MethodTiming, ...]
    influence: tuple[tuple[str, dict], ...] = ()
    force_model: str = "cubature"
    settings: tuple[SettingResult, ...] = ()
    plain_r: int | None = None

    def row(self, method: str) -> dict | None:
        """The row of ``method`` (None if it was not run)."""
        return next((row for row in self.rows if row["method"] == method), None)


@dataclass(frozen=True)
class PaperSetting:
    """The reduced sizes and force model the paper's method runs a scene at.

    Attributes:
        m, r, s: LB eigenfunctions, reduced coordinates, cubature elements.
        source: where they come from (:data:`PAPER_SOURCE`: the paper's Table 2;
            :data:`SCENE_SOURCE`: a scene the paper has no row for, at its own sizes).
        forces: the reduced elastic force (the paper's: ``"cubature"``).
    """

    m: int
    r: int
    s: int
    source: str
    forces: str = "cubature"


def paper_setting(scene, paper_table: Mapping[str, Sequence]) -> PaperSetting:
    """The paper's setting of a scene: its Table 2 (m, r, s) with cubature forces.

    Args:
        scene: the :class:`~lbshape.scene.schema.Scene`.
        paper_table: the paper's Table 2 by scene name, each row's columns (DOFs, tets,
            example vertices, m, r, s, …)
            (:data:`lbshape.studies.realtime.PAPER_TABLE2`).

    Returns:
        The scene's row's (m, r, s), or for a scene without a row its own (m, r, s)
        (``source`` :data:`SCENE_SOURCE`); forces ``"cubature"`` in both cases.
    """
    row = paper_table.get(scene.name)
    if row is None:
        red = scene.reduced
        return PaperSetting(int(red.m), int(red.r), int(red.s), SCENE_SOURCE)
    m, r, s = (int(value) for value in row[3:6])
    return PaperSetting(m, r, s, PAPER_SOURCE)


@dataclass(frozen=True)
class SettingResult:
    """The reduced method at one setting of a scene, in the settings comparison.

    Attributes:
        label: ``"paper"`` (:func:`paper_setting`) or ``"lbshape"`` (the scene as written).
        source: how the setting was chosen (:data:`PAPER_SOURCE`, :data:`SCENE_SOURCE`,
            :data:`LBSHAPE_SOURCE`; the paper's setting of a scene that already runs it
            says so and shares the lbshape setting's runs).
        m, r: LB eigenfunctions and reduced coordinates.
        s: the elements the reduced force sums over (as Table 2's s: every element for
            the polynomial forces).
        s_max: the cubature elements asked for (the setting's ``[reduced] s``).
        forces: the reduced elastic force (``"polynomial"`` or ``"cubature"``).
        timing: the reduced runs' per-step times over the repeats (ms).
        error_vs_full: :func:`trajectory_error` against ``full`` with the examples (None
            if a run stopped).
        error_vs_full_no_examples: the same, both runs without the examples (``k_ex = 0``);
            without an example force the same runs as ``error_vs_full``.
        examples: whether the scene's examples act on it (False: the "without examples"
            error is the same run).
        free_body: a free body's :meth:`~lbshape.analysis.free_body.FreeBodyError.stats`
            against ``full`` with the examples (None for a fixed object or a stopped run).
        free_body_no_examples: the same without the examples.
    """

    label: str
    source: str
    m: int
    r: int
    s: int
    s_max: int
    forces: str
    timing: MethodTiming
    error_vs_full: float | None
    error_vs_full_no_examples: float | None
    examples: bool
    free_body: dict | None = None
    free_body_no_examples: dict | None = None

    def t_total(self) -> dict | None:
        """``{"median", "min", "max"}`` per-step total time (ms); None without a run."""
        return self.timing.summary("t_total_ms") if self.timing.t_total_ms else None

    def meets_time(self) -> bool:
        """Median per-step total time ≤ :data:`TARGET_T_TOTAL_MS`."""
        total = self.t_total()
        return total is not None and total["median"] <= TARGET_T_TOTAL_MS

    def meets_error(self) -> bool:
        """Error against ``full`` with the examples ≤ :data:`SETTINGS_TARGET_ERROR`."""
        return self.error_vs_full is not None and self.error_vs_full <= SETTINGS_TARGET_ERROR

    def payload(self) -> dict:
        """The setting's ``table2.json`` entry (times in ms, errors dimensionless)."""
        total = self.t_total()
        interp = self.timing.summary("t_interp_ms") if self.timing.t_interp_ms else None
        free = self.free_body or dict.fromkeys(FREE_BODY_KEYS)
        free_none = self.free_body_no_examples or dict.fromkeys(FREE_BODY_KEYS)
        return {
            "label": self.label, "source": self.source, "m": self.m, "r": self.r,
            "s": self.s, "s_max": self.s_max, "forces": self.forces,
            "t_total_ms": None if total is None else total["median"],
            "t_total_ms_min": None if total is None else total["min"],
            "t_total_ms_max": None if total is None else total["max"],
            "t_interp_ms": None if interp is None else interp["median"],
            "repeats": len(self.timing.t_total_ms), "stable": self.timing.stable,
            "message": self.timing.message,
            "error_vs_full": self.error_vs_full,
            "error_vs_full_no_examples": self.error_vs_full_no_examples,
            "examples": self.examples,
            "meets_t_total": self.meets_time(), "meets_error": self.meets_error(),
            **free, **{f"{key}_no_examples": value for key, value in free_none.items()},
        }


def example_vertex_count(scene) -> int:
    """Vertex count of the scene's last example mesh (0 without examples)."""
    if scene.examples is None or not scene.examples.poses:
        return 0
    return int(build_mesh(scene.examples.poses[-1].source).n_vertices)


def _check_methods(methods: Sequence[str]) -> tuple[str, ...]:
    methods = tuple(methods)
    if not methods:
        raise LbshapeError("give at least one method")
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise LbshapeError(f"unknown method(s) {unknown}; methods are {METHODS}")
    if len(set(methods)) != len(methods):
        raise LbshapeError(f"methods must be unique, got {list(methods)}")
    return methods


def _check_steps_repeats(steps: int, repeats: int) -> None:
    if isinstance(steps, bool) or int(steps) != steps or steps <= WARMUP_STEPS:
        raise LbshapeError(
            f"steps must be an integer > {WARMUP_STEPS} (the warm-up steps left out of the "
            f"timings), got {steps}"
        )
    if isinstance(repeats, bool) or int(repeats) != repeats or repeats < 1:
        raise LbshapeError(f"repeats must be an integer >= 1, got {repeats}")


def bench_scene(
    scene,
    *,
    steps: int | None = None,
    methods: Sequence[str] = DEFAULT_METHODS,
    repeats: int = 3,
    pre=None,
    progress: bool = False,
    influence: bool = True,
    paper: PaperSetting | None = None,
    free_eval: bool = False,
) -> SceneBenchmark:
    """Run the methods side by side on one scene (see the module docstring).

    Args:
        scene: the :class:`~lbshape.scene.schema.Scene`.
        steps: steps per run (default: the scene's), > the warm-up steps.
        methods: which of ``full``, ``euclidean``, ``reduced`` to run.
        repeats: runs per method (interleaved); times are medians over them.
        pre: the scene's :class:`~lbshape.pipeline.precomputed.Precomputed` (default: built or
            loaded from the cache).
        progress: show the precompute's progress bars on stderr.
        influence: with examples, also run ``reduced`` and ``full`` once without
            examples and record the example influence.
        paper: also run the settings comparison (needs ``full`` and ``reduced``): the
            reduced method at this setting (:func:`paper_setting`; its own precompute,
            cached) in the same interleaved repeats as the other methods, beside the
            scene as written; each setting's error against ``full`` with and without
            the examples. ``full`` with examples is run once per m (the scene's is
            reused when the setting has the scene's m), ``full`` and each setting's
            ``reduced`` without examples once (the example influence's runs when it
            has them).

    Returns:
        The :class:`SceneBenchmark`. A run that stops on a solver failure is kept
        (``stable`` False in its timing, ``error_vs_full`` None) and logged.
    """
    methods = _check_methods(methods)
    if paper is not None and not {"full", "reduced"} <= set(methods):
        raise LbshapeError("the settings comparison needs the full and reduced methods")
    steps = scene.simulation.steps if steps is None else steps
    _check_steps_repeats(steps, repeats)
    steps, repeats = int(steps), int(repeats)
    if pre is None:
        pre = precompute(scene, progress=progress)
    jobs = [(method, scene, pre, method) for method in methods]
    variant = variant_pre = None
    failure = ""
    if paper is not None and not _runs_setting(scene, pre, paper):
        variant, variant_pre, failure = _paper_variant(scene, paper, progress=progress)
        if variant_pre is not None:
            jobs.append((_PAPER_JOB, variant, variant_pre, "reduced"))
    outputs, timings = _run_jobs(jobs, steps=steps, repeats=repeats, name=scene.name)
    mass = mass_matrix(pre.mesh, pre.material.density)
    examples = example_vertex_count(scene)
    full = outputs.get("full")
    rows = tuple(
        _row(scene.name, outputs[method], timings[method], examples,
             *_vs_full(outputs[method], full, pre, mass))
        for method in methods
    )
    if free_eval and is_free_body(pre) and full is not None:
        rows = _free_eval_rows(scene, pre, rows, outputs, mass, steps=steps)
    effects, references = _influence(scene, pre, outputs, steps=steps) if influence else ((), {})
    settings = ()
    if paper is not None:
        settings = _settings(scene, pre, paper, outputs, timings, references, variant,
                             variant_pre, failure, steps=steps, mass=mass)
    return SceneBenchmark(scene.name, float(scene.simulation.dt), steps, repeats, WARMUP_STEPS,
                          rows, tuple(timings[m] for m in methods), effects,
                          force_model=pre.elastic.force_model, settings=settings,
                          plain_r=pre.elastic.leading)


def _free_eval_rows(scene, pre, rows: tuple[dict, ...], outputs: dict, mass, *,
                    steps: int) -> tuple[dict, ...]:
    """The rows with a free body's :data:`ROW_FREE_EVAL_KEYS` filled: the noise floor of the
    ``full`` run on every row, each other method's evaluation against it."""
    full = outputs["full"]
    floor = noise_floor(scene, pre, full, mass, steps=steps).floor \
        if full.stats["stable"] else None
    out = []
    for row in rows:
        if row["method"] == "full":
            out.append({**row, "noise_floor": floor})
        else:
            out.append({**row, **whole_run(scene, pre, outputs[row["method"]], full, mass,
                                           floor)})
    return tuple(out)


def _paper_variant(scene, paper: PaperSetting, *, progress: bool):
    """The scene at the paper's setting and its precompute (cached).

    Returns:
        ``(variant, its Precomputed or None, failure message ('' if it was built))``.
    """
    variant = with_reduced(scene, m=paper.m, r=paper.r, s=paper.s, forces=paper.forces)
    try:
        return variant, precompute(variant, progress=progress), ""
    except LbshapeError as exc:
        failure = f"precompute at the paper's setting failed: {exc}"
        log.error("bench %s: %s", scene.name, failure)
        return variant, None, failure


def _settings(scene, pre, paper: PaperSetting, outputs: dict, timings: dict, references: dict,
              variant, variant_pre, failure: str, *, steps: int, mass
              ) -> tuple[SettingResult, SettingResult]:
    """The settings comparison, ``(paper, lbshape)``, from a benchmark's finished runs."""
    full = outputs.get("full")
    lbshape = _setting("lbshape", LBSHAPE_SOURCE, scene, pre, outputs, timings["reduced"],
                       outputs["reduced"], full, references, steps=steps, mass=mass)
    if variant_pre is not None:
        full_paper = full if variant.reduced.m == scene.reduced.m else _full_reference(
            variant, variant_pre, steps=steps)
        paper_result = _setting("paper", paper.source, variant, variant_pre, outputs,
                                timings[_PAPER_JOB], outputs[_PAPER_JOB], full_paper,
                                references, steps=steps, mass=mass)
    elif failure:
        paper_result = SettingResult(
            "paper", paper.source, paper.m, paper.r, paper.s, paper.s, paper.forces,
            MethodTiming("reduced", (), (), False, failure), None, None,
            lbshape.examples)
    else:  # the scene as written runs the paper's setting: the same runs
        paper_result = dataclasses.replace(
            lbshape, label="paper", source=f"{paper.source} ({LBSHAPE_SOURCE})")
    return paper_result, lbshape


#: the key of the paper's setting's reduced runs among a benchmark's interleaved jobs
_PAPER_JOB = "reduced (paper's setting)"


def _runs_setting(scene, pre, paper: PaperSetting) -> bool:
    """True when the scene as written already runs ``paper``'s sizes and force model."""
    red = scene.reduced
    return ((int(red.m), int(red.r), int(red.s)) == (paper.m, paper.r, paper.s)
            and pre.elastic.force_model == paper.forces)


def _full_reference(scene, pre, *, steps: int):
    """One ``full`` run with the examples (a setting whose m differs from the scene's)."""
    log.info("bench %s: full reference at m = %d", scene.name, scene.reduced.m)
    output = simulate(scene, pre, method="full", steps=steps)
    if output.message:
        log.error("bench %s: full reference (m=%d) stopped: %s", scene.name, scene.reduced.m,
                  output.message)
    return output


def _setting(label: str, source: str, scene, pre, outputs: dict, timing: MethodTiming,
             reduced, full, references: dict, *, steps: int, mass) -> SettingResult:
    """The :class:`SettingResult` of one setting's finished reduced runs.

    The runs without examples: ``full`` once per benchmark (the example influence's if
    it ran, kept in ``references`` for the other setting), ``reduced`` once per setting
    (the influence's for the scene as written).
    """
    apart = _errors_apart_from_examples(
        scene, pre, reduced, full, references, "full", steps=steps, mass=mass,
        reduced_none=references.get("reduced") if label == "lbshape" else None)
    stats = reduced.stats
    return SettingResult(
        label, source, m=int(stats["m"]), r=int(stats["r"]), s=int(stats["s"]),
        s_max=int(scene.reduced.s), forces=str(stats["forces"]), timing=timing,
        error_vs_full=_vs_full(reduced, full, pre, mass)[0],
        error_vs_full_no_examples=apart["error_no_examples"],
        examples=has_example_force(scene, pre),
        free_body=apart["free_body"], free_body_no_examples=apart["free_body_no_examples"],
    )


def _errors_apart_from_examples(scene, pre, reduced, full, references: dict, key, *,
                                steps: int, mass, reduced_none=None) -> dict:
    """The errors of a setting beyond its whole-field error with examples: the error of
    its run without examples (``k_ex = 0`` in both methods) and, for a free body, the
    centre path / rotation / deformation split of both runs.

    Args:
        scene, pre: the setting.
        reduced, full: its reduced run and the full reference, both with examples.
        references: full runs without examples, shared between settings: filled here
            under ``key`` once.
        reduced_none: its reduced run without examples if one ran already (else one is
            run here).

    Returns:
        ``{"error_no_examples", "free_body", "free_body_no_examples"}`` (the free-body
        splits None for a fixed object; without examples the runs with them serve).
    """
    if has_example_force(scene, pre):
        if key not in references:
            references[key] = simulate(without_examples(scene), pre, method="full",
                                       steps=steps)
        full_none = references[key]
        if reduced_none is None:
            reduced_none = simulate(without_examples(scene), pre, method="reduced",
                                    steps=steps)
    else:
        full_none, reduced_none = full, reduced
    error_none, free_none = _vs_full(reduced_none, full_none, pre, mass)
    return {
        "error_no_examples": error_none,
        "free_body": _vs_full(reduced, full, pre, mass)[1],
        "free_body_no_examples": free_none,
    }


def _influence(scene, pre, outputs: dict, *, steps: int
               ) -> tuple[tuple[tuple[str, dict], ...], dict]:
    """Example influence of the finished ``reduced`` and ``full`` runs (stable ones only);
    one whose run without examples stopped has every key ``None`` and the reason in
    ``influence_message``.

    Returns:
        ``((method, stats) pairs, {method: its run without examples})``.
    """
    if not has_example_force(scene, pre):
        return (), {}
    effects, references = [], {}
    for method in ("reduced", "full"):
        output = outputs.get(method)
        if output is None or not output.stats["stable"]:
            continue
        try:
            effect, reference = example_influence(scene, pre, output, method=method,
                                                  steps=steps)
        except LbshapeError as exc:  # unavailable, with the reason; the run itself stays
            log.warning("bench %s: no example influence for %s: %s", scene.name, method, exc)
            effects.append((method, {**dict.fromkeys(STATS_KEYS),
                                     "influence_message": str(exc)}))
            continue
        effects.append((method, effect.stats()))
        references[method] = reference
    return tuple(effects), references


def _run_interleaved(scene, pre, methods: tuple[str, ...], *, steps: int, repeats: int):
    """Each method ``repeats`` times, interleaved (a failed method is not run again).

    Returns:
        ``({method: its first SimulationOutput}, (MethodTiming per method, in order))``.
    """
    outputs, timings = _run_jobs([(method, scene, pre, method) for method in methods],
                                 steps=steps, repeats=repeats, name=scene.name)
    return outputs, tuple(timings[method] for method in methods)


def _run_jobs(jobs: Sequence[tuple], *, steps: int, repeats: int, name: str
              ) -> tuple[dict, dict]:
    """Each job ``repeats`` times, interleaved (a failed job is not run again).

    Args:
        jobs: ``(key, scene, pre, method)`` per job, keys unique.
        name: the scene's name, for the log.

    Returns:
        ``({key: its first SimulationOutput}, {key: its MethodTiming})``.
    """
    outputs: dict[str, object] = {}
    interp: dict[str, list[float]] = {job[0]: [] for job in jobs}
    total: dict[str, list[float]] = {job[0]: [] for job in jobs}
    phases: dict[str, list[dict]] = {job[0]: [] for job in jobs}
    medians: dict[str, list[float]] = {job[0]: [] for job in jobs}
    for repeat in range(repeats):
        for key, scene, pre, method in jobs:
            first = outputs.get(key)
            if first is not None and not first.stats["stable"]:
                continue  # deterministic: a failed run fails again
            output = simulate(scene, pre, method=method, steps=steps)
            log.info("bench %s %s repeat %d: t_interp %.3f ms, t_total %.3f ms", name,
                     key, repeat + 1, output.stats["t_interp_ms"], output.stats["t_total_ms"])
            interp[key].append(float(output.stats["t_interp_ms"]))
            total[key].append(float(output.stats["t_total_ms"]))
            if output.phase_ms:
                phases[key].append(output.phase_ms)
            if output.step_median_ms is not None:
                medians[key].append(output.step_median_ms)
            outputs.setdefault(key, output)
            if output.message:
                log.error("bench %s: %s stopped: %s", name, key, output.message)
    timings = {
        key: MethodTiming(method, tuple(interp[key]), tuple(total[key]),
                          bool(outputs[key].stats["stable"]), outputs[key].message,
                          tuple(phases[key]), tuple(medians[key]))
        for key, _, _, method in jobs
    }
    return outputs, timings


def _vs_full(output, full, pre, mass) -> tuple[float | None, dict | None]:
    """``(error_vs_full, free-body split)`` of a run against ``full``:
    :func:`~lbshape.pipeline.simulate.run_error` (the one computation ``simulate --compare
    full`` uses); the error None if either run is missing or stopped early, the split
    (:data:`~lbshape.analysis.free_body.KEYS`) None also for a fixed object."""
    errors = run_error(output, full, pre, mass)
    if errors is None:
        return None, None
    free = {key: errors[key] for key in FREE_BODY_KEYS} if is_free_body(pre) else None
    return errors["error_vs_full"], free


def _row(scene: str, output, timing: MethodTiming, examples: int,
         error: float | None, free_body: dict | None = None) -> dict:
    """The row of one method: the contract keys :data:`ROW_KEYS` (sizes, median times,
    error), then :data:`ROW_EXTRA_KEYS` (a free body's split error, else None) and
    :data:`ROW_FREE_EVAL_KEYS` (None; filled by ``free_eval``)."""
    stats = output.stats
    return {
        "scene": scene, "method": timing.method,
        "n_vertices": int(stats["n_vertices"]), "n_tets": int(stats["n_tets"]),
        "example_vertices": examples, "m": int(stats["m"]),
        "r": int(stats["r"]), "s": int(stats["s"]),
        "t_interp_ms": timing.summary("t_interp_ms")["median"],
        "t_total_ms": timing.summary("t_total_ms")["median"],
        "error_vs_full": error,
        **(free_body or dict.fromkeys(ROW_EXTRA_KEYS)),
        **dict.fromkeys(ROW_FREE_EVAL_KEYS),
    }


