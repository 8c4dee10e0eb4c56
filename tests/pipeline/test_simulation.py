"""End to end: scenes -> precompute (cached) -> reduced / full simulation."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from conftest import golden

from lbshape.cli import main
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import simulate
from lbshape.scene import load_scene


@pytest.fixture(scope="module")
def demo():
    """The demo scene and its precompute, in the session's private cache."""
    scene = load_scene("demo")
    return scene, precompute(scene)


def _m_norm(u, mass):
    flat = u.reshape(u.shape[0], -1)
    return np.sqrt(np.einsum("ti,ti->t", flat, (mass @ flat.T).T))


def test_precompute_is_cached_and_runtime_changes_reuse_it(demo, caplog):
    scene, pre = demo
    again = precompute(scene)
    assert again.stages.from_cache and again.key == pre.key
    np.testing.assert_array_equal(again.U, pre.U)
    # runtime-only changes keep the key
    faster = dataclasses.replace(
        scene, simulation=dataclasses.replace(scene.simulation, dt=2e-3, steps=5))
    assert precompute(faster).key == pre.key
    # a precompute field changes it, and so does k_ex (the example responses are shifted
    # by it)
    other = dataclasses.replace(scene, reduced=dataclasses.replace(scene.reduced, s=10))
    from lbshape.pipeline.precompute_key import scene_cache_key

    assert scene_cache_key(other) != pre.key
    softer = dataclasses.replace(scene, examples=dataclasses.replace(scene.examples,
                                                                     stiffness=1.0))
    assert scene_cache_key(softer) != pre.key


def test_mesh_file_change_invalidates_the_cache(tmp_path):
    from lbshape.geometry.shapes import write_shape

    mesh_path = tmp_path / "bar.msh"
    write_shape("demo-bar", mesh_path)
    scene_path = tmp_path / "bar.toml"
    scene_path.write_text(
        '[object]\nmesh = "bar.msh"\n[reduced]\nm = 4\nr = 6\ns = 8\n'
        '[fixed]\nregion = "z > 0.999"\n[simulation]\nsteps = 3\n'
    )
    first = precompute(load_scene(str(scene_path)))
    assert not first.stages.from_cache
    assert precompute(load_scene(str(scene_path))).stages.from_cache
    data = bytearray(mesh_path.read_bytes())
    data[-20:-19] = b" " if data[-20:-19] != b" " else b"\n"  # one byte, same mesh
    mesh_path.write_bytes(bytes(data))
    assert not precompute(load_scene(str(scene_path))).stages.from_cache


def test_examples_pull_the_object_to_the_example_shape(demo):
    """No loads, one example, k_ex far above the basis' stiffest mode: the object
    settles at the static balance f_int(q) = k_ex (q_1 − q), close to the example."""
    from lbshape.elastic.reduced_forces import ReducedForceModel

    scene, _ = demo
    # no loads, one example: its own precompute (the basis holds the responses to the
    # scene's loads and example pulls, shifted by k_ex: the value of k_ex is part of the
    # key, so the stiffest mode is read off a first precompute)
    quiet = dataclasses.replace(
        scene, loads=(), examples=dataclasses.replace(scene.examples,
                                                      poses=scene.examples.poses[:1]))
    first = precompute(quiet)
    stiffest = float(np.linalg.eigvalsh(ReducedForceModel(
        first.mesh.points, first.mesh.tets, first.material, first.U,
        first.elastic.cubature_elements,
        first.elastic.cubature_weights).tangent(np.zeros(first.r))).max())
    k_ex = 100.0 * stiffest
    quiet = dataclasses.replace(
        quiet, examples=dataclasses.replace(quiet.examples, stiffness=k_ex),
        damping=dataclasses.replace(scene.damping, alpha=2.0 * np.sqrt(k_ex)))
    pre1 = precompute(quiet)
    elastic = ReducedForceModel(pre1.mesh.points, pre1.mesh.tets, pre1.material, pre1.U,
                                pre1.elastic.cubature_elements, pre1.elastic.cubature_weights)
    out = simulate(quiet, pre1, steps=300)
    assert out.stats["stable"]
    # the example in reduced coordinates, through the precompute's target basis
    q1 = pre1.examples.lb_to_reduced_for(clamped=pre1.examples.target_boundary == "clamped") \
        @ pre1.examples.example_coefficients[0].ravel()
    # the static balance, by Newton in the reduced space
    q = q1.copy()
    for _ in range(30):
        f, K = elastic.force_and_tangent(q)
        q -= np.linalg.solve(K + k_ex * np.eye(pre1.r), f + k_ex * (q - q1))
    u_balance = (pre1.U @ q).reshape(-1, 3)
    u_example = (pre1.U @ q1).reshape(-1, 3)
    settled = np.linalg.norm(out.displacements[-1] - u_balance) / np.linalg.norm(u_balance)
    near = np.linalg.norm(u_balance - u_example) / np.linalg.norm(u_example)
    assert settled < 1e-3, f"final shape is {settled:.2e} away from the static balance"
    assert near < 0.05, f"the balance is {near:.2%} away from the example"


def test_zero_example_stiffness_has_no_effect(demo):
    from lbshape.pipeline.simulate import reduced_simulation

    scene, pre = demo
    off = dataclasses.replace(scene, examples=dataclasses.replace(scene.examples, stiffness=0.0))
    assert reduced_simulation(off, pre).driver is None
    without = dataclasses.replace(scene, examples=None)
    pre_without = precompute(without)
    # k_ex = 0 appends no example responses: the basis is the one without examples
    pre_off = precompute(off)
    np.testing.assert_array_equal(pre_off.U, pre_without.U)
    a = simulate(off, pre_off, steps=40).displacements
    b = simulate(without, pre_without, steps=40).displacements
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-12 * max(np.abs(b).max(), 1e-30))


