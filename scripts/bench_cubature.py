"""Cubature accuracy versus size, and the per-call cost of the reduced force kernel.

Usage: ``.venv/bin/python scripts/bench_cubature.py [--s-max 120] [--out-dir results]``.

Writes (atomically):

* ``cubature_error_vs_s.csv`` and ``.png``: training and held-out relative reduced
  force error of a greedy + NNLS cubature against its number of elements s, on the
  cuboid bar (StVK), for the basis named in the files;
* ``reduced_force_timing.md``: median time per call of the run-time path
  ``force_and_tangent_into`` of the cubature
  (:class:`~lbshape.elastic.reduced_forces.ReducedForceModel`) for the paper's (r, s) and
  of the exact polynomial StVK forces
  (:class:`~lbshape.elastic.polynomial_forces.PolynomialForceModel`) at the same r, with
  the thread settings.

The error curve comes from one greedy run up to ``s_max`` with tolerance 0: the
greedy path of a run limited to s elements is the prefix of that run (same seed,
same random candidate batches), so the row for s is the first step with s elements.
"""

from __future__ import annotations

import os

if __name__ == "__main__":  # single-threaded BLAS for the timings, set before numpy loads
    for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

import argparse
import csv
import io
import itertools
import logging
import timeit
from pathlib import Path

import numpy as np

from lbshape.elastic.cubature import train_cubature
from lbshape.elastic.cubature_poses import inverse_frequency_scales, training_poses
from lbshape.elastic.element_kernels import FullSpaceElasticity, mass_matrix
from lbshape.elastic.materials import Material
from lbshape.elastic.polynomial_forces import PolynomialForceModel
from lbshape.elastic.reduced_forces import ReducedForceModel
from lbshape.geometry.mesh import TetMesh
from lbshape.io.atomic import write_bytes_atomic
from lbshape.io.machine import load_text, machine_description, machine_text
from lbshape.report.plots import pyplot, save_figure

log = logging.getLogger(__name__)

DEFAULT_OUT = Path(__file__).resolve().parents[1] / "results"
#: (r, s) of the paper's Table 2 scenes (bar 30/60, car 20/23 ~ 60 here, cross 42/21)
TIMING_CASES = ((20, 60), (30, 60), (42, 21), (42, 60))
TARGET_US = 150.0  # goal for r = 30, s = 60


# -- inputs ---------------------------------------------------------------------------------
def bar_mesh() -> tuple[TetMesh, str]:
    """The cuboid bar (0.2 × 0.2 × 1 m, about 330 vertices) and how it was made."""
    try:
        from lbshape.geometry.shapes import build_shape
    except ImportError:
        from lbshape.geometry.primitives import box

        return box((0.2, 0.2, 1.0), 0.07, origin=(-0.1, -0.1, 0.0)), "primitives.box h=0.07"
    return build_shape("bar-cuboid"), "shapes.build_shape('bar-cuboid')"


def polynomial_basis(mesh: TetMesh, r: int, *, density: float = 1000.0) -> np.ndarray:
    """A smooth mass-orthonormal basis (3n, r) vanishing at the top face (z = z_max).

    Columns: ``ζ x̂^a ŷ^b ζ^c e_i`` (``ζ = (z_max − z)/L``, ``x̂ = x/L``, ``ŷ = y/L``,
    L the largest bounding-box edge), by increasing degree ``1 + a + b + c``, then
    Gram-Schmidt in the consistent mass inner product (``UᵀMU = I``, M in kg).
    """
    p = mesh.points
    length = float(np.ptp(p, axis=0).max())
    centre = p.mean(axis=0)
    x, y = (p[:, 0] - centre[0]) / length, (p[:, 1] - centre[1]) / length
    zeta = (p[:, 2].max() - p[:, 2]) / length
    fields = []
    for degree in itertools.count(0):
        for a in range(degree + 1):
            for b in range(degree + 1 - a):
                c = degree - a - b
                scalar = zeta * x**a * y**b * zeta**c
                for i in range(3):
                    v = np.zeros((mesh.n_vertices, 3))
                    v[:, i] = scalar
                    fields.append(v.ravel())
        if len(fields) >= r:
            break
    V = np.column_stack(fields[:r])
    M = mass_matrix(mesh, density)
    L = np.linalg.cholesky(V.T @ (M @ V))
    return np.linalg.solve(L, V.T).T


