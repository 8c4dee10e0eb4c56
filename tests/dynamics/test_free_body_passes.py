"""A free body's step in passes (:mod:`lbshape.dynamics.free_body_passes`): in flight as many
as resolve the deformation's highest frequency, the example spring's included."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from test_free_body import Body

from lbshape.dynamics.free_body_passes import FLIGHT_PERIOD_ERROR, passes, resolved_pass
from lbshape.errors import LbshapeError
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import reduced_simulation
from lbshape.scene import load_scene
from lbshape.scene.variants import with_step, without_examples


@pytest.fixture(scope="module")
def soft():
    return Body()


def test_resolved_pass_holds_newmarks_period_error():
    """Newmark (average acceleration) turns ω into ``2 atan(ω h / 2) / h``: at the resolved
    pass the period is long by :data:`FLIGHT_PERIOD_ERROR` (to its leading order, (ω h)²/12);
    ω combines the basis's highest mode and the example spring (per unit mass)."""
    omega_max, k_ex = 313.0, 3.0e5
    h = resolved_pass(omega_max, k_ex)
    omega = math.sqrt(omega_max**2 + k_ex)
    elongation = omega * h / (2.0 * math.atan(omega * h / 2.0)) - 1.0
    assert 0.97 * FLIGHT_PERIOD_ERROR <= elongation <= FLIGHT_PERIOD_ERROR, elongation
    assert resolved_pass(None, 0.0) == math.inf and resolved_pass(None, 4.0) == \
        pytest.approx(math.sqrt(12.0 * FLIGHT_PERIOD_ERROR) / 2.0)
    assert passes(1e-3, h) == 2 and passes(1e-3, math.inf) == 1
    assert passes(1e-3, 2.5e-4) == 4  # round-off of 1e-3 / 2.5e-4 does not add one
    assert passes(1e-3, 1.0 / 3000.0) == 3 and passes(1.0 / 60.0, 1.0 / 3000.0) == 50


def test_flight_passes_are_steps_of_their_length(soft):
    """A step of Δt in k flight passes is k steps of Δt/k to round-off (a spinning,
    vibrating body, no contact), and the default passes follow ``omega_max``."""
    q0 = 0.02 * np.arange(1, 9) / 8.0
    options = dict(velocity=(1.0, 0.0, 0.5), angular_velocity=(3.0, 1.0, 8.0), q0=q0,
                   beta=1e-3)
    passed = soft.simulation(dt=3e-3, flight_dt=1e-3, **options)
    fine = soft.simulation(dt=1e-3, **options)
    assert (passed.flight_passes, fine.flight_passes) == (3, 1)
    for _ in range(40):
        passed.step()
        for _ in range(3):
            fine.step()
        assert passed.substeps == 3
    assert passed.time == pytest.approx(fine.time, abs=1e-12)
    np.testing.assert_allclose(passed.q, fine.q, rtol=0, atol=1e-10 * np.abs(fine.q).max())
    np.testing.assert_allclose(passed.rigid.angular_momentum, fine.rigid.angular_momentum,
                               rtol=1e-12)
    whole = soft.simulation(dt=3e-3, **options)
    for _ in range(40):
        whole.step()
    assert np.abs(whole.q - fine.q).max() > 1e-4 * np.abs(fine.q).max()  # the test can fail
    assert soft.simulation(dt=1e-3, omega_max=700.0).flight_passes == 3  # ω h = 0.7 > 0.35
    assert soft.simulation(dt=1e-3, omega_max=300.0).flight_passes == 1
    # a stiff body's passes stop at the contact's: no more passes in flight than in contact
    assert soft.simulation(dt=1e-3, omega_max=5000.0).flight_passes == 3
    assert soft.simulation(dt=1e-3, omega_max=5000.0, contact_dt=1e-3).flight_passes == 1
    for bad in (0.0, -1e-3, float("nan")):
        with pytest.raises(LbshapeError, match="flight_dt must be > 0 s"):
            soft.simulation(dt=1e-3, flight_dt=bad)


def test_car_flight_resolves_its_example_spring():
    """The car with examples (k_ex = 3e5/s²: √k_ex = 548 rad/s) takes 2 passes a 1 ms step
    in flight, without examples (313 rad/s) one; at 60 Hz 31 and 16 (16 at the ramp's
    start). Over its 0.12 s of flight before the wall its deformation q ends within 0.5 %
    of the run at dt/4 (measured 0.17 %); in whole 1 ms steps it is 2.5 % off (Newmark's
    period of its highest frequency 3 % long)."""
    car = load_scene("car")
    pre = precompute(car)

    def run(dt, **simulation):
        scene = with_step(car, dt, 0.12)
        scene = dataclasses.replace(scene, simulation=dataclasses.replace(
            scene.simulation, **simulation))
        engine = reduced_simulation(scene, pre)
        assert engine.run(scene.simulation.steps).stable
        return engine

    fine, passed, whole = run(2.5e-4), run(1e-3), run(1e-3, flight_dt=1e-3)
    assert (fine.flight_passes, passed.flight_passes, whole.flight_passes) == (1, 2, 1)
    assert passed.time == pytest.approx(fine.time) and np.abs(fine.q).max() > 1e-3

    def error(engine):
        return np.linalg.norm(engine.q - fine.q) / np.linalg.norm(fine.q)

    assert error(passed) <= 0.005, error(passed)
    assert error(whole) >= 5 * error(passed), (error(whole), error(passed))
    sixty = reduced_simulation(with_step(car, 1 / 60, 0.1), pre)  # its pull ramps from 0
    assert sixty.flight_passes == 16
    assert passes(sixty.dt, resolved_pass(sixty.omega_max, sixty.configured_k_ex)) == 31
    bare = without_examples(car)
    assert reduced_simulation(bare, pre).flight_passes == 1
    assert reduced_simulation(with_step(bare, 1 / 60, 0.1), pre).flight_passes == 16
