"""LB spectrum: analytic box eigenvalues, convergence rates, invariances, MPI, CLI."""

from __future__ import annotations

import itertools
import json
import logging
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
from conftest import observed_rates

from lbshape.cli import main as cli_main
from lbshape.errors import LbshapeError, SolverError
from lbshape.geometry.mesh import TetMesh, gmsh_session
from lbshape.geometry.primitives import box, structured_box
from lbshape.spectral.spectrum import (
    count_eigenvalues_below,
    lb_matrices,
    lb_matrices_csr,
    lb_spectrum,
)

REPO = Path(__file__).resolve().parents[2]
PYTHON = str(REPO / ".venv" / "bin" / "python") if (REPO / ".venv").is_dir() else sys.executable


def neumann_box_eigenvalues(size, m: int) -> np.ndarray:
    """(m,) smallest non-zero ``π²(i²/a² + j²/b² + k²/c²)``, i, j, k ≥ 0, ascending."""
    values = sorted(
        math.pi**2 * sum((i / a) ** 2 for i, a in zip(ijk, size, strict=True))
        for ijk in itertools.product(range(m + 1), repeat=3)
    )
    return np.array(values[1 : m + 1])


def m_subspace_angles(A: np.ndarray, B: np.ndarray, M) -> np.ndarray:
    """Principal angles (radians) between span(A) and span(B) in the M inner product."""
    L = np.linalg.cholesky(M.toarray())  # M = L Lᵀ, so ⟨x, y⟩_M = (Lᵀx)·(Lᵀy)
    return scipy.linalg.subspace_angles(L.T @ A, L.T @ B)


def clusters(values: np.ndarray, rtol: float) -> list[np.ndarray]:
    """Index groups of ascending ``values`` whose consecutive relative gaps are < rtol."""
    groups, current = [], [0]
    for i in range(1, values.size):
        if values[i] - values[i - 1] < rtol * values[i]:
            current.append(i)
        else:
            groups.append(np.array(current))
            current = [i]
    groups.append(np.array(current))
    return groups


def rotation(rng: np.random.Generator) -> np.ndarray:
    """A random proper rotation (3, 3)."""
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


# ---------------------------------------------------------------- matrices


def test_matrices_are_exact_for_constants_and_linears():
    mesh = box((1.0, 0.8, 0.6), h=0.25)
    K, M = lb_matrices_csr(mesh)
    ones = np.ones(mesh.n_vertices)
    x = mesh.points[:, 0]
    vol = mesh.volume()
    assert abs(K - K.T).max() < 1e-13 and abs(M - M.T).max() < 1e-17
    assert np.abs(K @ ones).max() < 1e-12, f"K·1 = {np.abs(K @ ones).max():.2e}"
    assert ones @ M @ ones == pytest.approx(vol, rel=1e-13)
    assert x @ K @ x == pytest.approx(vol, rel=1e-12)  # ∫|∇x|² = |Ω|
    # P1 fields are integrated exactly: 1ᵀ M x = ∫x = |Ω| / 2, xᵀ M x = ∫x² = |Ω| / 3
    assert ones @ M @ x == pytest.approx(0.5 * vol, rel=1e-12)
    assert x @ M @ x == pytest.approx(vol / 3.0, rel=1e-12)


def test_matrices_owner_destroys_once():
    with lb_matrices(structured_box((1, 1, 1), (2, 2, 2))) as mats:
        assert mats.stiffness.getSize() == (27, 27)
    assert mats.stiffness is None and mats.mass is None
    mats.destroy()  # idempotent


# ---------------------------------------------------------------- analytic boxes


