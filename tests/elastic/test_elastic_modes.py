"""Linear elastic modes: exact matrices, rigid modes, cantilever convergence, errors, CLI, MPI."""

from __future__ import annotations

import json
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
from lbshape.elastic.materials import Material
from lbshape.elastic.modes import elastic_matrices, linear_modes, rigid_body_modes
from lbshape.errors import LbshapeError, SolverError
from lbshape.geometry.mesh import TetMesh, gmsh_session
from lbshape.geometry.primitives import structured_box

REPO = Path(__file__).resolve().parents[2]
PYTHON = str(REPO / ".venv" / "bin" / "python") if (REPO / ".venv").is_dir() else sys.executable

#: ν = 0 makes the axial problem exactly one-dimensional (no lateral contraction)
BAR_MATERIAL = Material(young=1.0e6, poisson=0.0, density=1000.0)
MATERIAL = Material(young=2.0e5, poisson=0.3, density=1100.0)
H, L = 0.1, 1.0  # square section h × h, length L (metres)


def m_subspace_angles(A: np.ndarray, B: np.ndarray, M) -> np.ndarray:
    """Principal angles (radians) between span(A) and span(B) in the M inner product."""
    L_ = np.linalg.cholesky(M.toarray())
    return scipy.linalg.subspace_angles(L_.T @ A, L_.T @ B)


def analytic_rigid_fields(points: np.ndarray) -> np.ndarray:
    """(3n, 6) translations and rotations about the origin (not orthonormal)."""
    n = points.shape[0]
    out = np.zeros((n, 3, 6))
    for c in range(3):
        out[:, c, c] = 1.0
        axis = np.eye(3)[c]
        out[:, :, 3 + c] = np.cross(axis, points)
    return out.reshape(3 * n, 6)


def clamped_bar(n: int) -> tuple[TetMesh, np.ndarray]:
    """h × h × L bar of cubes (n across the section), and its vertices at z = 0."""
    mesh = structured_box((H, H, L), (n, n, 10 * n))
    return mesh, np.flatnonzero(mesh.points[:, 2] < 1e-12)


# ---------------------------------------------------------------- matrices


def test_matrices_are_exact_for_rigid_and_linear_fields():
    mesh = structured_box((0.4, 0.3, 0.5), (3, 2, 3))
    with elastic_matrices(mesh, MATERIAL) as mats:
        K, M = mats.stiffness, mats.mass
        assert mats.stiffness_petsc.getSize() == (3 * mesh.n_vertices,) * 2
    scale = abs(K).max()
    assert abs(K - K.T).max() < 1e-13 * scale
    rigid = analytic_rigid_fields(mesh.points)
    leak = np.abs(K @ rigid).max() / (scale * np.abs(rigid).max())
    assert leak < 1e-13, f"K does not annihilate rigid motions: {leak:.2e}"
    vol = mesh.volume()
    ones_x = np.zeros(3 * mesh.n_vertices)
    ones_x[0::3] = 1.0
    assert ones_x @ M @ ones_x == pytest.approx(MATERIAL.density * vol, rel=1e-13)
    # a linear field u = A x has the energy ½uᵀKu = |Ω|(μ ε:ε + λ/2 (tr ε)²)
    A = np.array([[0.3, -0.2, 0.1], [0.05, -0.1, 0.25], [0.4, 0.15, 0.2]])
    u = (mesh.points @ A.T).ravel()
    eps = 0.5 * (A + A.T)
    exact = vol * (MATERIAL.mu * np.sum(eps * eps) + 0.5 * MATERIAL.lam * np.trace(eps) ** 2)
    assert 0.5 * u @ K @ u == pytest.approx(exact, rel=1e-12)


def test_stable_neohookean_has_the_same_stiffness_at_rest():
    mesh = structured_box((0.4, 0.3, 0.5), (2, 2, 2))
    nh = Material("neohookean", young=MATERIAL.young, poisson=MATERIAL.poisson,
                  density=MATERIAL.density)
    with elastic_matrices(mesh, MATERIAL, petsc=False) as a, \
            elastic_matrices(mesh, nh, petsc=False) as b:
        diff = abs(a.stiffness - b.stiffness).max() / abs(a.stiffness).max()
    assert diff < 1e-12, f"K(StVK) and K(stable NH) differ by {diff:.2e}"