def bar_basis(mesh: TetMesh, material: Material, r: int) -> tuple[np.ndarray, np.ndarray, str]:
    """(U (3n, r), pose scales (r,), description) for the bar.

    The pose scales are inverse Rayleigh frequencies ``ω_i² = u_iᵀ K₀ u_i`` (U is
    mass-orthonormal; K₀ the tangent at rest).
    """
    U = polynomial_basis(mesh, r, density=material.density)
    K0 = FullSpaceElasticity(mesh, material).tangent(np.zeros(3 * mesh.n_vertices))
    omega2 = np.einsum("ij,ij->j", U, K0 @ U)
    return U, inverse_frequency_scales(omega2), (
        "smooth polynomial basis (degree-ordered monomials times the distance to the "
        "fixed top face, mass-orthonormal)"
    )


# -- measurements ---------------------------------------------------------------------------
def error_vs_s(
    *,
    s_max: int = 120,
    r: int = 30,
    n_train: int = 200,
    n_holdout: int = 100,
    candidates: int = 200,
    magnitude: float = 0.15,
    seed: int = 0,
) -> dict:
    """Held-out and training error of the greedy cubature for s = 1..s_max on the bar."""
    material = Material("stvk", young=1.0e5, poisson=0.3, density=1000.0)
    mesh, mesh_source = bar_mesh()
    U, scales, basis = bar_basis(mesh, material, r)
    cub = train_cubature(
        mesh, material, U, rng=np.random.default_rng(seed), scales=scales,
        max_elements=s_max, tol=0.0, n_train=n_train, n_holdout=n_holdout,
        candidates_per_iter=candidates, magnitude=magnitude,
    )
    history = cub.errors_by_size
    rows = []
    for s in range(1, int(history[:, 0].max()) + 1):
        first = np.flatnonzero(history[:, 0] == s)
        if first.size:
            rows.append((s, float(history[first[0], 1]), float(history[first[0], 2])))
    return {
        "mesh": mesh_source,
        "n_vertices": mesh.n_vertices,
        "n_tets": mesh.n_tets,
        "material": "stvk",
        "basis": basis,
        "r": r,
        "n_train": n_train,
        "n_holdout": n_holdout,
        "magnitude": magnitude,
        "rows": rows,
    }


def time_force_and_tangent(
    cases=TIMING_CASES, *, number: int = 500, repeats: int = 21, seed: int = 0
) -> list[dict]:
    """µs per ``force_and_tangent_into`` call for each (r, s), both materials, and of the
    exact polynomial StVK forces (every element) at each r.

    Elements are drawn at random from the bar (the cost depends on s and r only);
    q is a training pose of the bar (10% of its length at most). The samples of all
    cases are interleaved (round-robin), so that load from other processes spreads
    evenly over the cases; each sample is ``number`` calls.

    Returns:
        rows ``{"model", "forces", "r", "s", "median_us", "min_us", "max_us"}``.
    """
    rng = np.random.default_rng(seed)
    mesh, _ = bar_mesh()
    size = float(np.ptp(mesh.points, axis=0).max())
    calls = []
    for model_name in ("stvk", "neohookean"):
        material = Material(model_name)
        for r, s in cases:
            U = polynomial_basis(mesh, r, density=material.density)
            elements = rng.choice(mesh.n_tets, size=s, replace=False)
            weights = rng.uniform(0.5, 2.0, size=s) * mesh.n_tets / s
            model = ReducedForceModel(mesh.points, mesh.tets, material, U, elements, weights)
            q = training_poses(
                U, np.ones(r), count=1, magnitude=0.1, object_size=size, rng=rng
            )[0]
            calls.append(((model_name, "cubature", r, s), _timed_call(model, q)))
    stvk = Material("stvk")
    for r in sorted({r for r, _ in cases}):
        U = polynomial_basis(mesh, r, density=stvk.density)
        model = PolynomialForceModel(mesh.points, mesh.tets, stvk, U)
        q = training_poses(U, np.ones(r), count=1, magnitude=0.1, object_size=size, rng=rng)[0]
        calls.append((("stvk", "polynomial", r, mesh.n_tets), _timed_call(model, q)))
    samples = {key: [] for key, _ in calls}
    for _ in range(repeats):
        for key, call in calls:
            samples[key].append(timeit.timeit(call, number=number) / number * 1e6)
    rows = []
    for (model_name, forces, r, s), times in samples.items():
        times = np.asarray(times)
        rows.append({
            "model": model_name, "forces": forces, "r": r, "s": s,
            "median_us": float(np.median(times)),
            "min_us": float(times.min()), "max_us": float(times.max()),
        })
    return rows


