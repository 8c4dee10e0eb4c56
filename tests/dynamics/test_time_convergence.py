"""A free body pulled by two examples converges in dt at the order of its scheme.

The example target is evaluated at the scheme's predicted end of the step, where the
step's other forces act: held from the start of the step it would be a first-order
force in a second-order scheme. A bar spinning in empty space (no contact, whose own
sources of error are first order) pulled between an arc and a twist, run at dt, dt/2
and dt/4 over the same 0.1 s, in both methods, in whole steps (the reduced body's
``flight_dt`` = dt: the scheme's own order): the error of dt against dt/4 is small
and falls from dt to dt/2 by more than the first-order ratio 3 (second order: 5).
"""

from __future__ import annotations

import pytest
from conftest import golden

from lbshape.analysis.norms import trajectory_error
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import full_simulation, reduced_simulation
from lbshape.scene.reader import scene_from_dict

#: the bar of test_free_body_examples.py, pulled between two examples
PULLED = {
    "object": {"shape": "demo-bar"},
    "material": {"young": 2e5, "density": 1000.0},
    "damping": {"beta": 0.0},
    "reduced": {"m": 6, "r": 12, "s": 30},
    "examples": {"stiffness": 5e4, "pose": [
        {"shape": "demo-bar", "pose": "arc", "parameters": {"angle": 0.8, "axis": "z",
                                                           "direction": "x"}},
        {"shape": "demo-bar", "pose": "twist", "parameters": {"angle": 0.8, "axis": "z"}}]},
    "initial": {"velocity": [0.3, 0.0, 0.0], "angular_velocity": [0.0, 2.0, 1.0]},
}
DT, STEPS = 0.002, 50


def flight(method: str, dt: float) -> dict:
    """The ``[simulation]`` key of whole steps in flight (the reduced method's only)."""
    return {"flight_dt": dt} if method == "reduced" else {}


@pytest.mark.slow
@pytest.mark.parametrize("method", ["reduced", "full"])
def test_a_pulled_free_body_converges_in_dt(method):
    runs, pre = {}, None
    for n in (1, 2, 4):
        scene = scene_from_dict({**PULLED, "simulation": {"dt": DT / n, "steps": STEPS * n,
                                                        **flight(method, DT / n)}},
                                name="pulled-bar")
        pre = pre or precompute(scene)
        engine = (reduced_simulation if method == "reduced" else full_simulation)(scene, pre)
        record = engine.run(STEPS * n, stride=n)
        assert record.stable, record.message
        runs[n] = (engine.displacements(record), record.times)
    mass = mass_matrix(pre.mesh, pre.material.density)
    fine, times = runs[4]
    errors = [trajectory_error(runs[n][0], fine, mass, times=runs[n][1], times_full=times)
              for n in (1, 2)]
    assert errors[0] < golden("time_convergence.error_at_dt").limit, errors
    ratio = errors[0] / errors[1]
    assert ratio > golden("time_convergence.refinement_ratio").limit, errors
