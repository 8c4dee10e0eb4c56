"""Cost growth with mesh size (``lbshape bench --scaling``).

One base scene (default ``bar-cylinder``: the cuboid bar, twisted cylinder examples of
their own resolution) at several object sizes ``[object] size`` (the gmsh size h in
metres; the examples, m, r and s stay), from about 300 to more than 100k object
vertices:

* **precompute** — each size from scratch (``lbshape precompute SCENE --force``) in a
  fresh subprocess, so the peak memory is that size's own: wall time, the peak resident
  memory of the process (``wait4``'s ``ru_maxrss``; under MPI the largest rank), and the
  per-stage seconds and peak memory the precompute records
  (:attr:`~lbshape.pipeline.precomputed.StageReport.seconds`, ``peak_mb``,
  rank 0's). With ``ranks > 1`` the subprocess is
  ``mpirun --allow-run-as-root -n ranks``.
* **per-step time** — the reduced simulation of every size in this process (threads as
  set by the caller; 1 for the published numbers), sizes interleaved within each repeat
  so that load from other processes spreads over all sizes; per size the median over
  repeats of the mean ``t_total`` / ``t_interp`` after the warm-up steps. Each size is
  timed twice: with the scene's own route (``lb-table`` where the precompute accepted
  the table, else the per-step solve it falls back to) and with :data:`COMMON_ROUTE`,
  the per-step target solve, at every size — the same work per step whatever the
  size, so that column shows whether the step itself grows with the mesh.
* **the step at the same (m, r, s)** — the appended responses give each size its own r
  (the step's cost follows r), so the smallest size is precomputed once more with its
  scene's r raised until its basis has the largest size's columns
  (:func:`matched_r_precompute`) and timed interleaved with the others: the
  ``same (m, r, s)`` verdict compares the largest size with that copy.

Writes ``scaling.csv`` (one row per size), ``scaling.md`` (tables, machine, the ≥100k
verdicts) and ``scaling.png`` (log-log precompute time and peak memory per stage, and
per-step time, against vertices).
"""

from __future__ import annotations

import csv
import dataclasses
import io
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lbshape.errors import LbshapeError, SolverError
from lbshape.io.atomic import write_text_atomic
from lbshape.io.machine import load_text, machine_description, machine_text
from lbshape.pipeline.precompute import precompute, stage_names
from lbshape.pipeline.simulate import WARMUP_STEPS, reduced_simulation
from lbshape.report.plots import pyplot, save_figure
from lbshape.scene import load_scene
from lbshape.scene.variants import scaled_scene

#: the scene whose object is refined
DEFAULT_SCENE = "bar-cylinder"
#: object sizes h (m) of the default sweep: about 330, 1.9k, 9k, 25k, 56k and 103k vertices
DEFAULT_SIZES: tuple[float, ...] = (0.0665, 0.035, 0.0185, 0.0125, 0.0092, 0.0065)
#: steps per timed reduced run, and repeats
DEFAULT_STEPS = 300
#: the route timed at every size besides the scene's own: the per-step target solve
#: (``lb-exact``), which every precompute with examples supports
COMMON_ROUTE = "lb-exact"
DEFAULT_REPEATS = 3
#: the targets of a ≥ 100k-vertex object (reported, never asserted)
TARGET_VERTICES = 100_000
TARGET_SECONDS = 300.0
TARGET_PEAK_MB = 8 * 1024.0
TARGET_STEP_RATIO = 1.2
#: precomputes tried to reach the largest size's r at the smallest size
MATCH_R_TRIES = 3
#: CSV columns before the per-stage ones
_COLUMNS = ("size_m", "n_vertices", "n_tets", "r", "ranks", "wall_s", "stages_s", "peak_mb",
            "t_total_ms", "t_total_min_ms", "t_total_max_ms", "t_interp_ms", "target_table",
            "t_total_common_route_ms")


