"""The reduced runs' error estimate (lbshape.analysis.error_estimate, lbshape.pipeline.estimate)."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import scipy.linalg
import scipy.sparse.linalg as spla

from lbshape.analysis.error_estimate import (
    FACTOR_SPACING,
    MIN_INTERVALS,
    FrameForces,
    ResidualErrorEstimator,
    select_frames,
)
from lbshape.analysis.norms import trajectory_error
from lbshape.dynamics.contact import ContactPlane
from lbshape.dynamics.record import RunRecord
from lbshape.elastic.element_kernels import FullSpaceElasticity, mass_matrix
from lbshape.elastic.materials import Material
from lbshape.geometry.primitives import structured_box
from lbshape.pipeline.estimate import STATS_KEYS, estimate_error
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import simulate
from lbshape.scene import load_scene
from lbshape.scene.variants import with_step

ROOT = Path(__file__).resolve().parents[2]


def _tiny(material: Material):
    mesh = structured_box(size=(0.3, 0.1, 0.1), divisions=(2, 1, 1))
    fixed = np.flatnonzero(mesh.points[:, 0] < 1e-9)
    fixed_dofs = (3 * fixed[:, None] + np.arange(3)).ravel()
    free = np.setdiff1d(np.arange(3 * mesh.n_vertices), fixed_dofs)
    return mesh, free


def test_frame_forces_and_rest_stiffness_match_the_element_sum():
    material = Material(model="stvk", young=1e5, poisson=0.3, density=1000.0)
    mesh, _ = _tiny(material)
    u = np.random.default_rng(0).normal(scale=1e-2, size=(3 * mesh.n_vertices, 2))
    forces = FrameForces(mesh.points, mesh.tets, material)
    exact = FullSpaceElasticity(mesh, material)
    np.testing.assert_allclose(forces(u)[:, 1], exact.force(u[:, 1]), rtol=1e-12, atol=1e-12)
    K0 = exact.tangent(np.zeros(3 * mesh.n_vertices)).toarray()
    np.testing.assert_allclose(forces.rest_stiffness().toarray(), K0, rtol=1e-12,
                               atol=1e-9 * np.abs(K0).max())


def test_estimate_is_zero_when_the_basis_spans_the_free_space():
    """r = 3n − fixed dofs: the full equations' residual outside the basis is round-off."""
    material = Material(model="stvk", young=1e5, poisson=0.3, density=1000.0)
    mesh, free = _tiny(material)
    mass = mass_matrix(mesh, material.density)
    forces = FrameForces(mesh.points, mesh.tets, material)
    K0 = forces.rest_stiffness()
    # a mass-orthonormal basis of every free dof: U_f = L⁻ᵀ with M_ff = L Lᵀ
    L = np.linalg.cholesky(mass[free][:, free].toarray())
    U = np.zeros((3 * mesh.n_vertices, free.size))
    U[free] = scipy.linalg.solve_triangular(L, np.eye(free.size), lower=True).T
    pattern = np.zeros(3 * mesh.n_vertices)
    pattern[free[2::3]] = -1.0
    est = ResidualErrorEstimator(forces, U, mass, K0, free, alpha=0.5, beta=0.01,
                                 loads=[(pattern, lambda t: min(t / 0.1, 1.0))])
    times = np.arange(21) * 0.01
    Q = np.outer(np.sin(7.0 * times), np.random.default_rng(1).normal(scale=1e-2,
                                                                       size=free.size))
    lu = spla.splu(est.effective_matrix(0.01).tocsc())
    result = est.estimate(times, Q, lu.solve)
    assert result.value is not None and result.value < 1e-10, result.value
    # with a truncated basis the same trajectory has an error to report
    truncated = ResidualErrorEstimator(forces, U[:, :6], mass, K0, free, alpha=0.5,
                                       beta=0.01, loads=[(pattern, lambda t: 1.0)])
    assert truncated.estimate(times, Q[:, :6], lu.solve).value > 1e-3


