"""The default job: ``lbshape demo`` / ``make demo``.

Runs the built-in ``demo`` scene end to end and writes pictures and a short
summary to ``results/demo/`` (atomically):

1. precompute (cached): LB shape space with different-topology examples (a cuboid
   bar guided by twisted cylinders), nonlinear modal basis, cubature;
2. simulate with the paper's reduced method and with the full-space reference;
3. error of the reduced trajectory against the full one, per-step times;
4. pictures: the bar at a few instants (reduced and full), the examples, and the
   interior LB eigenfunctions of the teddy (the paper's Figure 2).
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

from lbshape.elastic.element_kernels import mass_matrix
from lbshape.errors import LbshapeError
from lbshape.geometry.shapes import build_shape
from lbshape.io.atomic import write_json_atomic
from lbshape.io.paths import RESULTS_DIR
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import simulate
from lbshape.report.bench import trajectory_error
from lbshape.report.figures import examples_figures, simulation_figure
from lbshape.report.render import render_eigenfunctions
from lbshape.scene import load_scene
from lbshape.spectral.spectrum import lb_spectrum

log = logging.getLogger(__name__)

#: repository-relative default output folder
DEFAULT_OUT = RESULTS_DIR / "demo"


def spectra_figure(out: Path, *, m: int = 6) -> dict:
    """Eigenfunctions on the teddy's interior (Figure 2) and the demo meshes' spectra."""
    summary = {}
    for name in ("demo-bar", "demo-cylinder", "teddy"):
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
        if name == "teddy":
            render_eigenfunctions(
                mesh, spectrum.eigenvectors, spectrum.eigenvalues,
                out / "teddy_eigenfunctions.png", indices=(0, 1, 2, 3),
                clip_normal=(0.0, 1.0, 0.0),
            )
    return summary


def simulation_figures(out: Path) -> dict:
    """Precompute and simulate the demo scene (reduced and full); pictures and numbers."""
    scene = load_scene("demo")
    started = time.perf_counter()
    pre = precompute(scene, progress=True)
    precompute_seconds = time.perf_counter() - started
    runs = {method: simulate(scene, pre, method=method, out=out / "runs" / method)
            for method in ("reduced", "full")}
    mass = mass_matrix(pre.mesh, scene.material.density)
    error = trajectory_error(runs["reduced"].displacements, runs["full"].displacements, mass,
                             times=runs["reduced"].times, times_full=runs["full"].times)
    for method, run in runs.items():
        simulation_figure(pre, run, out / f"demo_{method}.png")
    examples_figures(scene, pre, out)
    return {
        "scene": scene.name,
        "precompute_seconds": precompute_seconds,
        "precompute_from_cache": pre.from_cache,
        "stage_seconds": pre.stage_seconds,
        "alignment_residuals": [float(r) for r in pre.alignment_residuals],
        "cubature_errors": pre.cubature_errors,
        "reduced": runs["reduced"].stats,
        "full": runs["full"].stats,
        "error_vs_full": error,
        "speedup_t_total": runs["full"].stats["t_total_ms"] / runs["reduced"].stats["t_total_ms"],
    }


def run_demo(out: Path | None = None) -> Path:
    """Run the demo; return the summary file path."""
    out = Path(out) if out is not None else DEFAULT_OUT
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise LbshapeError(f"cannot create output folder {out}: {exc.strerror}") from None
    summary = {"simulation": simulation_figures(out), "spectra": spectra_figure(out)}
    return write_json_atomic(out / "summary.json", summary)