@dataclass
class ScalingPoint:
    """One object size: its precompute and per-step time.

    Attributes:
        size: the object's gmsh size h (m).
        n_vertices, n_tets: the object mesh.
        ranks: MPI processes of the precompute (1: serial).
        wall_seconds: the precompute subprocess's wall time (s), start-up included.
        peak_mb: its peak resident memory (MB; under MPI the largest process; the
            whole run's is :attr:`total_peak_mb`).
        stage_seconds: seconds per stage (rank 0).
        stage_peak_mb: peak resident memory per stage (MB, summed over the ranks).
        t_total_ms: per repeat, the mean reduced step time after warm-up (ms).
        t_interp_ms: per repeat, the mean time of the example target (ms).
        target_table: whether the precompute tabulated the example target (else the
            reduced step solves it at run time, a different t_interp).
        r: the basis's columns (the scene's r and the static responses and example
            responses appended where the size's modes miss them: the step's cost
            follows r, which can differ between sizes).
        t_total_common_ms: per repeat, the mean reduced step time (ms) with the
            target route :data:`COMMON_ROUTE` at every size.
        s: the cubature's elements.
        same_r: the smallest size only: the r of its copy precomputed with the largest
            size's r (:func:`matched_r_precompute`), None elsewhere.
        same_r_s: that copy's cubature elements.
        t_total_same_r_ms: per repeat, that copy's mean reduced step time (ms).
    """

    size: float
    n_vertices: int
    n_tets: int
    ranks: int
    wall_seconds: float
    peak_mb: float
    stage_seconds: dict
    stage_peak_mb: dict
    t_total_ms: list = field(default_factory=list)
    t_interp_ms: list = field(default_factory=list)
    target_table: bool | None = None
    t_total_common_ms: list = field(default_factory=list)
    r: int | None = None
    s: int | None = None
    same_r: int | None = None
    same_r_s: int | None = None
    t_total_same_r_ms: list = field(default_factory=list)

    @property
    def stages_seconds(self) -> float:
        """The sum of the stage times (s)."""
        return float(sum(self.stage_seconds.values()))

    @property
    def total_peak_mb(self) -> float:
        """Peak resident memory of the whole precompute (MB): the process's, or under MPI
        the largest per-stage sum over the ranks (at least the largest process's)."""
        return max([self.peak_mb, *self.stage_peak_mb.values()]) if self.ranks > 1 \
            else self.peak_mb


def precompute_subprocess(scene_path: Path, *, ranks: int = 1) -> tuple[float, float]:
    """``lbshape precompute SCENE --force`` in a fresh process (under ``mpirun -n ranks``
    when ranks > 1): (wall seconds, peak resident MB of the largest process)."""
    command = [sys.executable, "-m", "lbshape.cli", "precompute", str(scene_path), "--force"]
    if ranks > 1:
        mpirun = shutil.which("mpirun")
        if mpirun is None:
            raise LbshapeError("--ranks > 1 needs mpirun on the PATH")
        command = [mpirun, "--allow-run-as-root", "--oversubscribe", "-n", str(ranks),
                   *command]
    started = time.perf_counter()
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                               env=os.environ.copy())
    output = process.stdout.read()
    _, status, usage = os.wait4(process.pid, 0)
    process.returncode = os.waitstatus_to_exitcode(status)
    seconds = time.perf_counter() - started
    if process.returncode != 0:
        tail = output.decode(errors="replace").strip().splitlines()[-3:]
        raise LbshapeError(f"precompute of {scene_path.name} failed (exit "
                           f"{process.returncode}): {' | '.join(tail)}")
    return seconds, usage.ru_maxrss / 1024.0  # KB on Linux