@pytest.mark.parametrize(
    ("size", "base"),
    [((1.0, 1.0, 1.0), (3, 3, 3)), ((2.0, 1.0, 1.0), (4, 2, 2))],
    ids=["cube", "box-2x1x1"],
)
def test_box_eigenvalues_converge_at_second_order_from_above(size, base):
    m, leading = 8, 6
    exact = neumann_box_eigenvalues(size, m)
    errors, hs = [], []
    for k in (1, 2, 4):
        divisions = tuple(k * b for b in base)
        spectrum = lb_spectrum(structured_box(size, divisions), m)
        rel = (spectrum.eigenvalues - exact) / exact
        assert np.all(rel > 0), f"FEM eigenvalues must be upper bounds; rel. errors {rel}"
        errors.append(rel)
        hs.append(size[0] / divisions[0])
    errors = np.array(errors)
    rates = observed_rates(errors[-2:], hs[-2:])[0]
    assert np.all(rates[:leading] >= 1.8), f"observed rates {np.round(rates, 3)}"
    assert errors[-1, :leading].max() < 0.03, f"finest relative errors {errors[-1]}"


def test_box_with_accidental_degeneracy_unstructured():
    """2x1x1: λ(2,0,0) = λ(0,1,0) = λ(0,0,1) = π² on an unstructured mesh."""
    size = (2.0, 1.0, 1.0)
    spectrum = lb_spectrum(box(size, h=0.12), 6)
    exact = neumann_box_eigenvalues(size, 6)
    rel = (spectrum.eigenvalues - exact) / exact
    assert np.all(rel > 0) and rel.max() < 0.05, f"relative errors {rel}"
    # the degenerate triple stays within the discretisation error of each other
    triple = spectrum.eigenvalues[1:4]
    assert np.ptp(triple) / triple.mean() < 0.01, f"triple {triple}"


def test_degenerate_cluster_matches_analytic_subspace():
    """Cube: the π² eigenspace span{cos πx, cos πy, cos πz}, compared as a subspace."""
    angles = []
    for n in (6, 12):
        mesh = structured_box((1.0, 1.0, 1.0), (n, n, n))
        spectrum = lb_spectrum(mesh, 3)
        exact = np.cos(np.pi * mesh.points)  # (n, 3) columns cos πx, cos πy, cos πz
        angles.append(m_subspace_angles(spectrum.eigenvectors, exact, spectrum.mass).max())
    rate = math.log2(angles[0] / angles[1])
    assert angles[1] < 0.005 and rate >= 1.8, f"max angles {angles}, rate {rate:.3f}"


# ---------------------------------------------------------------- structure


def test_single_zero_mode_and_m_orthonormality():
    mesh = box((1.0, 0.8, 0.6), h=0.2)
    spectrum = lb_spectrum(mesh, 10)
    scale = spectrum.eigenvalues[0]
    assert abs(spectrum.zero_eigenvalue) < 1e-10 * scale, spectrum.zero_eigenvalue
    assert np.all(spectrum.eigenvalues > 0.5 * scale)  # only one (near-)zero of the m+1
    assert np.all(np.diff(spectrum.eigenvalues) >= 0)
    Phi, M, K = spectrum.eigenvectors, spectrum.mass, spectrum.stiffness
    gram = Phi.T @ M @ Phi
    assert np.abs(gram - np.eye(10)).max() < 1e-10, np.abs(gram - np.eye(10)).max()
    # orthogonal to the constant mode, K-diagonal with the eigenvalues
    assert np.abs(np.ones(mesh.n_vertices) @ M @ Phi).max() < 1e-10
    np.testing.assert_allclose(Phi.T @ K @ Phi, np.diag(spectrum.eigenvalues),
                               rtol=0, atol=1e-8 * spectrum.eigenvalues[-1])
    assert spectrum.residuals.max() < 1e-9, spectrum.residuals
    # sign rule: the first vertex of largest magnitude is positive
    for phi in Phi.T:
        big = np.flatnonzero(np.abs(phi) >= (1 - 1e-6) * np.abs(phi).max())[0]
        assert phi[big] > 0


