"""Benchmark: LB eigenpairs, SLEPc (production path) against scipy ``eigsh``.

For structured 2 x 1 x 1 boxes of about 1k, 10k, 50k and 100k vertices and m = 10,
30, it times on the *same assembled matrices* (assembly timed separately):

* SLEPc: :func:`lbshape.spectral.spectrum.lb_spectrum_from_matrices` (Krylov-Schur,
  shift-and-invert, CHOLMOD Cholesky in serial; includes the inertia completeness
  check, the gather to input order, the M-orthonormalisation and the residual
  check), and the same without the inertia check (``verify=False``);
* scipy: ``eigsh(K, k=m+1, M=M, sigma=σ, which="LM", tol)`` (ARPACK, SuperLU),
  with the same target σ and tolerance.

Wall clock, median (and range) over repeats; fewer repeats for the largest sizes
(stated in the table). Threads are pinned to 1 unless set by the caller.
Writes ``results/eigen_benchmark.{csv,md,png}`` atomically.

Usage: ``.venv/bin/python scripts/bench_eigen.py``
"""

from __future__ import annotations

import os

if __name__ == "__main__":  # before numpy/PETSc load their threading libraries
    for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import csv
import io
import logging
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from lbshape.io.atomic import write_bytes_atomic
from lbshape.io.machine import load_average, machine_text
from lbshape.report.plots import pyplot, save_figure

log = logging.getLogger("bench_eigen")

RESULTS = Path(__file__).resolve().parents[1] / "results"
#: divisions (2k, k, k) of the 2 x 1 x 1 box: 960, 9537, 47937, 99937 vertices
DEFAULT_K = (7, 16, 28, 36)
DEFAULT_M = (10, 30)
TOL = 1e-10
#: target of the headline: 100k vertices, m = 30
TARGET_SECONDS = 20.0


@dataclass(frozen=True)
class Row:
    n_vertices: int
    n_tets: int
    m: int
    assembly_s: float
    slepc_s: float
    slepc_min_s: float
    slepc_max_s: float
    slepc_repeats: int
    slepc_noverify_s: float
    scipy_s: float
    scipy_min_s: float
    scipy_max_s: float
    scipy_repeats: int
    speedup: float
    max_rel_eig_diff: float
    slepc_max_residual: float


def _timed(fn: Callable[[], object], repeats: int) -> tuple[list[float], object]:
    times, result = [], None
    for _ in range(repeats):
        started = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - started)
    return times, result


def scipy_eigenvalues(K, M, m: int, sigma: float, tol: float) -> np.ndarray:
    """(m,) smallest non-zero eigenvalues by ``eigsh`` shift-and-invert (constant mode dropped)."""
    from scipy.sparse.linalg import eigsh

    values = eigsh(K, k=m + 1, M=M, sigma=sigma, which="LM", tol=tol,
                   return_eigenvectors=True)[0]
    return np.sort(values)[1:]


def bench_one(k: int, ms: Sequence[int], *, repeats: Callable[[int], tuple[int, int]],
              tol: float = TOL) -> list[Row]:
    """Time SLEPc and scipy on the (2k, k, k) box for every m in ``ms``."""
    from lbshape.geometry.primitives import structured_box
    from lbshape.spectral.spectrum import TARGET_FRACTION, lb_matrices, lb_spectrum_from_matrices

    mesh = structured_box((2.0, 1.0, 1.0), (2 * k, k, k))
    n = mesh.n_vertices
    started = time.perf_counter()
    mats = lb_matrices(mesh)
    assembly = time.perf_counter() - started
    rows = []
    with mats:
        K, M = mats.to_scipy()
        sigma = -TARGET_FRACTION * mats.eigenvalue_scale
        for m in ms:
            n_slepc, n_scipy = repeats(n)
            t_slepc, t_noverify = [], []
            for _ in range(n_slepc):  # interleaved, so that outside load hits both alike
                times, spectrum = _timed(
                    lambda m=m: lb_spectrum_from_matrices(mats, m, tol=tol), 1)
                t_slepc += times
                t_noverify += _timed(
                    lambda m=m: lb_spectrum_from_matrices(mats, m, tol=tol, verify=False), 1)[0]
            t_scipy, values = _timed(
                lambda m=m: scipy_eigenvalues(K, M, m, sigma, tol), n_scipy)
            diff = float(np.max(np.abs(values - spectrum.eigenvalues) / spectrum.eigenvalues))
            row = Row(
                n_vertices=n, n_tets=mesh.n_tets, m=m, assembly_s=assembly,
                slepc_s=statistics.median(t_slepc), slepc_min_s=min(t_slepc),
                slepc_max_s=max(t_slepc), slepc_repeats=n_slepc,
                slepc_noverify_s=statistics.median(t_noverify),
                scipy_s=statistics.median(t_scipy), scipy_min_s=min(t_scipy),
                scipy_max_s=max(t_scipy), scipy_repeats=n_scipy,
                speedup=statistics.median(t_scipy) / statistics.median(t_slepc),
                max_rel_eig_diff=diff, slepc_max_residual=float(spectrum.residuals.max()),
            )
            log.info("n=%d m=%d slepc %.2f s scipy %.2f s (x%.1f), eig diff %.1e",
                     n, m, row.slepc_s, row.scipy_s, row.speedup, diff)
            rows.append(row)
    return rows


def default_repeats(n_vertices: int) -> tuple[int, int]:
    """(SLEPc, scipy) repeats: 3 each where cheap, fewer scipy runs for the largest."""
    if n_vertices <= 20_000:
        return 3, 3
    if n_vertices <= 60_000:
        return 3, 2
    return 3, 1


