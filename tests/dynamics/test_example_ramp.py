"""The example force ramped in from t = 0 (``[examples] ramp``).

``k_ex(t) = k_ex s(min(1, t/T))``, ``s(x) = 3x² − 2x³``, in every engine that applies the
example force — the reduced fixed engine, the reduced free body and the full-space
reference — at the step's end time, in the pull and the spring alike; ``ramp = 0`` is the
engine without a ramp, state for state; a bad value is refused in one line (exit 2).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import lbshape
from lbshape.cli import main
from lbshape.dynamics.example_ramp import check_ramp, ramp_factor
from lbshape.dynamics.free_body import FreeBodySimulation
from lbshape.dynamics.free_body_ramp import RampedFreeBody
from lbshape.errors import LbshapeError
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import full_simulation, reduced_simulation
from lbshape.scene import load_scene
from lbshape.scene.reader import scene_from_dict

#: a free bar in empty space pulled by a strong arc example
FREE = {
    "object": {"shape": "demo-bar"},
    "material": {"young": 2e5, "density": 1000.0},
    "damping": {"beta": 0.0},
    "reduced": {"m": 6, "r": 12, "s": 30},
    "examples": {"stiffness": 5e4, "ramp": 0.02, "pose": [
        {"shape": "demo-bar", "pose": "arc", "parameters": {"angle": 0.8, "axis": "z",
                                                           "direction": "x"}}]},
    "initial": {"velocity": [0.3, 0.0, 0.0], "angular_velocity": [0.0, 2.0, 1.0]},
    "simulation": {"dt": 0.002, "steps": 20},
}
RAMP = 0.02  # s, 10 steps of the scenes' 2 ms


def _with_ramp(scene, ramp: float):
    return dataclasses.replace(scene, examples=dataclasses.replace(scene.examples, ramp=ramp))


def _demo(ramp: float):
    scene = load_scene("demo")
    return _with_ramp(dataclasses.replace(
        scene, simulation=dataclasses.replace(scene.simulation, dt=0.002)), ramp)


def test_ramp_factor_is_a_c1_smoothstep():
    T = 0.05
    assert ramp_factor(0.0, T) == 0.0 and ramp_factor(-1.0, T) == 0.0
    assert ramp_factor(T / 4, T) == pytest.approx(3 / 16 - 2 / 64)
    assert ramp_factor(T / 2, T) == pytest.approx(0.5)
    assert ramp_factor(T, T) == 1.0 and ramp_factor(3 * T, T) == 1.0
    assert ramp_factor(0.3, 0.0) == 1.0  # no ramp
    h = 1e-7  # the rate is zero at both ends (C¹) and 1.5/T in the middle
    for t, rate in ((0.0, 0.0), (T, 0.0), (T / 2, 1.5 / T)):
        slope = (ramp_factor(t + h, T) - ramp_factor(t - h, T)) / (2 * h)
        assert slope == pytest.approx(rate, abs=1e-4 / T), (t, slope)


@pytest.mark.parametrize("value", [-0.01, float("inf"), float("nan"), True, "slow"])
def test_bad_ramps_are_refused(value):
    with pytest.raises(LbshapeError, match="ramp") as caught:
        check_ramp(value)
    assert "\n" not in str(caught.value)
    data = {**FREE, "examples": {**FREE["examples"], "ramp": value}}
    with pytest.raises(LbshapeError, match=r"examples\.ramp") as caught:
        scene_from_dict(data, name="bad")
    assert "\n" not in str(caught.value)


def test_a_bad_ramp_exits_2_in_one_line(tmp_path, capsys):
    text = (load_scene("demo").source.read_text()
            .replace("stiffness = 8000.0", "stiffness = 8000.0\nramp = -0.5"))
    path = tmp_path / "ramped.toml"
    path.write_text(text)
    assert main(["simulate", str(path), "--steps", "1", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "examples.ramp" in err[0], err


def _step_beside_by_hand(sim, by_hand, k: float, steps: int) -> None:
    """Step the ramped engine and an unramped one whose k_ex is switched by hand to
    k s(t₁) before each step; the ramped one's k_ex is k s(t) after each."""
    driver = by_hand.driver
    for _ in range(steps):
        by_hand.set_example_force(driver, k * ramp_factor(by_hand.time + by_hand.dt, RAMP))
        by_hand.step()
        sim.step()
        assert sim.k_ex == pytest.approx(k * ramp_factor(sim.time, RAMP), rel=1e-14)


