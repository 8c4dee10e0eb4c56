"""The precompute under ``mpirun -n 2`` equals the serial one; output and errors once.

Each test runs the command line in a subprocess with two MPI ranks (marker ``mpi``)
on small scenes: a clamped bar with two examples of another mesh, and a free bar.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lbshape.elastic.cubature_poses import training_poses
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.elastic.reduced_forces import ReducedForceModel
from lbshape.pipeline.precompute import precompute
from lbshape.scene import load_scene

PYTHON = sys.executable
REPO = Path(__file__).resolve().parents[2]

BAR = """\
name = "mpi-bar"
[object]
shape = "bar-cuboid"
size = 0.1
[material]
model = "stvk"
young = 1.0e6
poisson = 0.3
density = 1000.0
[reduced]
m = 6
r = 12
s = 20
[examples]
stiffness = 100.0
[[examples.pose]]
shape = "bar-cylinder"
size = 0.06
pose = "twist"
parameters = { angle = 1.0, axis = "z", anchor = "max" }
[[examples.pose]]
shape = "bar-cylinder"
size = 0.06
pose = "twist"
parameters = { angle = -0.5, axis = "z", anchor = "max" }
[fixed]
region = "z > 0.999"
[simulation]
steps = 5
"""
#: the same bar without examples and without fixed vertices: a free body
FREE = "\n".join(line for line in BAR.split("[examples]")[0].splitlines()
                 if not line.startswith("m = ")).replace("mpi-bar", "mpi-free") \
    + '\n[simulation]\nsteps = 5\n'


def _mpirun(*args, env) -> subprocess.CompletedProcess:
    mpirun = shutil.which("mpirun")
    if mpirun is None:
        pytest.skip("mpirun not available")
    return subprocess.run(
        [mpirun, "--allow-run-as-root", "--oversubscribe", "-n", "2", PYTHON, "-m",
         "lbshape.cli", *args], cwd=REPO, env=env, capture_output=True, text=True, timeout=600)


def _env(cache: Path) -> dict:
    return {**os.environ, "OMP_NUM_THREADS": "1", "LBSHAPE_CACHE": str(cache),
            "PYTHONPATH": str(REPO)}


def _span_sine(U1: np.ndarray, U2: np.ndarray, M) -> float:
    """Sine of the largest principal angle between two M-orthonormal bases' spans."""
    cosines = np.linalg.svd(U1.T @ (M @ U2), compute_uv=False)
    return float(np.sqrt(max(0.0, 1.0 - cosines.min() ** 2)))


def _rule_errors(pre, U_ref, q_ref, M) -> np.ndarray:
    """Relative reduced-force errors (P,) of ``pre``'s cubature at the displacements
    ``U_ref q`` (the same full-space poses whatever the basis of ``pre``)."""
    q = (pre.U.T @ (M @ U_ref)) @ q_ref.T  # coordinates in pre's basis (r, P)
    args = (pre.mesh.points, pre.mesh.tets, pre.material, pre.U)
    rule = ReducedForceModel(*args, pre.elastic.cubature_elements, pre.elastic.cubature_weights)
    exact = ReducedForceModel(*args, np.arange(pre.mesh.n_tets), np.ones(pre.mesh.n_tets))
    return np.array([np.linalg.norm(rule.force(x) - exact.force(x)) / np.linalg.norm(exact.force(x))
                     for x in q.T])


@pytest.mark.mpi
@pytest.mark.parametrize("text", [BAR, FREE], ids=["bar-examples", "free"])
def test_two_ranks_equal_serial_and_write_once(tmp_path, monkeypatch, text):
    path = tmp_path / "scene.toml"
    path.write_text(text)
    scene = load_scene(str(path))
    parallel_cache = tmp_path / "cache-2"
    proc = _mpirun("precompute", str(path), "--json", env=_env(parallel_cache))
    assert proc.returncode == 0, proc.stderr
    record = json.loads(proc.stdout)  # one JSON object: rank 0 alone printed
    assert record["origin"] == "computed"
    assert len(list(parallel_cache.rglob("*.npz"))) == 1
    distributed = {"modes", "derivatives", "cubature", "forces"} | (
        {"lb", "lb-cubature"} if scene.has_examples else set())
    assert record["stage_ranks"] == {name: 2 if name in distributed else 1
                                     for name in record["stage_seconds"]}

    monkeypatch.setenv("LBSHAPE_CACHE", str(tmp_path / "cache-1"))
    serial = precompute(scene, save=False)
    assert set(serial.stages.ranks.values()) == {1}
    monkeypatch.setenv("LBSHAPE_CACHE", str(parallel_cache))
    parallel = precompute(scene)
    assert parallel.stages.from_cache and parallel.stages.ranks == record["stage_ranks"]

    M = mass_matrix(serial.mesh, scene.material.density)
    np.testing.assert_array_equal(parallel.mesh.tets, serial.mesh.tets)
    np.testing.assert_allclose(parallel.elastic.omega2, serial.elastic.omega2, rtol=1e-8)
    assert _span_sine(serial.U, parallel.U, M) <= 1e-6
    # the two rules' force errors on the same held-out displacements
    q = training_poses(serial.U, np.ones(serial.r), count=20, magnitude=0.1,
                       object_size=1.0, rng=np.random.default_rng(7))
    errors = _rule_errors(serial, serial.U, q, M), _rule_errors(parallel, serial.U, q, M)
    assert 0 < errors[0].mean() < 0.5
    np.testing.assert_allclose(errors[1], errors[0], rtol=1e-3, atol=1e-6)
    if scene.has_examples:
        np.testing.assert_allclose(parallel.shape.eigenvalues, serial.shape.eigenvalues, rtol=1e-8)
        scale = np.abs(serial.examples.example_descriptors).max()
        np.testing.assert_allclose(parallel.examples.example_descriptors,
                                   serial.examples.example_descriptors, rtol=0,
                                   atol=1e-6 * scale)
        # the projection of the LB basis onto span U does not depend on U's columns
        projected = [pre.U @ pre.examples.projection for pre in (serial, parallel)]
        np.testing.assert_allclose(projected[1], projected[0], rtol=0,
                                   atol=1e-6 * np.abs(projected[0]).max())
        for key in ("train", "holdout"):
            assert parallel.examples.lb_cubatures.named_errors[key] == pytest.approx(
                serial.examples.lb_cubatures.named_errors[key], rel=1e-3, abs=1e-6)
    else:
        assert parallel.frame.mass == pytest.approx(serial.frame.mass, rel=1e-12)
        np.testing.assert_allclose(parallel.frame.center, serial.frame.center, atol=1e-12)


@pytest.mark.mpi
def test_two_ranks_print_a_user_error_once(tmp_path):
    path = tmp_path / "scene.toml"
    path.write_text(BAR.replace("r = 12", "r = 5000"))  # more than the mesh's DOFs
    cache = tmp_path / "cache"
    proc = _mpirun("precompute", str(path), env=_env(cache))
    assert proc.returncode == 2, proc.stderr
    errors = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "reduced.r=5000" in errors[0], proc.stderr
    assert "Traceback" not in proc.stderr and not proc.stdout
    assert not list(cache.rglob("*.npz"))
