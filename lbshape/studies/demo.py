"""The default job: ``lbshape demo`` / ``make demo``.

Runs the built-in ``demo`` scene end to end and writes pictures and a short
summary to ``results/demo/`` when run from the repository's root, else to
``./lbshape-results/demo/`` (:func:`lbshape.io.paths.output_root`), atomically:

1. precompute (cached): LB shape space with different-topology examples (a cuboid
   bar guided by twisted cylinders), nonlinear modal basis, cubature;
2. simulate the bar under its twisting load three ways: the reduced method with
   **no examples** (``k_ex = 0``), the reduced method **with the examples** (the
   paper's method) and the **full-space reference** with the examples; plus the
   full space without examples, for the reference's own example influence;
3. numbers: error of the reduced run against the full one, per-step times, the
   example influence (:mod:`lbshape.pipeline.influence`), the eq. 5 residual and
   the twist of the bar's free end in each run;
4. pictures: ``demo_comparison.png`` (rest | no examples | examples, reduced |
   full reference, final frames; ``demo_end_view.png`` the same seen from below
   the free end, where the twist shows best), ``demo.gif`` (the three runs animated side by
   side), ``examples_on_object.png`` / ``examples_raw.png`` (the examples as the
   method sees them on the object, and as given), ``demo_reduced.png`` /
   ``demo_full.png`` (frames over time) and ``eigenfunctions.png``, the demo bar's
   interior LB eigenfunctions (its shape space; the teddy's, the paper's Figure 2, are
   drawn by ``lbshape render teddy-global`` into that scene's figures folder).

The summary's ``headline`` states speed, error versus full and influence in one
line; :data:`SUMMARY_KEYS` are the keys of its ``simulation`` part.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

from lbshape.analysis.norms import trajectory_error
from lbshape.analysis.twist import end_twist_degrees
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.errors import LbshapeError, SolverError
from lbshape.geometry.shapes import build_shape
from lbshape.io.atomic import write_json_atomic
from lbshape.io.paths import output_root
from lbshape.pipeline.influence import compare_runs
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import simulate
from lbshape.report.figures import (
    comparison_animation,
    comparison_figure,
    eigenfunctions_figure,
    examples_figures,
    simulation_figure,
)
from lbshape.scene import load_scene
from lbshape.scene.variants import without_examples
from lbshape.spectral.spectrum import lb_spectrum

log = logging.getLogger(__name__)

#: keys of the ``simulation`` part of ``summary.json``
SUMMARY_KEYS: tuple[str, ...] = (
    "scene", "headline", "precompute_seconds", "precompute_from_cache", "stage_seconds",
    "alignment_residuals", "alignment_methods", "cubature_errors", "reduced",
    "reduced_no_examples", "full",
    "full_no_examples", "error_vs_full", "speedup_t_total", "example_influence",
    "example_influence_max", "influence_frame", "example_influence_full", "example_residual",
    "example_residual_none", "end_twist_deg", "example_twist_deg", "simulation_seconds",
    "pictures",
)
#: frames of the GIF
ANIMATION_FRAMES = 40
#: camera direction of ``demo_end_view.png``: below the free end, looking up the bar
END_VIEW = (0.0, -0.25, -1.0)


def spectra_summary(*, m: int = 6) -> dict:
    """The LB spectra of the demo's meshes (the object and its examples' mesh)."""
    summary = {}
    for name in ("demo-bar", "demo-cylinder"):
        started = time.perf_counter()
        mesh = build_shape(name)
        spectrum = lb_spectrum(mesh, m)
        summary[name] = {
            "n_vertices": mesh.n_vertices,
            "n_tets": mesh.n_tets,
            "volume": mesh.volume(),
            "eigenvalues": [float(v) for v in spectrum.eigenvalues],
            "seconds": time.perf_counter() - started,
        }
    return summary


def default_out() -> Path:
    """The demo's default folder: ``demo/`` under :func:`lbshape.io.paths.output_root`
    (``results/demo`` in the repository's root, else ``./lbshape-results/demo``)."""
    return output_root() / "demo"


def headline(summary: dict) -> str:
    """The one-line statement of speed, error versus full and example influence."""
    reduced, full = summary["reduced"], summary["full"]
    twist = summary["end_twist_deg"]
    influence = summary["example_influence"]
    influence_text = "undefined" if influence is None else f"{influence:.2f}"
    return (
        f"reduced {reduced['t_total_ms']:.2f} ms/step vs full {full['t_total_ms']:.2f} ms/step "
        f"({summary['speedup_t_total']:.1f}x); error vs full {summary['error_vs_full']:.1%}; "
        f"example influence {influence_text} (end twist {twist['reduced']:.0f} deg with "
        f"examples, {twist['reduced_no_examples']:.0f} deg without; full reference "
        f"{twist['full']:.0f} deg)"
    )


def simulation_figures(out: Path) -> dict:
    """Precompute and simulate the demo scene (see the module docstring); pictures and numbers."""
    scene = load_scene("demo")
    if scene.examples is None or not scene.examples.acts:
        raise LbshapeError("the demo scene must have examples with k_ex > 0")
    started = time.perf_counter()
    pre = precompute(scene, progress=True)
    precompute_seconds = time.perf_counter() - started
    plain = without_examples(scene)
    started = time.perf_counter()
    runs = {
        "reduced": simulate(scene, pre, method="reduced", out=out / "runs" / "reduced"),
        "reduced_no_examples": simulate(plain, pre, method="reduced",
                                        out=out / "runs" / "reduced_no_examples"),
        "full": simulate(scene, pre, method="full", out=out / "runs" / "full"),
        "full_no_examples": simulate(plain, pre, method="full"),
    }
    simulation_seconds = time.perf_counter() - started
    failed = {name: run.message for name, run in runs.items() if run.message}
    if failed:
        raise SolverError(f"demo runs stopped: {failed}")
    mass = mass_matrix(pre.mesh, scene.material.density)
    error = trajectory_error(runs["reduced"].displacements, runs["full"].displacements, mass,
                             times=runs["reduced"].times, times_full=runs["full"].times)
    influence = compare_runs(pre, runs["reduced"], runs["reduced_no_examples"], mass)
    influence_full = compare_runs(pre, runs["full"], runs["full_no_examples"], mass)
    twist = {name: end_twist_degrees(pre.mesh.points, run.displacements[-1], end="free",
                                     fixed=pre.fixed_vertices)
             for name, run in runs.items()}
    rest = pre.mesh.points
    example_twist = [end_twist_degrees(rest, pre.examples.rest_points(k) - rest, end="free",
                                       fixed=pre.fixed_vertices)
                     for k in range(len(pre.shape.example_names))]

    compared = [("no examples (reduced)", runs["reduced_no_examples"]),
                ("examples (reduced)", runs["reduced"]),
                ("examples (full reference)", runs["full"])]
    pictures = [
        comparison_figure(pre, compared, out / "demo_comparison.png", twist=True),
        comparison_figure(pre, compared, out / "demo_end_view.png", twist=True,
                          view_vector=END_VIEW, view_up=(0.0, 1.0, 0.0), zoom=1.5),
        comparison_animation(pre, compared, out / "demo.gif", frames=ANIMATION_FRAMES,
                             twist=True),
        *examples_figures(scene, pre, out),
        simulation_figure(pre, runs["reduced"], out / "demo_reduced.png"),
        simulation_figure(pre, runs["full"], out / "demo_full.png"),
        eigenfunctions_figure(scene, pre, out / "eigenfunctions.png"),
    ]
    summary = {
        "scene": scene.name,
        "precompute_seconds": precompute_seconds,
        "precompute_from_cache": pre.stages.from_cache,
        "stage_seconds": pre.stages.seconds,
        "alignment_residuals": [float(r) for r in pre.examples.alignment_residuals],
        "alignment_methods": pre.examples.alignment_methods,
        "cubature_errors": pre.elastic.cubature_errors,
        **{name: run.stats for name, run in runs.items()},
        "error_vs_full": error,
        "speedup_t_total": runs["full"].stats["t_total_ms"] / runs["reduced"].stats["t_total_ms"],
        "example_influence": influence.final,
        "example_influence_max": influence.maximum,
        "influence_frame": influence.frame,
        "example_influence_full": influence_full.final,
        "example_residual": influence.residual,
        "example_residual_none": influence.residual_none,
        "end_twist_deg": twist,
        "example_twist_deg": example_twist,
        "simulation_seconds": simulation_seconds,
        "pictures": [p.name for p in pictures],
    }
    summary["headline"] = headline(summary)
    return {key: summary[key] for key in SUMMARY_KEYS}


def run_demo(out: Path | None = None) -> Path:
    """Run the demo; return the summary file path."""
    out = Path(out) if out is not None else default_out()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise LbshapeError(f"cannot create output folder {out}: {exc.strerror}") from None
    summary = {"simulation": simulation_figures(out), "spectra": spectra_summary()}
    return write_json_atomic(out / "summary.json", summary)