def run_scaling(sizes: Sequence[float] = DEFAULT_SIZES, *, scene: str = DEFAULT_SCENE,
                ranks: int = 1, steps: int = DEFAULT_STEPS, repeats: int = DEFAULT_REPEATS,
                progress: bool = False) -> list[ScalingPoint]:
    """Precompute ``scene`` at every object size in a subprocess, then time the reduced
    step of all sizes interleaved (see the module docstring)."""
    if ranks < 1 or steps <= WARMUP_STEPS or repeats < 1 or not sizes:
        raise LbshapeError(f"need ranks >= 1, steps > {WARMUP_STEPS}, repeats >= 1 and at "
                           f"least one size; got {ranks}, {steps}, {repeats}, {list(sizes)}")
    points, runs = [], []
    with tempfile.TemporaryDirectory(prefix="lbshape-scaling-") as folder:
        for size in sizes:
            path = scaled_scene(scene, float(size), Path(folder))
            wall, peak = precompute_subprocess(path, ranks=ranks)
            loaded = load_scene(path)
            pre = precompute(loaded)  # from the cache the subprocess wrote
            point = ScalingPoint(
                size=float(size), n_vertices=pre.mesh.n_vertices, n_tets=pre.mesh.n_tets,
                ranks=ranks, wall_seconds=wall, peak_mb=peak,
                stage_seconds=dict(pre.stages.seconds), stage_peak_mb=dict(pre.stages.peak_mb),
                target_table=(pre.examples.target_table is not None) if pre.has_examples else None,
                r=int(pre.r), s=int(pre.elastic.cubature_elements.size))
            points.append(point)
            runs.append((loaded, pre))
            if progress:
                print(f"scaling: h={size:g} m, {point.n_vertices} vertices: precompute "
                      f"{wall:.1f} s, peak {peak:.0f} MB", file=sys.stderr)
        matched = _matched_small(points, runs, scene, Path(folder), progress)
        for _ in range(repeats):
            if matched is not None:
                points[0].t_total_same_r_ms.append(_timed_run(*matched, steps)[1])
            for point, (loaded, pre) in zip(points, runs, strict=True):
                t_interp, t_total = _timed_run(loaded, pre, steps)
                point.t_total_ms.append(t_total)
                point.t_interp_ms.append(t_interp)
                if pre.has_examples:
                    common = dataclasses.replace(loaded, reduced=dataclasses.replace(
                        loaded.reduced, interpolation=COMMON_ROUTE))
                    point.t_total_common_ms.append(_timed_run(common, pre, steps)[1])
    return points


def matched_r_precompute(scene: str, size: float, r_target: int, r_asked: int,
                         folder: Path, *, tries: int = MATCH_R_TRIES):
    """``(scene, precompute)`` of ``scene`` at ``size`` whose basis has ``r_target``
    columns: the scene's ``[reduced] r`` raised by what is missing (the appended
    responses add their own columns), at most ``tries`` precomputes; None if no try hits
    it exactly."""
    asked = int(r_asked)
    for _ in range(tries):
        loaded = load_scene(scaled_scene(scene, size, folder, r=asked))
        pre = precompute(loaded, force=True, save=False)
        if int(pre.r) == r_target:
            return loaded, pre
        asked += r_target - int(pre.r)
        if asked < 1:
            return None
    return None


def _matched_small(points: list[ScalingPoint], runs: list, scene: str, folder: Path,
                   progress: bool):
    """The smallest size precomputed with the largest size's r (None when they already
    agree, when there is one size, or when no precompute reaches it); sets its point's
    ``same_r`` and ``same_r_s``."""
    small, big = points[0], max(points, key=lambda p: p.n_vertices)
    if small is big or small.r == big.r:
        return None
    matched = matched_r_precompute(scene, small.size, big.r,
                                   runs[0][0].reduced.r + big.r - small.r, folder)
    if matched is None:
        return None
    small.same_r = int(matched[1].r)
    small.same_r_s = int(matched[1].elastic.cubature_elements.size)
    if progress:
        print(f"scaling: h={small.size:g} m again with r = {small.same_r} (scene r = "
              f"{matched[0].reduced.r})", file=sys.stderr)
    return matched