def test_inertia_count_matches_dense_eigenvalues():
    mesh = box((1.0, 0.8, 0.6), h=0.3)
    K, M = lb_matrices_csr(mesh)
    dense = scipy.linalg.eigh(K.toarray(), M.toarray(), eigvals_only=True)
    with lb_matrices(mesh) as mats:
        for i in (1, 5, 17, 40):
            tau = 0.5 * (dense[i - 1] + dense[i])
            count = count_eigenvalues_below(mats, tau)
            assert count == i, f"tau={tau:.4f}: inertia count {count}, dense count {i}"


@pytest.mark.parametrize("n", [4, 6])
def test_exactly_repeated_eigenvalues_are_all_found(n):
    """Symmetric Kuhn cube: single-vector Krylov alone misses copies of double
    eigenvalues for some m (e.g. n=4, m=3); the inertia check must recover them."""
    mesh = structured_box((1.0, 1.0, 1.0), (n, n, n))
    K, M = lb_matrices_csr(mesh)
    dense = scipy.linalg.eigh(K.toarray(), M.toarray(), eigvals_only=True)[1:]
    for m in range(1, 13):
        values = lb_spectrum(mesh, m).eigenvalues
        np.testing.assert_allclose(values, dense[:m], rtol=1e-9, err_msg=f"m={m}")


def test_two_bodies_give_two_zero_eigenvalues():
    a = structured_box((1, 1, 1), (2, 2, 2))
    b = structured_box((1, 1, 1), (2, 2, 2), origin=(3.0, 0.0, 0.0))
    two = TetMesh(np.vstack([a.points, b.points]), np.vstack([a.tets, a.n_vertices + b.tets]))
    with pytest.raises(SolverError, match="found 2.*2 disconnected bodies"):
        lb_spectrum(two, 3)


def test_scaling_law():
    mesh = box((1.0, 0.8, 0.6), h=0.2)
    s = 2.5
    ref = lb_spectrum(mesh, 6)
    big = lb_spectrum(mesh.with_points(s * mesh.points), 6)
    np.testing.assert_allclose(big.eigenvalues, ref.eigenvalues / s**2, rtol=1e-9)
    # the first 6 eigenvalues of this box are simple: vectors (with signs) scale as s^-3/2
    np.testing.assert_allclose(big.eigenvectors, ref.eigenvectors * s**-1.5,
                               rtol=0, atol=1e-7 * np.abs(ref.eigenvectors).max())


def test_rotation_and_translation_invariance():
    """Cube: the Kuhn mesh's axis-permutation symmetry splits each analytic triple into
    1 + 2 exactly degenerate eigenvalues, whose eigenvectors are compared as subspaces."""
    mesh = structured_box((1.0, 1.0, 1.0), (6, 6, 6))
    m = 7
    ref = lb_spectrum(mesh, m)
    rng = np.random.default_rng(7)
    R, t = rotation(rng), rng.uniform(-5, 5, size=3)
    moved = lb_spectrum(mesh.with_points(mesh.points @ R.T + t), m)
    np.testing.assert_allclose(moved.eigenvalues, ref.eigenvalues, rtol=1e-9)
    groups = clusters(ref.eigenvalues, rtol=1e-6)
    assert [g.size for g in groups] == [1, 2, 2, 1, 1], ref.eigenvalues
    for g in groups:
        angles = m_subspace_angles(ref.eigenvectors[:, g], moved.eigenvectors[:, g], ref.mass)
        assert angles.max() < 1e-6, f"cluster {g}: angles {angles}"
    # translation alone changes nothing, signs included (for the simple eigenvalue)
    shifted = lb_spectrum(mesh.with_points(mesh.points + t), m)
    np.testing.assert_allclose(shifted.eigenvectors[:, 6], ref.eigenvectors[:, 6],
                               rtol=0, atol=1e-8)


# ---------------------------------------------------------------- errors


@pytest.mark.parametrize("m", [0, -1, 2.5, True, "3"])
def test_bad_m(m):
    with pytest.raises(LbshapeError, match="m must be an integer"):
        lb_spectrum(structured_box((1, 1, 1), (2, 2, 2)), m)


