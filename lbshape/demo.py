"""The default job: ``lbshape demo`` / ``make demo``.

Runs the built-in demo end to end and writes pictures and a short summary to
``results/demo/`` (atomically): the object and example meshes, their LB spectra,
and the interior eigenfunctions of the teddy (the paper's Figure 2).
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

from lbshape.atomic_io import write_json_atomic
from lbshape.errors import LbshapeError

log = logging.getLogger(__name__)

#: repository-relative default output folder
DEFAULT_OUT = Path(__file__).resolve().parents[1] / "results" / "demo"


def spectra_figure(out: Path, *, m: int = 6) -> dict:
    """Eigenfunctions on the teddy's interior (Figure 2) and the demo meshes' spectra."""
    from lbshape.render import render_eigenfunctions
    from lbshape.shapes import build_shape
    from lbshape.spectrum import lb_spectrum

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


def run_demo(out: Path | None = None) -> Path:
    """Run the demo; return the summary file path."""
    out = Path(out) if out is not None else DEFAULT_OUT
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise LbshapeError(f"cannot create output folder {out}: {exc.strerror}") from None
    summary = {"spectra": spectra_figure(out)}
    return write_json_atomic(out / "summary.json", summary)