@pytest.mark.slow
def test_reduced_engine_pulls_with_the_ramped_stiffness():
    scene = _demo(RAMP)
    pre = precompute(scene)
    sim = reduced_simulation(scene, pre)
    k = float(scene.examples.stiffness)
    patterns = [(load.pattern, load.profile) for load in sim.loads]
    assert sim.k_ex == 0.0
    for _ in range(12):
        sim.step()
        expected = k * ramp_factor(sim.time, RAMP)
        loads = sum(profile(sim.time) * pattern for pattern, profile in patterns)
        # the pull k(t) q* and the spring k(t) q of the step (its Newton coefficients)
        assert sim.k_ex == pytest.approx(expected, rel=1e-14)
        assert sim._coefficients[5] == sim.k_ex
        np.testing.assert_allclose(sim._fext_old - loads, expected * sim.q_target,
                                   rtol=1e-12, atol=1e-12 * np.abs(loads).max())
    assert sim.k_ex == k  # past the ramp
    # the same as the unramped engine with k_ex switched by hand at each step
    by_hand = reduced_simulation(_demo(0.0), pre)
    sim.reset()
    assert sim.k_ex == k  # a reset restarts the ramp at the next step
    _step_beside_by_hand(sim, by_hand, k, 12)
    np.testing.assert_allclose(sim.x, by_hand.x, rtol=1e-10, atol=1e-14)
    plain = reduced_simulation(_demo(0.0), pre)
    plain.run(12)
    assert np.linalg.norm(plain.x - sim.x) > 1e-3 * np.linalg.norm(plain.x)
    # the public API (and the live window, which steps it) ramps the same engine
    api = lbshape.simulation(scene, pre, method="reduced")
    api.step()
    assert api.engine.k_ex == pytest.approx(k * ramp_factor(scene.simulation.dt, RAMP))


@pytest.mark.slow
def test_free_body_pulls_with_the_ramped_stiffness():
    scene = scene_from_dict(FREE, name="free-ramp")
    pre = precompute(scene)
    sim = reduced_simulation(scene, pre)
    assert type(sim) is RampedFreeBody
    assert type(reduced_simulation(_with_ramp(scene, 0.0), pre)) is FreeBodySimulation
    k = float(scene.examples.stiffness)
    by_hand = reduced_simulation(_with_ramp(scene, 0.0), pre)
    _step_beside_by_hand(sim, by_hand, k, 14)
    np.testing.assert_allclose(sim.q, by_hand.q, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(sim.rigid.rotation, by_hand.rigid.rotation, rtol=1e-12)
    plain = reduced_simulation(_with_ramp(scene, 0.0), pre)
    plain.run(14)
    assert np.linalg.norm(plain.q - sim.q) > 1e-3 * np.linalg.norm(plain.q)
    # the full reference ramps the same stiffness
    full = full_simulation(scene, pre)
    for _ in range(3):
        full.step()
        assert full._k_ex == pytest.approx(k * ramp_factor(full.time, RAMP), rel=1e-14)


@pytest.mark.slow
def test_full_engine_pulls_with_the_ramped_stiffness():
    scene = _demo(RAMP)
    pre = precompute(scene)
    engine = full_simulation(scene, pre)
    k = float(scene.examples.stiffness)
    for _ in range(4):
        engine.step()
        expected = k * ramp_factor(engine.time, RAMP)
        x = engine.stepper.x
        u = engine.full_displacement(x).reshape(-1)
        # the spring k(t) M x (free dofs) and the pull k(t) M L c* of the step
        spring = engine._force(x) - engine._compiled.force(u)
        np.testing.assert_allclose(spring, expected * (engine._mass_ff @ x),
                                   rtol=1e-9, atol=1e-9 * np.abs(spring).max())
        assert engine._k_ex == pytest.approx(expected, rel=1e-14)
        np.testing.assert_allclose(engine._b, expected * (engine._mass_target
                                                          @ engine.target_coefficients),
                                   rtol=1e-12)
        K = engine._force_and_tangent(x)[1].copy()  # the tangent holds k(t) M
        K0 = engine._compiled.force_and_tangent(u)[1].copy()
        dx = np.linspace(-1.0, 1.0, x.size)
        np.testing.assert_allclose((K - K0) @ dx, expected * (engine._mass_ff @ dx),
                                   rtol=1e-9, atol=1e-9 * expected)


@pytest.mark.slow
def test_ramp_zero_is_no_ramp_state_for_state():
    scene = load_scene("demo")
    pre = precompute(scene)
    zero = _with_ramp(scene, 0.0)
    assert scene.examples.ramp == 0.0
    assert "example_ramp" not in scene.runtime_fields()
    a, b = reduced_simulation(scene, pre), reduced_simulation(zero, pre)
    a.run(30)
    b.run(30)
    assert np.array_equal(a.x, b.x)
    free = scene_from_dict(FREE, name="free-ramp")
    free_pre = precompute(free)
    plain = {**FREE, "examples": {k: v for k, v in FREE["examples"].items() if k != "ramp"}}
    a = reduced_simulation(scene_from_dict(plain, name="free"), free_pre)
    b = reduced_simulation(_with_ramp(free, 0.0), free_pre)
    assert type(a) is type(b) is FreeBodySimulation
    a.run(20)
    b.run(20)
    assert np.array_equal(a.q, b.q)
    a, b = full_simulation(scene, pre), full_simulation(zero, pre)
    a.run(5)
    b.run(5)
    assert np.array_equal(a.stepper.x, b.stepper.x)