def test_m_too_large():
    with pytest.raises(LbshapeError, match=r"m=26 is too large for a mesh with 27 vertices"):
        lb_spectrum(structured_box((1, 1, 1), (2, 2, 2)), 26)


def test_bad_target():
    with pytest.raises(LbshapeError, match="target must be a finite negative"):
        lb_spectrum(structured_box((1, 1, 1), (2, 2, 2)), 3, target=0.5)


def test_non_convergence_is_reported():
    from petsc4py import PETSc

    options = PETSc.Options()
    options.setValue("lb_eps_max_it", 1)
    try:
        with pytest.raises(SolverError, match=r"converged \d+ of 21 requested pairs"):
            lb_spectrum(structured_box((2, 1, 1), (8, 4, 4)), 20, tol=1e-12)
    finally:
        options.delValue("lb_eps_max_it")


def test_factor_packages_agree(caplog):
    """The serial default (CHOLMOD if available) and MUMPS (used in parallel) agree;
    ``-lb_st_pc_factor_mat_solver_type`` reaches the solver through the prefix."""
    from mpi4py import MPI
    from petsc4py import PETSc

    from lbshape.spectral.spectrum import factor_package

    caplog.set_level(logging.INFO, logger="lbshape.spectral.spectrum")
    mesh = box((1.0, 0.8, 0.6), h=0.2)
    default = lb_spectrum(mesh, 8)
    assert f"factor={factor_package(MPI.COMM_SELF)}" in caplog.text
    options = PETSc.Options()
    options.setValue("lb_st_pc_factor_mat_solver_type", "mumps")
    try:
        mumps = lb_spectrum(mesh, 8)
    finally:
        options.delValue("lb_st_pc_factor_mat_solver_type")
    assert "factor=mumps" in caplog.text
    np.testing.assert_allclose(mumps.eigenvalues, default.eigenvalues, rtol=1e-10)
    np.testing.assert_allclose(mumps.eigenvectors, default.eigenvectors, rtol=0, atol=1e-7)


# ---------------------------------------------------------------- CLI and MPI


def _write_box_msh(path: Path, size=(2.0, 1.0, 1.0), h=0.2) -> Path:
    with gmsh_session() as gmsh:
        gmsh.clear()
        gmsh.model.add("box")
        gmsh.model.occ.addBox(0, 0, 0, *size)
        gmsh.model.occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMax", h)
        gmsh.option.setNumber("Mesh.RandomSeed", 1)
        gmsh.model.mesh.generate(3)
        gmsh.write(str(path))
        gmsh.clear()
    return path


@pytest.fixture(scope="module")
def box_msh(tmp_path_factory) -> Path:
    return _write_box_msh(tmp_path_factory.mktemp("eigen") / "box.msh")


def _run_cli(capsys, *argv) -> tuple[int, str, str]:
    code = cli_main(list(argv))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_cli_json_contract(box_msh, capsys):
    code, out, _ = _run_cli(capsys, "eigen", str(box_msh), "--m", "4", "--json")
    assert code == 0
    payload = json.loads(out)
    assert list(payload) == ["n_vertices", "n_tets", "volume", "eigenvalues", "seconds"]
    assert payload["volume"] == pytest.approx(2.0, rel=1e-12)
    exact = neumann_box_eigenvalues((2.0, 1.0, 1.0), 4)
    rel = (np.array(payload["eigenvalues"]) - exact) / exact
    assert np.all(rel > 0) and rel.max() < 0.1, f"relative errors {rel}"


def test_cli_table(box_msh, capsys):
    code, out, _ = _run_cli(capsys, "eigen", str(box_msh), "--m", "3")
    assert code == 0 and "lambda_i" in out and len(out.splitlines()) == 2 + 3


@pytest.mark.parametrize(
    ("args", "message"),
    [(["--m", "100000"], "m=100000 is too large for a mesh with"), (["--m", "0"], "m must be")],
)
def test_cli_bad_m(box_msh, capsys, args, message):
    code, out, err = _run_cli(capsys, "eigen", str(box_msh), *args)
    assert code == 2 and out == ""
    assert err.startswith("error: ") and message in err and err.count("\n") == 1, err