def _timed_run(scene, pre, steps: int) -> tuple[float, float]:
    """(t_interp, t_total) in ms: means after the warm-up of one reduced run."""
    record = reduced_simulation(scene, pre).run(steps, stride=steps)
    if not record.stable:
        raise SolverError(f"the reduced run of {scene.name} stopped: {record.message}")
    return record.mean_ms(warmup=WARMUP_STEPS)


# ------------------------------------------------------------------------------ output
def point_payload(point: ScalingPoint) -> dict:
    """One point as plain JSON data."""
    return {"size_m": point.size, "n_vertices": point.n_vertices, "n_tets": point.n_tets,
            "ranks": point.ranks, "wall_s": point.wall_seconds, "peak_mb": point.peak_mb,
            "stage_seconds": point.stage_seconds, "stage_peak_mb": point.stage_peak_mb,
            "t_total_ms": list(point.t_total_ms), "t_interp_ms": list(point.t_interp_ms),
            "target_table": point.target_table,
            "t_total_common_route_ms": list(point.t_total_common_ms), "r": point.r,
            "s": point.s, "same_r": point.same_r, "same_r_s": point.same_r_s,
            "t_total_same_r_ms": list(point.t_total_same_r_ms)}


def write_scaling(points: Sequence[ScalingPoint], out: Path, *,
                  machine: dict | None = None) -> list[Path]:
    """Write ``scaling.csv``, ``scaling.md`` and ``scaling.png`` into ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    machine = machine_description() if machine is None else machine
    names = _stage_order(points)
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow([*_COLUMNS, *(f"{n}_s" for n in names), *(f"{n}_peak_mb" for n in names)])
    for p in points:
        writer.writerow([f"{p.size:g}", p.n_vertices, p.n_tets, "" if p.r is None else p.r,
                         p.ranks, f"{p.wall_seconds:.2f}",
                         f"{p.stages_seconds:.2f}", f"{p.peak_mb:.0f}",
                         f"{np.median(p.t_total_ms):.4f}", f"{min(p.t_total_ms):.4f}",
                         f"{max(p.t_total_ms):.4f}", f"{np.median(p.t_interp_ms):.4f}",
                         _yes_no(p.target_table), _median_cell(p.t_total_common_ms),
                         *(_cell(p.stage_seconds.get(n), ".2f") for n in names),
                         *(_cell(p.stage_peak_mb.get(n), ".0f") for n in names)])
    paths = [write_text_atomic(out / "scaling.csv", buffer.getvalue()),
             write_text_atomic(out / "scaling.md", scaling_markdown(points, machine)),
             scaling_plot(points, out / "scaling.png")]
    return paths


def verdicts(points: Sequence[ScalingPoint]) -> list[str]:
    """The targets of the largest object with ≥ 100k vertices, measured (one line each)."""
    large = [p for p in points if p.n_vertices >= TARGET_VERTICES]
    if not large:
        return [f"no object with >= {TARGET_VERTICES} vertices in this run"]
    big = max(large, key=lambda p: p.n_vertices)
    small = min(points, key=lambda p: p.n_vertices)
    ratio = np.median(big.t_total_ms) / np.median(small.t_total_ms)
    common = ([] if not (big.t_total_common_ms and small.t_total_common_ms) else [
        _verdict(f"reduced t_total with the {COMMON_ROUTE} route at every size, "
                 f"{big.n_vertices} / {small.n_vertices} vertices{_r_pair(big, small)}",
                 np.median(big.t_total_common_ms) / np.median(small.t_total_common_ms),
                 TARGET_STEP_RATIO, "x")])
    same = ([] if not small.t_total_same_r_ms else [
        _verdict(f"reduced t_total at the same (m, r, s), {big.n_vertices} / "
                 f"{small.n_vertices} vertices (r = {big.r} / {small.same_r}, s = "
                 f"{_or_dash(big.s)} / {_or_dash(small.same_r_s)}; the small bar precomputed "
                 f"again with the large one's r)",
                 np.median(big.t_total_ms) / np.median(small.t_total_same_r_ms),
                 TARGET_STEP_RATIO, "x")])
    return [
        _verdict(f"precompute of {big.n_vertices} vertices (-n {big.ranks})",
                 big.wall_seconds, TARGET_SECONDS, "s"),
        _verdict("its peak memory" + (f" (all {big.ranks} ranks)" if big.ranks > 1 else ""),
                 big.total_peak_mb, TARGET_PEAK_MB, "MB"),
        _verdict(f"reduced t_total at {big.n_vertices} / {small.n_vertices} vertices"
                 f"{_r_pair(big, small)}",
                 ratio, TARGET_STEP_RATIO, "x"),
        *common,
        *same,
    ]


def _or_dash(value) -> str:
    return "—" if value is None else str(value)


def _r_pair(big: ScalingPoint, small: ScalingPoint) -> str:
    """`` (r = a / b)`` of two points, '' when unknown."""
    return "" if big.r is None or small.r is None else f" (r = {big.r} / {small.r})"


def scaling_markdown(points: Sequence[ScalingPoint], machine: dict) -> str:
    """The Markdown report of a sweep."""
    names = _stage_order(points)
    ranks = sorted({p.ranks for p in points})
    lines = [
        "# Cost growth with mesh size",
        "",
        f"Scene: the built-in bar-cylinder with `[object] size` = h (its examples, m, r, s "
        f"asked unchanged; r: the basis's columns, with the static and example responses "
        f"each size's modes miss appended; the cubature force model at every size, "
        f"`reduced.forces = \"cubature\"`); precompute from scratch in a fresh process per size "
        f"({'serial' if ranks == [1] else 'mpirun -n ' + '/'.join(map(str, ranks))}); "
        f"per-step times: the reduced method, sizes interleaved in one process, median of "
        f"{len(points[0].t_total_ms)} repeats of the mean after {WARMUP_STEPS} warm-up steps.",
        f"Machine: {machine_text(machine)}; load average {load_text(machine)} at the end.",
        "",
        "| h (m) | vertices | tets | r | ranks | precompute wall (s) | stages (s) "
        "| peak, largest process (MB) "
        f"| t_total (ms) [range] | t_interp (ms) | target table | t_total, {COMMON_ROUTE} "
        "route (ms) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for p in points:
        lines.append(
            f"| {p.size:g} | {p.n_vertices} | {p.n_tets} | {'—' if p.r is None else p.r} "
            f"| {p.ranks} | {p.wall_seconds:.1f} "
            f"| {p.stages_seconds:.1f} | {p.peak_mb:.0f} | {np.median(p.t_total_ms):.3f} "
            f"[{min(p.t_total_ms):.3f}–{max(p.t_total_ms):.3f}] "
            f"| {np.median(p.t_interp_ms):.3f} | {_yes_no(p.target_table)} "
            f"| {_median_cell(p.t_total_common_ms) or '—'} |")
    for title, key, fmt in (("Seconds per stage", "stage_seconds", ".2f"),
                            ("Peak resident memory per stage (MB, summed over the ranks)",
                             "stage_peak_mb", ".0f")):
        lines += ["", f"## {title}", "", "| vertices | " + " | ".join(names) + " |",
                  "|---|" + "---|" * len(names)]
        for p in points:
            values = getattr(p, key)
            lines.append(f"| {p.n_vertices} | "
                         + " | ".join(_cell(values.get(n), fmt) for n in names) + " |")
    lines += ["", "## Targets at >= 100k vertices", ""]
    lines += [f"- {line}" for line in verdicts(points)]
    return "\n".join(lines) + "\n"


def scaling_plot(points: Sequence[ScalingPoint], path: Path) -> Path:
    """Log-log precompute time and peak memory (total and per stage) and the per-step
    time against vertices."""
    plt = pyplot()
    names = _stage_order(points)
    n = [p.n_vertices for p in points]
    fig, axes = plt.subplots(1, 3, figsize=(15.0, 4.4), dpi=110)
    ax = axes[0]
    ax.loglog(n, [p.wall_seconds for p in points], "k-o", lw=2, label="precompute (wall)")
    for name in names:
        values = [p.stage_seconds.get(name) for p in points]
        if any(v for v in values):
            ax.loglog(n, [v or np.nan for v in values], "-", marker=".", label=name)
    ax.axhline(TARGET_SECONDS, color="0.5", ls="--", lw=0.8, label="5 min")
    ax.set_title("precompute time", fontsize=10)
    ax.set_ylabel("s")
    ax = axes[1]
    several = any(p.ranks > 1 for p in points)
    ax.loglog(n, [p.peak_mb / 1024 for p in points], "k-o", lw=2,
              label="largest process" if several else "process peak")
    for name in names:
        values = [p.stage_peak_mb.get(name) for p in points]
        if any(v for v in values):
            ax.loglog(n, [(v or np.nan) / 1024 for v in values], "-", marker=".", label=name)
    ax.axhline(TARGET_PEAK_MB / 1024, color="0.5", ls="--", lw=0.8, label="8 GB")
    ax.set_title("peak resident memory" + (" (stages: sum over ranks)" if several else ""),
                 fontsize=10)
    ax.set_ylabel("GB")
    ax = axes[2]
    total = np.array([np.median(p.t_total_ms) for p in points])
    low = total - np.array([min(p.t_total_ms) for p in points])
    high = np.array([max(p.t_total_ms) for p in points]) - total
    ax.errorbar(n, total, yerr=[low, high], fmt="k-o", label="reduced t_total")
    for x, y, point in zip(n, total, points, strict=True):
        if point.r is not None:  # the step's cost follows r, which the sizes may differ in
            ax.annotate(f"r={point.r}", (x, y), fontsize=7, xytext=(0, 5),
                        textcoords="offset points", ha="center")
    ax.plot(n, [np.median(p.t_interp_ms) for p in points], "-s", label="t_interp")
    ax.fill_between([min(n), max(n)], total[0], total[0] * TARGET_STEP_RATIO, color="0.85",
                    label="first size + 20 %")
    if all(p.t_total_common_ms for p in points):
        common = np.array([np.median(p.t_total_common_ms) for p in points])
        ax.plot(n, common, "-^", label=f"t_total, {COMMON_ROUTE} route at every size")
        ax.fill_between([min(n), max(n)], common[0], common[0] * TARGET_STEP_RATIO,
                        color="0.85")
    ax.set_xscale("log")
    ax.set_yscale("log")  # the default route and the solved one differ by 20x
    ax.set_title("reduced step (same m and s; r at each point)", fontsize=10)
    ax.set_ylabel("ms per step")
    for ax in axes:
        ax.set_xlabel("object vertices")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    return save_figure(fig, path)


def _stage_order(points: Sequence[ScalingPoint]) -> list[str]:
    """Stage names in pipeline order (those any point recorded)."""
    seen = {name for p in points for name in p.stage_seconds}
    order = stage_names(load_scene(DEFAULT_SCENE))
    return [n for n in order if n in seen] + sorted(seen - set(order))


def _yes_no(value) -> str:
    return "—" if value is None else ("yes" if value else "no (solved per step)")


def _median_cell(values: list) -> str:
    """The median of ``values`` (ms, 3 decimals), '' when there are none."""
    return f"{np.median(values):.3f}" if values else ""


def _cell(value, fmt: str) -> str:
    return "" if value is None else format(value, fmt)


def _verdict(what: str, value: float, target: float, unit: str) -> str:
    ok = value <= target
    miss = "" if ok else f", missed by {value / target - 1:.0%}"
    return (f"{what}: {value:.3g} {unit} (target <= {target:g} {unit}: "
            f"{'met' if ok else 'not met'}{miss})")