def test_select_frames_keeps_uniform_frames_and_thins_them():
    """The leading uniform frames; thinned to the stored factor's spacing where the frame
    step divides it (5 ms → every 10th), else to at most ``max_frames`` intervals."""
    times = np.array([0.0, 0.1, 0.2, 0.3, 0.35])
    kept, Q, Qdot = select_frames(times, np.arange(10.0).reshape(5, 2), max_frames=50)
    np.testing.assert_allclose(kept, [0.0, 0.1, 0.2, 0.3])
    assert Q.shape == Qdot.shape == (4, 2)
    kept, _, _ = select_frames(np.arange(101) * 0.005, np.zeros((101, 1)), max_frames=50)
    assert FACTOR_SPACING == 0.05 and len(kept) == 11 and kept[1] == pytest.approx(0.05)
    kept, _, _ = select_frames(np.arange(101) * 0.005, np.zeros((101, 1)), max_frames=50,
                               spacing=0.0123)
    assert len(kept) == 51 and kept[1] == pytest.approx(0.01)
    short = np.arange(16) * 0.01  # 3 intervals of 50 ms: fewer than MIN_INTERVALS
    kept, _, _ = select_frames(short, np.zeros((16, 1)), max_frames=5)
    assert MIN_INTERVALS == 4 and len(kept) == 6 and kept[1] == pytest.approx(0.03)


def test_thinned_frames_keep_the_velocities_of_every_frame():
    """q = sin(40 t) saved every 5 ms, thinned to every 5th frame: the velocities are the
    central differences over the saved frames (within 1 % of 40 cos(40 t)), not over the
    thinned ones (25 ms apart: 16 % low at t = 0.1 s)."""
    times = np.arange(101) * 0.005
    kept, Q, Qdot = select_frames(times, np.sin(40.0 * times)[:, None], spacing=0.025)
    assert kept[1] == pytest.approx(0.025)
    inner = slice(1, -1)
    np.testing.assert_allclose(Qdot[inner, 0], 40.0 * np.cos(40.0 * kept[inner]),
                               atol=0.01 * 40.0)


def test_operators_match_the_mass_matrix_and_the_element_tangent():
    material = Material(model="stvk", young=1e5, poisson=0.3, density=1000.0)
    mesh = structured_box(size=(0.3, 0.1, 0.1), divisions=(3, 2, 2))
    forces = FrameForces(mesh.points, mesh.tets, material)
    keep = np.ones(3 * mesh.n_vertices, dtype=bool)
    keep[:6] = False
    M, K = forces.operators(material.density, keep)
    outer = np.outer(keep, keep)
    K0 = FullSpaceElasticity(mesh, material).tangent(np.zeros(3 * mesh.n_vertices)).toarray()
    M0 = mass_matrix(mesh, material.density).toarray()
    np.testing.assert_allclose(K.toarray(), K0 * outer, atol=1e-12 * np.abs(K0).max())
    np.testing.assert_allclose(M.toarray(), M0 * outer, atol=1e-12 * np.abs(M0).max())
    np.testing.assert_allclose(forces.mass(material.density).toarray(), M0,
                               atol=1e-12 * np.abs(M0).max())


def test_stats_json_holds_the_error_estimate(tmp_path):
    """``simulate`` writing its folder: stats.json has ``error_estimate`` (a number for a
    fixed object) with its message and cost."""
    import json

    scene = load_scene("demo")
    simulate(scene, precompute(scene), method="reduced", steps=4, out=tmp_path / "run")
    stats = json.loads((tmp_path / "run" / "stats.json").read_text())
    assert isinstance(stats["error_estimate"], float) and stats["error_estimate"] >= 0.0
    assert stats["error_estimate_message"] == "" and stats["error_estimate_ms"] > 0.0