def _timed_call(model, q: np.ndarray):
    """The run-time call ``model.force_and_tangent_into(q, f, K)`` on preallocated arrays,
    warmed up (compiled) once."""
    f, K = np.zeros(q.size), np.zeros((q.size, q.size))
    model.force_and_tangent_into(q, f, K)
    return lambda: model.force_and_tangent_into(q, f, K)


# -- outputs --------------------------------------------------------------------------------
def write_error_outputs(result: dict, out_dir: Path) -> tuple[Path, Path]:
    """Write ``cubature_error_vs_s.csv`` and ``.png``; returns their paths."""
    text = io.StringIO()
    text.write(
        f"# {result['mesh']}: {result['n_vertices']} vertices, {result['n_tets']} tets, "
        f"{result['material']}; basis: {result['basis']}; r={result['r']}; "
        f"{result['n_train']} training / {result['n_holdout']} held-out poses, "
        f"largest displacement {result['magnitude']:g} x length\n"
    )
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(["s", "train_error", "holdout_error"])
    for s, train, hold in result["rows"]:
        writer.writerow([s, f"{train:.6e}", f"{hold:.6e}"])
    csv_path = Path(out_dir) / "cubature_error_vs_s.csv"
    write_bytes_atomic(csv_path, text.getvalue().encode())

    s, train, hold = np.array(result["rows"]).T
    fig, ax = pyplot().subplots(figsize=(5.5, 3.8), dpi=120)
    ax.semilogy(s, hold, label="held-out poses")
    ax.semilogy(s, train, "--", label="training poses")
    ax.axvline(60, color="0.6", lw=0.8, ls=":", label="s = 60 (bar, Table 2)")
    ax.set_xlabel("cubature elements s")
    ax.set_ylabel("relative reduced force error")
    ax.set_title(f"Cubature on the bar (r = {result['r']}, StVK)", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return csv_path, save_figure(fig, Path(out_dir) / "cubature_error_vs_s.png")


def write_timing_markdown(rows: list[dict], out_dir: Path, *, number: int, repeats: int) -> Path:
    """Write ``reduced_force_timing.md``; returns its path."""
    machine = machine_description()
    lines = [
        "# Reduced force and tangent per call (the run-time path `force_and_tangent_into`)",
        "",
        f"Machine: {machine_text(machine)}. Median, min and max over {repeats} samples of "
        f"{number} calls each (cases interleaved), warm-up excluded. Load average (1, 5, 15 "
        f"min) when written: {load_text(machine)} — other processes shared the cores, so "
        "the median includes their interference and the min is the closest to an unloaded "
        "machine.",
        "",
        "Cubature: s elements (`ReducedForceModel`); polynomial: the exact StVK force over "
        "every element of the bar (`PolynomialForceModel`, s = all tetrahedra), whose cost "
        "depends on r only.",
        "",
        "| material | force | r | s | median µs | min µs | max µs |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        lines.append(
            f"| {row['model']} | {row['forces']} | {row['r']} | {row['s']} "
            f"| {row['median_us']:.1f} "
            f"| {row['min_us']:.1f} | {row['max_us']:.1f} |"
        )
    target = [row for row in rows if (row["r"], row["s"]) == (30, 60)
              or (row["r"], row["forces"]) == (30, "polynomial")]
    if target:
        median = max(row["median_us"] for row in target)
        best = max(row["min_us"] for row in target)
        lines += [
            "",
            f"Target ≤ {TARGET_US:.0f} µs at r = 30 (s = 60, or the polynomials; slowest case): "
            f"median {median:.1f} µs — **{'met' if median <= TARGET_US else 'NOT met'}**; "
            f"min {best:.1f} µs — **{'met' if best <= TARGET_US else 'NOT met'}**.",
        ]
    path = Path(out_dir) / "reduced_force_timing.md"
    write_bytes_atomic(path, ("\n".join(lines) + "\n").encode())
    return path


def main(argv: list[str] | None = None) -> list[Path]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--s-max", type=int, default=120)
    parser.add_argument("--n-train", type=int, default=200)
    parser.add_argument("--n-holdout", type=int, default=100)
    parser.add_argument("--number", type=int, default=500, help="calls per timing sample")
    parser.add_argument("--repeats", type=int, default=21, help="timing samples per case")
    parser.add_argument("--out-dir", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args(argv)
    result = error_vs_s(s_max=args.s_max, n_train=args.n_train, n_holdout=args.n_holdout)
    paths = list(write_error_outputs(result, args.out_dir))
    rows = time_force_and_tangent(number=args.number, repeats=args.repeats)
    paths.append(write_timing_markdown(rows, args.out_dir, number=args.number,
                                       repeats=args.repeats))
    return paths


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    for p in main():
        print(p)
