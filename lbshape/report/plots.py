"""Benchmark plots with matplotlib (Agg, off-screen); each written atomically as a PNG.

* :func:`save_figure` — any figure to a PNG path (atomic), closing it;
* :func:`speed_error_plot` — the reduced method's per-step time against its error
  versus ``full`` over a sweep (``speed_vs_error.png``).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from lbshape.io.atomic import write_atomic


def pyplot():
    """``matplotlib.pyplot`` with the off-screen Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: str | Path) -> Path:
    """Write ``fig`` as a PNG to ``path`` atomically and close it; returns ``path``."""
    try:
        return write_atomic(path, lambda tmp: fig.savefig(tmp, format="png"))
    finally:
        pyplot().close(fig)


def _s_label(point) -> str:
    """How a sweep point's force is labelled: ``s=…`` for the cubature, ``exact`` for the
    polynomial forces (every element, whatever s)."""
    return f"s={point.s}" if point.forces == "cubature" else "exact"


def speed_error_plot(points: Sequence, path: str | Path, *, scene: str, steps: int,
                     dt: float, target_error: float, target_ms: float) -> Path:
    r"""Per-step time (ms) against trajectory error vs ``full`` (%), one line per r.

    Points at the sweep's first m are grouped by r (annotated with s; with the exact
    polynomial forces s changes nothing, so each r is one point marked "exact"); points
    at other m are shown apart. Failed runs (no error) are left out.

    Args:
        points: the sweep's :class:`~lbshape.studies.sweep.SweepPoint`\ s, the scene's
            own m first (see :func:`lbshape.studies.sweep.speed_error_sweep`).
        path: the PNG to write.
        scene, steps, dt: for the title (dt in s).
        target_error, target_ms: the error (dimensionless) and per-step time (ms)
            targets, drawn as lines.
    """
    plt = pyplot()
    base_m = points[0].m  # the grid lists the scene's m first
    fig, ax = plt.subplots(figsize=(6.0, 4.2), dpi=120)
    markers = "osD^v<>ph*"
    for index, r in enumerate(sorted({p.r for p in points if p.m == base_m})):
        # s_max past the tolerance: same s; the exact forces: one point per r (s unused)
        unique = {p.s if p.forces == "cubature" else 0: p for p in points
                  if p.m == base_m and p.r == r and p.error_vs_full is not None}
        group = [unique[s] for s in sorted(unique)]
        if not group:
            continue
        x = [p.t_total_ms for p in group]
        ax.plot(x, [100 * p.error_vs_full for p in group], marker=markers[index % len(markers)],
                label=f"r = {r} (m = {base_m})")
        for p in group:
            ax.annotate(_s_label(p), (p.t_total_ms, 100 * p.error_vs_full), fontsize=7,
                        xytext=(3, 3), textcoords="offset points")
    m_points = [p for p in points if p.m != base_m and p.error_vs_full is not None]
    if m_points:
        ax.plot([p.t_total_ms for p in m_points], [100 * p.error_vs_full for p in m_points],
                "k^", label="other m")
        for p in m_points:
            ax.annotate(f"m={p.m}", (p.t_total_ms, 100 * p.error_vs_full), fontsize=7,
                        xytext=(3, -9), textcoords="offset points")
    ax.axhline(100 * target_error, color="0.6", lw=0.8, ls=":",
               label=f"{100 * target_error:g}% error")
    ax.axvline(target_ms, color="0.6", lw=0.8, ls="--", label=f"{target_ms:g} ms per step")
    ax.set_xlabel("reduced method: time per step (ms, median)")
    ax.set_yscale("log")
    ax.set_ylabel("trajectory error vs full (%)")
    ax.set_title(f"{scene}: speed against error ({steps} steps of {dt:g} s)", fontsize=10)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return save_figure(fig, path)