# ---------------------------------------------------------------- free body


def test_free_bar_has_exactly_six_rigid_modes_spanning_rigid_motion():
    mesh = structured_box((H, H, L), (2, 2, 12))
    modes = linear_modes(mesh, MATERIAL, 5)
    assert modes.n_rigid == 6 and modes.rigid.shape == (3 * mesh.n_vertices, 6)
    relative = np.abs(modes.rigid_omega2) / modes.omega2[0]
    assert relative.max() < 1e-9, f"rigid |omega^2| / omega_1^2 = {relative}"
    angles = m_subspace_angles(modes.rigid, analytic_rigid_fields(mesh.points), modes.mass)
    assert angles.max() < 1e-6, f"principal angles to analytic rigid fields {angles}"
    both = np.hstack([modes.rigid, modes.vectors])
    gram = both.T @ (modes.mass @ both)
    assert np.abs(gram - np.eye(11)).max() < 1e-12
    assert np.all(np.diff(modes.omega2) >= 0) and modes.omega2[0] > 0
    np.testing.assert_allclose(modes.frequencies_hz, np.sqrt(modes.omega2) / (2 * math.pi),
                               rtol=1e-14)
    assert modes.residuals.max() < 1e-8
    # the analytic basis helper is M-orthonormal and spans the same space
    R = rigid_body_modes(mesh.points, modes.mass)
    assert np.abs(R.T @ (modes.mass @ R) - np.eye(6)).max() < 1e-12
    assert m_subspace_angles(R, modes.rigid, modes.mass).max() < 1e-6


def test_two_bodies_are_reported_with_their_rigid_modes():
    a = structured_box((0.2, 0.2, 0.2), (1, 1, 1))
    b = structured_box((0.2, 0.2, 0.2), (1, 1, 1), origin=(1.0, 0.0, 0.0))
    two = TetMesh(np.vstack([a.points, b.points]), np.vstack([a.tets, b.tets + a.n_vertices]))
    with pytest.raises(SolverError, match="exactly 6 rigid modes, found 12"):
        linear_modes(two, MATERIAL, 8)


# ---------------------------------------------------------------- clamped bar


def _classify(mesh: TetMesh, modes) -> dict[str, float]:
    """Lowest ω (rad/s) of the axial, torsional and bending families, told by shape.

    Per mode: the M-weighted share of the z component (axial ≈ 1) and the twist
    share ``Σ m (r × u)_z² / Σ m |r|² |u|²`` about the bar axis (torsion ≈ 1,
    bending ≈ 1/2, axial 0).
    """
    n = mesh.n_vertices
    lumped = np.asarray(modes.mass.sum(axis=1)).ravel()[0::3]
    r = mesh.points[:, :2] - mesh.points[:, :2].mean(axis=0)
    found: dict[str, float] = {}
    for k in range(modes.count):
        u = modes.vectors[:, k].reshape(n, 3)
        share = (lumped[:, None] * u**2).sum(axis=0)
        z_share = share[2] / share.sum()
        twist = r[:, 0] * u[:, 1] - r[:, 1] * u[:, 0]
        twist_share = (lumped * twist**2).sum() / (lumped * (r**2).sum(1) * (u**2).sum(1)).sum()
        family = ("axial" if z_share > 0.95 else "torsion" if twist_share > 0.95
                  else "bending" if z_share < 0.05 and 0.3 < twist_share < 0.7 else None)
        if family is not None and family not in found:
            found[family] = math.sqrt(modes.omega2[k])
    return found