def test_estimate_within_its_factor_of_the_full_reference_on_the_demo():
    """The demo at 60 Hz steps with its examples: within a factor 2 of the measured error,
    or within 1 percentage point where that error is below 1 %."""
    scene = with_step(load_scene("demo"), 1.0 / 60.0, 0.3)
    pre = precompute(scene)
    reduced = simulate(scene, pre, method="reduced")
    full = simulate(scene, pre, method="full")
    error = trajectory_error(reduced.displacements, full.displacements,
                             mass_matrix(pre.mesh, pre.material.density))
    estimate = reduced.stats["error_estimate"]
    assert estimate is not None and reduced.stats["error_estimate_message"] == ""
    if error < 0.01:
        assert abs(estimate - error) <= 0.01, (estimate, error)
    else:
        assert error / 2 <= estimate <= 2 * error, (estimate, error)
    assert full.stats["error_estimate"] is None and full.stats["error_estimate_message"]


def test_stats_keys_present_on_every_method_in_order():
    scene = load_scene("demo")
    pre = precompute(scene)
    for method in ("reduced", "euclidean", "full"):
        stats = simulate(scene, pre, method=method, steps=5).stats
        keys = list(stats)
        start = keys.index(STATS_KEYS[0])
        assert keys[start:start + len(STATS_KEYS)] == list(STATS_KEYS), keys
        assert (stats["error_estimate"] is None) == (method == "full"), stats
        assert stats["error_estimate_ms"] >= 0.0


def test_free_body_reports_none_with_the_time_of_its_first_contact():
    points = np.array([[0.0, 0.0, 0.1], [0.1, 0.0, 0.1], [0.0, 0.1, 0.2]])
    plane = ContactPlane(point=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0), stiffness=1e5)
    scene = SimpleNamespace(is_free=True, planes=(plane,), name="falling")
    pre = SimpleNamespace(mesh=SimpleNamespace(points=points))
    times = np.array([0.0, 0.1, 0.2, 0.3])
    drop = np.array([0.0, -0.05, -0.12, -0.2])  # the lowest vertex crosses z = 0 at 0.2 s
    frames = np.zeros((4, 3, 3))
    frames[:, :, 2] = drop[:, None]
    record = RunRecord(times, np.zeros((4, 2)), np.zeros(3), np.zeros(3), np.zeros(3))
    result = estimate_error(scene, pre, record, frames)
    assert result.value is None
    assert "first contact" in result.message and "t = 0.200 s" in result.message
    # no plane touched: still no number, with the reason
    result = estimate_error(scene, pre, record, np.zeros((4, 3, 3)))
    assert result.value is None and "free body" in result.message
    stopped = RunRecord(times, np.zeros((4, 2)), np.zeros(3), np.zeros(3), np.zeros(3),
                        stable=False, message="step 3 failed")
    assert "stopped" in estimate_error(scene, pre, stopped, frames).message


def test_outputs_doc_documents_the_estimate_keys():
    text = (ROOT / "docs" / "outputs.md").read_text()
    for key in STATS_KEYS:
        assert re.search(rf"\| `{key}` \|", text), key


def test_cubature_forces_report_none_with_the_reason():
    scene = SimpleNamespace(is_free=False, planes=(), name="cubature")
    pre = SimpleNamespace(elastic=SimpleNamespace(force_model="cubature"))
    record = RunRecord(np.array([0.0, 0.1]), np.zeros((2, 2)), np.zeros(1), np.zeros(1),
                       np.zeros(1))
    result = estimate_error(scene, pre, record)
    assert result.value is None and result.message.startswith("cubature forces")


def test_summary_line_words_for_the_estimate():
    from lbshape.cli.simulate import estimate_phrase

    assert estimate_phrase({"error_estimate": 0.0123}) == "error estimate 1.23%"
    assert estimate_phrase({"error_estimate": None, "error_estimate_message": "free body"}) \
        == "no error estimate (free body)"