def test_cli_missing_file(tmp_path, capsys):
    code, _, err = _run_cli(capsys, "eigen", str(tmp_path / "nope.msh"))
    assert code == 2 and err.startswith("error: mesh file not found") and err.count("\n") == 1


def _mpirun(*args, cwd) -> subprocess.CompletedProcess:
    mpirun = shutil.which("mpirun")
    if mpirun is None:
        pytest.skip("mpirun not available")
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.run(
        [mpirun, "--allow-run-as-root", "--oversubscribe", "-n", "2", PYTHON, *args],
        cwd=cwd, env=env, capture_output=True, text=True, timeout=120,
    )


@pytest.mark.mpi
def test_cli_serial_and_two_ranks_agree(box_msh, capsys):
    code, out, _ = _run_cli(capsys, "eigen", str(box_msh), "--json")
    assert code == 0
    serial = json.loads(out)
    proc = _mpirun("-m", "lbshape.cli", "eigen", str(box_msh), "--json", cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    parallel = json.loads(proc.stdout)  # only rank 0 prints: one JSON document
    for key in ("n_vertices", "n_tets"):
        assert parallel[key] == serial[key]
    assert parallel["volume"] == pytest.approx(serial["volume"], rel=1e-12)
    np.testing.assert_allclose(parallel["eigenvalues"], serial["eigenvalues"], rtol=1e-9)


_PARALLEL_SCRIPT = """
import sys
import numpy as np
from mpi4py import MPI
from lbshape.geometry.primitives import structured_box
from lbshape.spectral.spectrum import lb_spectrum
comm = MPI.COMM_WORLD
mesh = structured_box((2.0, 1.0, 1.0), (8, 4, 4)) if comm.rank == 0 else None
s = lb_spectrum(mesh, 6, comm=comm)
assert (s.eigenvectors is None) == (comm.rank != 0)
assert s.residuals.shape == (6,)
if comm.rank == 0:
    np.savez(sys.argv[1], values=s.eigenvalues, vectors=s.eigenvectors,
             K=s.stiffness.toarray(), M=s.mass.toarray())
"""


@pytest.mark.mpi
def test_python_api_on_two_ranks_matches_serial(tmp_path):
    script = tmp_path / "par.py"
    script.write_text(_PARALLEL_SCRIPT)
    out = tmp_path / "par.npz"
    proc = _mpirun(str(script), str(out), cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    par = np.load(out)
    ref = lb_spectrum(structured_box((2.0, 1.0, 1.0), (8, 4, 4)), 6)
    np.testing.assert_allclose(par["K"], ref.stiffness.toarray(), rtol=0, atol=1e-13)
    np.testing.assert_allclose(par["M"], ref.mass.toarray(), rtol=0, atol=1e-17)
    np.testing.assert_allclose(par["values"], ref.eigenvalues, rtol=1e-9)
    for g in clusters(ref.eigenvalues, rtol=1e-3):  # near-degenerate triple kept together
        angles = m_subspace_angles(ref.eigenvectors[:, g], par["vectors"][:, g], ref.mass)
        assert angles.max() < 1e-6, f"cluster {g}: angles {angles}"


# ---------------------------------------------------------------- benchmark script


def test_bench_eigen_smoke(tmp_path, load_script):
    """The benchmark runs on a tiny box, agrees with scipy and writes its three files."""
    bench = load_script("bench_eigen")
    rows = bench.run_benchmark((3,), (4,), out_dir=tmp_path, repeats=lambda n: (1, 1))
    assert len(rows) == 1 and rows[0].n_vertices == 7 * 4 * 4
    assert rows[0].max_rel_eig_diff < 1e-8, rows[0]
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["eigen_benchmark.csv", "eigen_benchmark.md", "eigen_benchmark.png"]
    assert (tmp_path / "eigen_benchmark.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "| 112 |" in (tmp_path / "eigen_benchmark.md").read_text()
