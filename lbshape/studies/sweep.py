"""The reduced method's speed against its error while r, s (and m) vary.

:func:`speed_error_sweep` runs each configuration's precompute (cached) and timed reduced
runs (:func:`lbshape.studies.bench`'s interleaved timing) and measures each against the
``full`` method at the same m (:func:`lbshape.analysis.norms.trajectory_error`); a free
body also as Table 2 measures it (without examples, and its rigid-motion/deformation
split). The sweep's CSV and plot are written by :func:`lbshape.studies.tables.write_sweep`.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

from lbshape.elastic.element_kernels import mass_matrix
from lbshape.elastic.polynomial_forces import check_force_choice
from lbshape.errors import LbshapeError
from lbshape.pipeline.influence import is_free_body
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import simulate
from lbshape.scene.variants import with_reduced
from lbshape.studies.bench import (
    _check_steps_repeats,
    _error_vs_full,
    _errors_apart_from_examples,
    _run_interleaved,
)

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SweepPoint:
    """One configuration of the speed-versus-error sweep (reduced method).

    Attributes:
        m, r: LB eigenfunctions and reduced coordinates.
        s_max: cubature elements asked for; ``s``: selected (training may stop at
            its tolerance first).
        t_interp_ms, t_total_ms: per-step medians over repeats (ms).
        t_total_min_ms, t_total_max_ms: range of the per-step total over repeats (ms).
        error_vs_full: trajectory error against ``full`` with the same m (None if a
            run failed).
        cubature_holdout_error: relative reduced-force error on held-out poses.
        forces: the reduced elastic force the runs used (``"polynomial"``: exact, every
            element, so s only sizes the cubature trained beside it; ``"cubature"``).
        r_asked: the r the configuration asked for (``[reduced] r``); the basis has
            ``r`` columns, more where static responses were appended (None: r).
        error_no_examples: a free body: the error of its run without examples
            (``k_ex = 0`` in both methods; its only run when it has none); None for a
            fixed object.
        free_body, free_body_no_examples: a free body's
            :meth:`~lbshape.analysis.free_body.FreeBodyError.stats` (centre path,
            rotation in degrees, body-frame deformation) with and without its examples
            (the same run twice for a free body without examples); None for a fixed object.
    """

    m: int
    r: int
    s_max: int
    s: int
    t_interp_ms: float
    t_total_ms: float
    t_total_min_ms: float
    t_total_max_ms: float
    error_vs_full: float | None
    cubature_holdout_error: float | None
    forces: str = "cubature"
    r_asked: int | None = None
    error_no_examples: float | None = None
    free_body: dict | None = None
    free_body_no_examples: dict | None = None

    @property
    def asked_r(self) -> int:
        """The r the configuration asked for (:attr:`r_asked`, else :attr:`r`)."""
        return self.r if self.r_asked is None else self.r_asked


def speed_error_sweep(
    scene,
    *,
    r_values: Sequence[int] = (10, 20, 30),
    s_values: Sequence[int] = (20, 60, 120),
    m_values: Sequence[int] = (),
    steps: int | None = None,
    repeats: int = 3,
    progress: bool = False,
    forces: Sequence[str] = (),
    polynomial_r_values: Sequence[int] = (),
) -> tuple[SweepPoint, ...]:
    """Per-step time and error of the reduced method while r, s (and m) vary.

    The grid, at the scene's m: with ``forces`` empty (the default) every (r, s) of
    ``r_values × s_values`` with the scene's force choice; with ``forces`` (reduced force
    models, ``"polynomial"`` and/or ``"cubature"``) each model's own grid —
    ``"cubature"``: every (r, s) of ``r_values × s_values``; ``"polynomial"``: every r of
    ``polynomial_r_values`` (default ``r_values``) at the scene's s alone (s only sizes
    the cubature trained beside the exact forces, so it is not swept). Plus
    (m, scene r, scene s, scene force choice) for each other m of ``m_values``. Each
    configuration is its own precompute (cached); the ``full`` reference is run once
    per m. Each force value is checked against the material
    (:func:`lbshape.elastic.polynomial_forces.check_force_choice`). A free body is
    also measured as Table 2 measures it: its run without examples (one untimed
    reduced run per configuration, one ``full`` reference per m) and the centre path,
    rotation and body-frame deformation of both (:class:`SweepPoint`).

    Args:
        scene: the base scene.
        r_values, s_values, m_values: the values swept.
        steps: steps per run (default: the scene's), > the warm-up steps.
        repeats: reduced runs per configuration.
        progress: precompute progress bars on stderr.
        forces: the force models swept (empty: the scene's choice alone).
        polynomial_r_values: r values of the polynomial grid (empty: ``r_values``).
    """
    steps = scene.simulation.steps if steps is None else steps
    _check_steps_repeats(steps, repeats)
    steps, repeats = int(steps), int(repeats)
    grid = sweep_grid(scene, r_values=r_values, s_values=s_values, m_values=m_values,
                      forces=forces, polynomial_r_values=polynomial_r_values)
    references: dict[int, object] = {}
    references_none: dict[int, object] = {}  # free bodies: full without examples, per m
    points = []
    for m, r, s, choice in grid:
        points.append(_sweep_point(scene, m, r, s, choice, references, references_none,
                                   steps=steps, repeats=repeats, progress=progress))
        log.info("sweep %s: %s", scene.name, points[-1])
    return tuple(points)


def sweep_grid(scene, *, r_values: Sequence[int], s_values: Sequence[int],
               m_values: Sequence[int] = (), forces: Sequence[str] = (),
               polynomial_r_values: Sequence[int] = ()) -> list[tuple[int, int, int, str]]:
    """The (m, r, s, forces) configurations of :func:`speed_error_sweep`, in order, unique.

    Raises:
        LbshapeError: a force choice the material cannot use, an empty grid or a value < 1.
    """
    base = scene.reduced
    for choice in forces:
        check_force_choice(choice, scene.material.model)
    if not forces:
        grid = [(base.m, int(r), int(s), base.forces) for r in r_values for s in s_values]
    else:
        grid = []
        for model in dict.fromkeys(forces):
            if model == "polynomial":
                grid += [(base.m, int(r), base.s, model)
                         for r in (polynomial_r_values or r_values)]
            else:
                grid += [(base.m, int(r), int(s), model) for r in r_values for s in s_values]
    grid += [(int(m), base.r, base.s, base.forces) for m in m_values if int(m) != base.m]
    grid = list(dict.fromkeys(grid))
    if not grid:
        raise LbshapeError("the sweep is empty: give r and s values (or m values)")
    for value in {v for point in grid for v in point[:3]}:
        if value < 1:
            raise LbshapeError(f"m, r and s must be >= 1, got {value}")
    return grid


def _sweep_point(scene, m: int, r: int, s: int, choice: str, references: dict,
                 references_none: dict, *, steps: int, repeats: int,
                 progress: bool) -> SweepPoint:
    """One configuration's precompute (cached) and timed reduced runs; the ``full``
    reference of its m is run once and kept in ``references`` (free bodies: the one
    without examples in ``references_none``)."""
    variant = with_reduced(scene, m=m, r=r, s=s, forces=choice)
    pre = precompute(variant, progress=progress)
    if m not in references:
        references[m] = simulate(variant, pre, method="full", steps=steps)
        if references[m].message:
            log.error("sweep: full reference (m=%d) stopped: %s", m, references[m].message)
    outputs, (timing,) = _run_interleaved(variant, pre, ("reduced",), steps=steps,
                                          repeats=repeats)
    mass = mass_matrix(pre.mesh, pre.material.density)
    error = _error_vs_full(outputs["reduced"], references[m], mass)
    free = {}
    if is_free_body(pre):
        free = _errors_apart_from_examples(variant, pre, outputs["reduced"], references[m],
                                           references_none, m, steps=steps, mass=mass)
    holdout = pre.elastic.cubature_errors.get("holdout")
    total = timing.summary("t_total_ms")
    return SweepPoint(
        m=m, r=pre.r, s_max=s, s=int(pre.elastic.cubature_elements.size),
        t_interp_ms=timing.summary("t_interp_ms")["median"], t_total_ms=total["median"],
        t_total_min_ms=total["min"], t_total_max_ms=total["max"], error_vs_full=error,
        cubature_holdout_error=None if holdout is None else float(holdout),
        forces=pre.elastic.force_model, r_asked=r, **free,
    )