def test_precompute_stores_the_estimate_operators_and_the_run_uses_them(monkeypatch):
    """The ``estimate`` stage holds everything per object (M, K₀, the force operators, M U,
    K₀ U, the loads' patterns), so a run builds none of it: the estimate from the stored
    operators equals the one built from scratch, and a run never assembles K₀."""
    import lbshape.pipeline.estimate as pipeline_estimate
    from lbshape.pipeline.precompute import stage_names

    scene = with_step(load_scene("demo"), 1.0 / 60.0, 0.2)
    assert "estimate" in stage_names(scene)
    pre = precompute(scene)
    assert pre.estimate is not None and {"M_data", "K_data", "MU", "patterns"} <= set(
        pre.estimate)
    stored = simulate(scene, pre, method="reduced").stats["error_estimate"]
    built = []

    def counting(*args, **kwargs):
        built.append(1)
        return pipeline_estimate.__dict__["_operators_from_scratch"](*args, **kwargs)

    monkeypatch.setattr(pipeline_estimate, "_operators_from_scratch",
                        pipeline_estimate.estimate_operators, raising=False)
    monkeypatch.setattr(pipeline_estimate, "estimate_operators", counting)
    again = simulate(scene, pre, method="reduced").stats["error_estimate"]
    assert built == [] and again == stored
    scratch = simulate(scene, dataclasses.replace(pre, estimate=None),
                       method="reduced").stats["error_estimate"]
    assert built == [1]
    assert scratch == pytest.approx(stored, rel=1e-10)


def test_a_run_on_the_stored_spacing_uses_the_stored_factor_and_never_factorises(monkeypatch):
    """The ``estimate`` stage stores the LDLᵀ factor of the effective stiffness at
    FACTOR_SPACING for the scene's damping. A 60 Hz run (every 3rd frame is 50 ms apart)
    solves with it and factorises nothing; its estimate equals the one with a factor made
    at run time (to round-off). Other damping, or another spacing, has no stored solver."""
    import lbshape.pipeline.estimate as pipeline_estimate
    from lbshape.pipeline.estimate import estimator

    scene = with_step(load_scene("demo"), 1.0 / 60.0, 0.3)
    pre = precompute(scene)
    est = estimator(scene, pre)
    solver = est.stored_solver(FACTOR_SPACING)
    assert solver is not None and est.stored_solver(1.0 / 15.0) is None
    other = dataclasses.replace(scene, damping=dataclasses.replace(
        scene.damping, alpha=2.0 * scene.damping.alpha + 0.1))
    assert estimator(other, pre).stored_solver(FACTOR_SPACING) is None
    rhs = np.random.default_rng(3).standard_normal(est.U.shape[0])
    matrix = est.effective_matrix(FACTOR_SPACING)
    assert np.linalg.norm(matrix @ solver(rhs) - rhs) <= 1e-12 * np.linalg.norm(rhs)

    factored, records = [], []
    original = pipeline_estimate.estimate_error
    monkeypatch.setattr(pipeline_estimate, "serial_cholesky",
                        lambda *a, **k: factored.append("sparse"))
    monkeypatch.setattr(ResidualErrorEstimator, "dense_solver",
                        lambda *a, **k: factored.append("dense"))
    monkeypatch.setattr(pipeline_estimate, "estimate_error",
                        lambda sc, pr, record, *a, **k: records.append(record)
                        or original(sc, pr, record, *a, **k))
    run = simulate(scene, pre, method="reduced")
    assert factored == [] and len(records) == 1 and run.stats["error_estimate"] > 0
    monkeypatch.undo()
    times, Q, Qdot = select_frames(records[0].times, records[0].states)
    assert times[1] - times[0] == pytest.approx(FACTOR_SPACING)
    fresh = estimator(scene, pre)
    at_run_time = fresh.estimate(times, Q, fresh.dense_solver(FACTOR_SPACING), Qdot=Qdot,
                                 size=fresh.size(records[0].states))
    assert run.stats["error_estimate"] == pytest.approx(at_run_time.value, rel=1e-10)