def run_benchmark(ks: Sequence[int] = DEFAULT_K, ms: Sequence[int] = DEFAULT_M, *,
                  out_dir: Path = RESULTS,
                  repeats: Callable[[int], tuple[int, int]] = default_repeats,
                  tol: float = TOL) -> list[Row]:
    """Run all sizes, write ``eigen_benchmark.{csv,md,png}`` to ``out_dir``, return rows."""
    load_before = load_average()
    rows = [row for k in ks for row in bench_one(k, ms, repeats=repeats, tol=tol)]
    load_after = load_average()
    note = (f"1-minute load average {_first(load_before)} before and {_first(load_after)} after "
            "the run (the machine is shared; other load slows the memory-bound solves).")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    write_bytes_atomic(out_dir / "eigen_benchmark.csv", _csv_text(rows).encode())
    table = markdown_table(rows, tol=tol, note=note)
    write_bytes_atomic(out_dir / "eigen_benchmark.md", table.encode())
    _plot_png(rows, out_dir / "eigen_benchmark.png")
    return rows


def _first(load: list[float] | None) -> str:
    """The 1-minute load average as text ("unknown" where not available)."""
    return "unknown" if load is None else f"{load[0]:.1f}"


def _environment() -> str:
    from petsc4py import PETSc
    from slepc4py import SLEPc

    petsc = ".".join(map(str, PETSc.Sys.getVersion()))
    slepc = ".".join(map(str, SLEPc.Sys.getVersion()))
    import scipy

    return f"{machine_text()}; PETSc {petsc}, SLEPc {slepc}, scipy {scipy.__version__}"


def markdown_table(rows: Sequence[Row], *, tol: float = TOL, note: str = "") -> str:
    """The benchmark as a markdown document with one table."""
    lines = [
        "# LB eigenpairs: SLEPc (production) vs scipy eigsh",
        "",
        "Structured 2 x 1 x 1 box, P1 stiffness and consistent mass, the m smallest non-zero",
        f"eigenpairs (m + 1 computed), shift-and-invert at the same target, tol = {tol:g}.",
        "SLEPc: Krylov-Schur + CHOLMOD Cholesky (serial default), including the inertia",
        "completeness check (one MUMPS LDL^T of K - tau M), gather, M-orthonormalisation and",
        "residual check; 'no check' is the same with `verify=False`. scipy:",
        "`eigsh(K, M=M, sigma, which='LM')` (ARPACK + SuperLU), which has no completeness check.",
        "Assembly (DOLFINx) is timed separately and excluded from both. Times: wall clock,",
        "median [min-max] over the stated repeats.",
        "",
        f"Environment: {_environment()}. {note}",
        "",
        "| vertices | tets | m | assembly s | SLEPc s | runs | SLEPc no check s | scipy s "
        "| runs | speed-up | max rel. eig diff | SLEPc max residual |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r.n_vertices} | {r.n_tets} | {r.m} | {r.assembly_s:.2f} "
            f"| {r.slepc_s:.2f} [{r.slepc_min_s:.2f}-{r.slepc_max_s:.2f}] | {r.slepc_repeats} "
            f"| {r.slepc_noverify_s:.2f} "
            f"| {r.scipy_s:.2f} [{r.scipy_min_s:.2f}-{r.scipy_max_s:.2f}] | {r.scipy_repeats} "
            f"| {r.speedup:.1f}x | {r.max_rel_eig_diff:.1e} | {r.slepc_max_residual:.1e} |"
        )
    largest = [r for r in rows if r.m == 30 and r.n_vertices >= 90_000]
    if largest:
        r = largest[-1]
        met = r.slepc_s < TARGET_SECONDS and r.slepc_s < r.scipy_s
        lines += [
            "",
            f"Target (about 100k vertices, m = 30: SLEPc under {TARGET_SECONDS:.0f} s and faster "
            f"than scipy): **{'met' if met else 'not met'}** — {r.n_vertices} vertices, "
            f"SLEPc {r.slepc_s:.2f} s, scipy {r.scipy_s:.2f} s.",
        ]
    return "\n".join(lines) + "\n"


def _csv_text(rows: Sequence[Row]) -> str:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=[f.name for f in fields(Row)])
    writer.writeheader()
    for row in rows:
        writer.writerow(asdict(row))
    return buffer.getvalue()


def _plot_png(rows: Sequence[Row], path: Path) -> Path:
    """Solve time against vertices, SLEPc and scipy per m, written to the PNG ``path``."""
    fig, ax = pyplot().subplots(figsize=(6.4, 4.4), dpi=120)
    for m, marker in zip(sorted({r.m for r in rows}), "os^v", strict=False):
        sel = [r for r in rows if r.m == m]
        n = [r.n_vertices for r in sel]
        ax.loglog(n, [r.slepc_s for r in sel], marker=marker, label=f"SLEPc, m={m}")
        ax.loglog(n, [r.scipy_s for r in sel], marker=marker, ls="--", label=f"scipy eigsh, m={m}")
    ax.axhline(TARGET_SECONDS, color="grey", lw=0.8, ls=":", label=f"{TARGET_SECONDS:.0f} s target")
    ax.set_xlabel("vertices")
    ax.set_ylabel("eigensolve wall time [s] (assembly excluded)")
    ax.set_title("LB eigenpairs: SLEPc vs scipy (1 thread)")
    ax.grid(True, which="both", lw=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)


def main() -> int:
    # the root logger stays at WARNING (the JIT compiler logs through it)
    logging.basicConfig(level=logging.WARNING, format="%(name)s: %(message)s")
    log.setLevel(logging.INFO)
    run_benchmark()
    sys.stdout.write((RESULTS / "eigen_benchmark.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