def test_cantilever_frequencies_converge_to_closed_forms():
    E, rho = BAR_MATERIAL.young, BAR_MATERIAL.density
    G = BAR_MATERIAL.mu
    exact = {
        "axial": math.pi / (2 * L) * math.sqrt(E / rho),
        "torsion": math.pi / (2 * L) * 0.918402 * math.sqrt(G / rho),  # J = 0.140577 h⁴
        "bending": 1.87510**2 * math.sqrt(E * H**4 / 12 / (rho * H**2 * L**4)),
    }
    divisions = (4, 6, 8)
    errors = {family: [] for family in exact}
    for n in divisions:
        mesh, fixed = clamped_bar(n)
        modes = linear_modes(mesh, BAR_MATERIAL, 8, fixed_vertices=fixed)
        assert modes.n_rigid == 0 and modes.rigid.shape[1] == 0
        clamped = (3 * fixed[:, None] + np.arange(3)).ravel()
        assert np.all(modes.vectors[clamped] == 0.0)
        found = _classify(mesh, modes)
        assert set(found) == set(exact), f"n={n}: identified {found}"
        for family, value in found.items():
            errors[family].append((value - exact[family]) / exact[family])
    h = 1.0 / np.asarray(divisions, dtype=float)
    rates = {f: observed_rates(np.abs(e), h) for f, e in errors.items()}
    report = "; ".join(f"{f}: errors {np.round(errors[f], 6)}, rates {np.round(rates[f], 2)}"
                       for f in exact)
    for family, err in errors.items():
        assert np.all(np.diff(np.abs(err)) < 0), f"{family} error does not decrease: {report}"
    # Rayleigh-Ritz: FEM ≥ the exact 3D value, which for ν = 0 is the 1D axial one
    assert min(errors["axial"]) > 0, report
    assert np.all((rates["axial"] > 1.8) & (rates["axial"] < 2.2)), report
    assert errors["axial"][-1] < 2e-5, report
    # torsion (1D St Venant) and bending (Euler-Bernoulli) converge at about O(h²)
    # to 3D limits within a few tenths of a percent of the beam theories
    assert np.all(rates["torsion"] > 1.5) and np.all(rates["bending"] > 1.5), report
    assert abs(errors["torsion"][-1]) < 0.06 and abs(errors["bending"][-1]) < 0.02, report


# ---------------------------------------------------------------- errors


def test_bad_requests_raise_clear_errors():
    mesh = structured_box((0.2, 0.2, 0.4), (1, 1, 2))  # 12 vertices, 36 DOFs
    with pytest.raises(LbshapeError, match=r"60 modes are too many for a mesh with 36 free DOFs"):
        linear_modes(mesh, MATERIAL, 60)
    with pytest.raises(LbshapeError, match="integer >= 1"):
        linear_modes(mesh, MATERIAL, 0)
    with pytest.raises(LbshapeError, match="out of range"):
        linear_modes(mesh, MATERIAL, 2, fixed_vertices=np.array([0, 12]))
    with pytest.raises(LbshapeError, match="every vertex is fixed"):
        linear_modes(mesh, MATERIAL, 2, fixed_vertices=np.arange(12))
    with pytest.raises(LbshapeError, match="target must be"):
        linear_modes(mesh, MATERIAL, 2, target=1.0)


def test_fixing_one_vertex_leaves_rigid_rotations():
    mesh = structured_box((0.2, 0.2, 0.4), (1, 1, 2))
    with pytest.raises(LbshapeError, match="do not prevent rigid motion: 3 zero-frequency"):
        linear_modes(mesh, MATERIAL, 4, fixed_vertices=np.array([0]))


def test_unconverged_solve_is_reported():
    from petsc4py import PETSc

    options = PETSc.Options()
    options.setValue("elastic_eps_max_it", 1)
    try:
        with pytest.raises(SolverError, match=r"converged \d+ of 46 requested pairs"):
            linear_modes(structured_box((H, H, L), (2, 2, 12)), MATERIAL, 40, tol=1e-12)
    finally:
        options.delValue("elastic_eps_max_it")


# ---------------------------------------------------------------- CLI and MPI


@pytest.fixture(scope="module")
def bar_msh(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("modes") / "bar.msh"
    with gmsh_session() as gmsh:
        gmsh.clear()
        gmsh.model.add("bar")
        gmsh.model.occ.addBox(0, 0, 0, 0.2, 0.2, 1.0)
        gmsh.model.occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.1)
        gmsh.option.setNumber("Mesh.RandomSeed", 1)
        gmsh.model.mesh.generate(3)
        gmsh.write(str(path))
        gmsh.clear()
    return path


