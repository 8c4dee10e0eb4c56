"""The free body's contact step converges in time: the rigid kick and the deformation
solve are swept until the kick uses the trapezoidal contact impulse of the step's two
ends, so an impact does not depend on the step size.

Measured on the car thrown into the wall (no examples): before the sweeps the rebound
speed was 3.12 m/s at dt = 1 ms and 3.54 m/s at 0.25 ms (12 % apart: the kick used the
contact at the start of the step only, with the deformation lagging by a step); with
them 3.692 and 3.689 m/s (0.08 %). The car's planes now have friction (μ = 0.5): 3.578
and 3.575 m/s (0.08 %; at most 5 and 4 sweeps a step). The limit 2 % sits far from all
(``contact_sweeps.rebound_speed_difference`` in tests/golden.toml). The steps are whole
(no contact sub-steps, which would make the two runs' contact steps the same).
"""

from __future__ import annotations

import dataclasses

import pytest
from conftest import golden

from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import reduced_simulation
from lbshape.scene import load_scene
from lbshape.scene.variants import without_examples

DURATION = 0.4  # s: the car reaches the wall at ~0.14 s and leaves it by ~0.3 s


def _rebound_speed(scene, pre, dt: float) -> tuple[float, int]:
    """(largest centre-of-mass speed away from the wall in m/s, most sweeps of a step)."""
    steps = int(round(DURATION / dt))
    scene = dataclasses.replace(  # whole steps: contact_dt = dt (no contact sub-steps)
        scene, simulation=dataclasses.replace(scene.simulation, dt=dt, steps=steps,
                                              contact_dt=dt))
    sim = reduced_simulation(scene, pre)
    most = 0
    speeds = []
    for _ in range(steps):
        sim.step()
        most = max(most, sim.sweeps)
        speeds.append(sim.rigid.momentum[0] / sim.frame.mass)
    return -min(speeds), most


@pytest.mark.slow
def test_car_rebound_does_not_depend_on_the_step():
    scene = without_examples(load_scene("car"))
    pre = precompute(scene)
    coarse, sweeps = _rebound_speed(scene, pre, 1e-3)
    fine, _ = _rebound_speed(scene, pre, 2.5e-4)
    assert coarse > 1.0 and fine > 1.0  # it bounced off the wall
    assert sweeps > 1  # the impact steps were swept
    limit = golden("contact_sweeps.rebound_speed_difference").limit
    assert abs(coarse - fine) <= limit * fine, (coarse, fine)