def test_reduced_error_against_full_falls_as_r_grows(demo):
    """Elastic response (no examples): the reduced space converges to full space.

    Measured (exact polynomial forces, the default): r = 4, 8, 24 give 0.425, 0.253,
    0.021 (r = 16 still 0.21: the basis). Limits: r = 24 below 0.07 (3.3x margin) and at
    most a fifth of the r = 4 error (measured a twentieth: 4x margin)."""
    scene, _ = demo
    scene = dataclasses.replace(scene, examples=None)
    steps = 150
    full_pre = precompute(scene)
    full = simulate(scene, full_pre, method="full", steps=steps)
    mass = mass_matrix(full_pre.mesh, scene.material.density)
    errors = []
    for r in (4, 8, 24):
        variant = dataclasses.replace(scene, reduced=dataclasses.replace(scene.reduced, r=r, s=40))
        pre = precompute(variant)
        out = simulate(variant, pre, steps=steps)
        diff = _m_norm(out.displacements - full.displacements, mass).max()
        errors.append(diff / _m_norm(full.displacements, mass).max())
    ratio = golden("simulation.error_r24_over_r4").limit
    assert errors[2] < ratio * errors[0], f"errors vs full for r=4,8,24: {errors}"
    limit = golden("simulation.reduced_error_r24").limit
    assert errors[2] < limit, f"errors vs full for r=4,8,24: {errors}"


@pytest.mark.parametrize(
    "change",
    [
        {"dt": 1.0 / 60.0},
        {"twist": np.pi},
        pytest.param({"stiffness": 1e5}, marks=pytest.mark.slow),
        pytest.param({"poisson": 0.45}, marks=pytest.mark.slow),
    ],
    ids=["dt-1/60", "twist-180", "stiff-examples", "nu-0.45"],
)
def test_hard_cases_follow_the_full_reference(demo, change):
    """Each hard case runs stable and stays on the full reference's trajectory.

    Measured (120 steps, error ``max_t ‖u − u_full‖_M / max_t ‖u_full‖_M``): dt = 1/60 s
    3.2 %, examples twisted 180° 4.4 %, k_ex = 1e5 5.5 %, ν = 0.45 5.5 %; limit 15 %
    (a run that left the physics is ≥ 100 % off: the demo moves ≈ 0.1 m)."""
    scene, _ = demo
    if "dt" in change:
        scene = dataclasses.replace(
            scene, simulation=dataclasses.replace(scene.simulation, dt=change["dt"]))
    if "twist" in change:
        poses = tuple(dataclasses.replace(p, parameters={**p.parameters, "angle": change["twist"]})
                      for p in scene.examples.poses)
        examples = dataclasses.replace(scene.examples, poses=poses)
        scene = dataclasses.replace(scene, examples=examples)
    if "stiffness" in change:
        scene = dataclasses.replace(
            scene, examples=dataclasses.replace(scene.examples, stiffness=change["stiffness"]))
    if "poisson" in change:
        scene = dataclasses.replace(
            scene, material=dataclasses.replace(scene.material, poisson=change["poisson"]))
    pre = precompute(scene)
    out = simulate(scene, pre, steps=120)
    full = simulate(scene, pre, method="full", steps=120)
    assert out.stats["stable"] and full.stats["stable"], (out.message, full.message)
    mass = mass_matrix(pre.mesh, scene.material.density)
    error = (_m_norm(out.displacements - full.displacements, mass).max()
             / _m_norm(full.displacements, mass).max())
    assert error <= golden("simulation.hard_cases_error").limit, error


def test_simulate_command_writes_contract_outputs(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["simulate", "demo", "--steps", "20", "--out", str(out), "--json"]) == 0
    stats = json.loads(capsys.readouterr().out)
    from lbshape.pipeline.estimate import STATS_KEYS as ESTIMATE_KEYS
    from lbshape.pipeline.influence import STATS_KEYS

    # the demo has examples: the contract keys, the error estimate, then the example influence
    assert list(stats) == ["scene", "method", "n_vertices", "n_tets", "m", "r", "s", "dt",
                           "steps", "t_interp_ms", "t_total_ms", "stable", "max_displacement",
                           "phase_ms", "forces", "example_stiffness", "timed_steps", "t_p95_ms",
                           "t_max_ms", "steps_over_dt", "force_model",
                           "force_elements", *ESTIMATE_KEYS, "warnings", *STATS_KEYS]
    assert stats["warnings"] == []
    assert stats["example_influence"] > 0.0
    assert json.loads((out / "stats.json").read_text()) == stats
    assert (out / "trajectory.pvd").exists() and stats["steps"] == 20
    assert main(["simulate", "no-such-scene"]) == 2
    assert capsys.readouterr().err.startswith("error: ")


def test_simulate_shows_both_runs_and_can_skip_the_influence(tmp_path, capsys):
    from lbshape.pipeline.influence import STATS_KEYS

    assert main(["simulate", "demo", "--steps", "20", "--out", str(tmp_path / "a")]) == 0
    shown = capsys.readouterr()
    err = shown.err
    # what the examples did, in the summary
    assert "simulate demo: visible change " in shown.out, shown.out
    assert "% of the bounding-box diagonal, closest: " in shown.out
    # a progress bar per run, the second one named for what it is
    assert "demo [reduced]" in err and "without examples (influence)" in err, err
    assert main(["simulate", "demo", "--steps", "20", "--out", str(tmp_path / "b"),
                 "--json", "--no-influence"]) == 0
    captured = capsys.readouterr()
    stats = json.loads(captured.out)
    assert not set(STATS_KEYS) & set(stats) and stats["steps"] == 20
    assert "without examples" not in captured.err  # no second run, no bars with --json