def _run_cli(capsys, *argv) -> tuple[int, str, str]:
    code = cli_main(list(argv))
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_cli_json_contract(bar_msh, capsys):
    from lbshape.geometry.mesh import load_mesh

    code, out, _ = _run_cli(capsys, "modes", str(bar_msh), "--r", "4", "--fixed", "z < 1e-6",
                            "--young", "2e5", "--poisson", "0.3", "--density", "1100", "--json")
    assert code == 0
    payload = json.loads(out)
    assert list(payload) == ["n_vertices", "n_tets", "n_rigid", "frequencies_hz", "seconds"]
    mesh = load_mesh(bar_msh)
    fixed = np.flatnonzero(mesh.points[:, 2] < 1e-6)
    expected = linear_modes(mesh, MATERIAL, 4, fixed_vertices=fixed)
    assert (payload["n_vertices"], payload["n_tets"]) == (mesh.n_vertices, mesh.n_tets)
    assert payload["n_rigid"] == 0
    np.testing.assert_allclose(payload["frequencies_hz"], expected.frequencies_hz, rtol=1e-9)


def test_cli_free_body_table(bar_msh, capsys):
    code, out, _ = _run_cli(capsys, "modes", str(bar_msh), "--r", "3")
    assert code == 0 and "6 rigid modes" in out and len(out.splitlines()) == 2 + 3, out


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--fixed", "z < -1"], "--fixed region 'z < -1' selects no vertex"),
        (["--poisson", "0.5"], "material poisson must be in (-1, 0.5), got 0.5"),
        (["--r", "0"], "integer >= 1"),
    ],
)
def test_cli_bad_input(bar_msh, capsys, args, message):
    code, out, err = _run_cli(capsys, "modes", str(bar_msh), *args)
    assert code == 2 and out == ""
    assert err.startswith("error: ") and message in err and err.count("\n") == 1, err


_PARALLEL_SCRIPT = """
import sys
import numpy as np
from mpi4py import MPI
from lbshape.elastic.modes import linear_modes
from lbshape.elastic.materials import Material
from lbshape.geometry.primitives import structured_box
comm = MPI.COMM_WORLD
mesh = structured_box((0.1, 0.1, 1.0), (2, 2, 20)) if comm.rank == 0 else None
fixed = np.flatnonzero(mesh.points[:, 2] < 1e-12) if comm.rank == 0 else None
material = Material(young=2.0e5, poisson=0.3, density=1100.0)
out = {}
for name, f in (("clamped", fixed), ("free", None)):
    m = linear_modes(mesh, material, 6, fixed_vertices=f, comm=comm)
    assert (m.vectors is None) == (comm.rank != 0) and m.residuals.shape == (6,)
    out[name + "_omega2"] = m.omega2
    out[name + "_rigid"] = m.n_rigid
    if comm.rank == 0:
        out[name + "_vectors"] = m.vectors
        out[name + "_K"] = m.stiffness.toarray()
if comm.rank == 0:
    np.savez(sys.argv[1], **out)
"""


@pytest.mark.mpi
def test_two_ranks_match_serial(tmp_path):
    mpirun = shutil.which("mpirun")
    if mpirun is None:
        pytest.skip("mpirun not available")
    script, result = tmp_path / "modes_mpi.py", tmp_path / "modes.npz"
    script.write_text(_PARALLEL_SCRIPT)
    proc = subprocess.run(
        [mpirun, "--allow-run-as-root", "--oversubscribe", "-n", "2", PYTHON, str(script),
         str(result)],
        cwd=REPO, env={**os.environ, "OMP_NUM_THREADS": "1"}, capture_output=True, text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    parallel = np.load(result)
    mesh = structured_box((0.1, 0.1, 1.0), (2, 2, 20))
    fixed = np.flatnonzero(mesh.points[:, 2] < 1e-12)
    for name, f in (("clamped", fixed), ("free", None)):
        serial = linear_modes(mesh, MATERIAL, 6, fixed_vertices=f)
        assert int(parallel[name + "_rigid"]) == serial.n_rigid
        np.testing.assert_allclose(parallel[name + "_omega2"], serial.omega2, rtol=1e-9)
        K = serial.stiffness.toarray()
        assert np.abs(parallel[name + "_K"] - K).max() < 1e-13 * np.abs(K).max()
        # same modes up to sign (the spectrum has no multiple eigenvalues here)
        overlap = np.abs(np.sum(parallel[name + "_vectors"] * (serial.mass @ serial.vectors), 0))
        np.testing.assert_allclose(overlap, 1.0, atol=1e-8)
