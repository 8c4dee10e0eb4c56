"""Runs stop only when their state is wrong (:mod:`lbshape.dynamics.sanity`).

A slender Neo-Hookean bar (0.05 × 0.05 × 1 m, E = 1 MPa: Euler load of the clamped-free
column π² E I / (4 L²) = 1.3 N) under a compressive ramp hundreds of times beyond its
Euler load buckles and folds past its clamp: its RMS displacement exceeds its own size
(the bound that used to stop such runs) and it runs to the end in the reduced and the
full method. A state that is wrong — a NaN load, an unchecked Newton at a huge step, an
inverted Neo-Hookean element, energy beyond what the loads put in — stops the run with
one line naming the step, and a load far beyond what the object carries is named as the
likely cause instead of advising a smaller step.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import re

import numpy as np
import pytest

from lbshape.dynamics.full import FullSpaceSimulator
from lbshape.dynamics.loads import TimedLoad, TimeProfile
from lbshape.dynamics.reduced import ReducedSimulation
from lbshape.dynamics.sanity import (
    COARSE_STEP,
    ENERGY_FACTOR,
    LOAD_BEYOND,
    LoadReach,
    coarse_step,
    failure_advice,
    forbids_inversion,
)
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.geometry.primitives import structured_box
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import (
    full_simulation,
    load_patterns,
    reduced_force_model,
    reduced_simulation,
    simulate,
)
from lbshape.scene.build import scene_from_mesh

#: the slender bar, clamped at its top (z = 1 m)
BAR = structured_box((0.05, 0.05, 1.0), (2, 2, 16))
SIZE = float(np.linalg.norm(BAR.points.max(axis=0) - BAR.points.min(axis=0)))
#: its Euler load, clamped-free: π² E I / (4 L²) with I = a⁴/12 (N)
EULER = math.pi**2 * 1e6 * 0.05**4 / 12 / 4


def bar_scene(force: float, *, model: str = "neohookean", dt: float = 0.001,
              steps: int = 1500):
    """The bar pushed at its free end towards the clamp by ``force`` N (ramped over 0.5 s,
    2 % sideways: the imperfection that picks the buckling direction)."""
    return scene_from_mesh(
        BAR, name="slender-bar", fixed="z > 0.999",
        material={"model": model, "young": 1e6, "poisson": 0.3, "density": 1000.0},
        damping={"alpha": 0.5, "beta": 0.005}, reduced={"m": 6, "r": 16, "s": 30},
        loads=[{"type": "region_force", "vector": [0.02 * force, 0.0, force],
                "region": "z < 0.001", "profile": "ramp", "start": 0.0, "duration": 0.5}],
        dt=dt, steps=steps)


@pytest.fixture(scope="module")
def bar():
    scene = bar_scene(500.0)
    return scene, precompute(scene)


def _rms(frames: np.ndarray) -> np.ndarray:
    """(f,) RMS vertex displacement of frames (f, n, 3) in m."""
    return np.sqrt((frames**2).sum(axis=2).mean(axis=1))


def _one_line_at_step(message: str, pattern: str) -> None:
    assert "\n" not in message and re.search(r"at step \d+ \(t = ", message), message
    assert re.search(pattern, message), message


# --------------------------------------------------------------------------- buckling
@pytest.mark.slow
def test_buckled_bar_folds_beyond_its_size_and_runs_to_the_end_reduced(bar):
    scene, pre = bar
    assert 500.0 > 300 * EULER
    record = reduced_simulation(scene, pre).run(scene.simulation.steps, stride=10)
    assert record.stable, record.message
    assert record.steps == scene.simulation.steps
    frames = record.displacements(pre.U)
    assert _rms(frames).max() > SIZE  # beyond the bound that stopped it before
    assert np.linalg.norm(frames, axis=2).max() > 1.0  # the free end passed the clamp's level


@pytest.mark.slow
def test_buckled_bar_folds_beyond_its_size_and_runs_to_the_end_full(bar):
    """The full method (every element checked for inversion at every step)."""
    scene, pre = bar
    scene = bar_scene(300.0)  # the same precompute: the full method reads only the mesh
    record = full_simulation(scene, pre).run(scene.simulation.steps, stride=10)
    assert record.stable, record.message
    assert _rms(record.displacements()).max() > SIZE


# ---------------------------------------------------------------------- wrong states
@dataclasses.dataclass(frozen=True)
class _NanAfter(TimeProfile):
    """A constant profile that turns NaN after ``after`` s (a corrupted load)."""

    after: float = 0.0

    def __call__(self, t: float) -> float:
        return math.nan if t > self.after + 1e-12 else 1.0


def test_a_nan_load_stops_every_engine_naming_the_step(bar):
    scene, pre = bar
    pattern = load_patterns(scene, pre, mass_matrix(pre.mesh, pre.material.density))[0].pattern
    profile = _NanAfter(after=0.01)
    reduced = ReducedSimulation(reduced_force_model(pre), r=pre.r, dt=0.001,
                                loads=[TimedLoad(pre.U.T @ pattern, profile)], basis=pre.U,
                                rest_points=pre.mesh.points).run(50)
    full = FullSpaceSimulator(pre.mesh, pre.material, dt=0.001,
                              fixed_vertices=pre.fixed_vertices,
                              loads=[TimedLoad(pattern, profile)]).run(50)
    for record in (reduced, full):
        assert not record.stable and record.steps == 10
        _one_line_at_step(record.message, r"non-finite .*at step 11 \(t = 0\.011 s\)")


def test_an_unchecked_newton_at_a_huge_step_stops_naming_the_step(bar):
    scene, pre = bar
    stepped = bar_scene(500.0, dt=0.05, steps=30)
    record = reduced_simulation(stepped, pre, newton_iterations=1).run(30)
    assert not record.stable and record.steps < 30
    _one_line_at_step(record.message, r"(inverted|energy blew up|non-finite)")


def test_energy_beyond_the_work_done_stops_the_run():
    """StVK (no inversion check): an unchecked Newton at 50 ms pumps energy in that the
    loads never did; the monitor (its potential tracked by the force's work) stops it."""
    scene = bar_scene(500.0, model="stvk", dt=0.05, steps=30)
    pre = precompute(scene)
    record = reduced_simulation(scene, pre, newton_iterations=1).run(30)
    assert not record.stable
    _one_line_at_step(record.message, rf"energy blew up at step \d+ .* {ENERGY_FACTOR:g} x budget")
    # StVK may invert: a load far beyond the bar's capacity runs, with a warning
    crushed = simulate(bar_scene(1e6, model="stvk", steps=3), pre, method="reduced")
    assert crushed.stats["stable"]
    assert [w for w in crushed.stats["warnings"] if w.startswith(
        "at its peak the load (1e+06 N) is far beyond what the object carries (~")]


def test_an_inverted_neo_hookean_element_stops_naming_the_step_and_the_load(bar):
    """1e6 N ramped on the bar: elements invert within milliseconds; the message names
    the step and the load as the likely cause, never a smaller step."""
    scene, pre = bar
    crushed = bar_scene(1e6, steps=200)
    for record in (reduced_simulation(crushed, pre).run(200),
                   full_simulation(crushed, pre).run(200)):
        assert not record.stable
        _one_line_at_step(record.message, r"an element inverted at step \d+ .*det F = -")
        assert re.search(r"the load \(\S+ N at this step, of 1e\+06 N\) is far beyond what "
                         r"the object carries \(~\S+ N at 100 % strain", record.message)
        assert "lower dt" not in record.message


def test_only_a_material_that_forbids_inversion_stops_on_it():
    assert forbids_inversion("neohookean") and not forbids_inversion("stvk")


# ------------------------------------------------------------------ advice, coarse dt
def test_the_load_advice_names_the_load_not_the_step():
    reach = LoadReach((1e6,), (0.5,))  # a strain of 50 % at the full load: carried
    assert reach.beyond([1.0]) is None
    reach = LoadReach((1e6,), (40.0,))
    text = failure_advice(reach=reach, scales=[1.0], omega_max=100.0, dt=0.1)
    assert text.startswith("the load (1e+06 N) is far beyond what the object carries "
                           "(~2.5e+04 N at 100 % strain"), text
    assert "lower dt" not in text
    # not the load: a coarse step is named only when it is coarse
    assert "lower dt" in failure_advice(reach=None, scales=[], omega_max=100.0, dt=0.1)
    assert failure_advice(reach=None, scales=[], omega_max=100.0, dt=0.01) == ""
    assert failure_advice(reach=LoadReach((1.0,), (LOAD_BEYOND / 2,)),
                          scales=[1.0], omega_max=None, dt=0.1) == ""


def test_a_coarse_step_is_warned_once_and_listed_in_the_stats(bar, caplog):
    scene, pre = bar
    omega = math.sqrt(float(np.max(pre.elastic.omega2)))
    assert coarse_step(omega, 0.001) is None and omega * 0.001 < COARSE_STEP
    coarse = bar_scene(500.0, dt=0.1, steps=3)
    with caplog.at_level(logging.WARNING, logger="lbshape"):
        output = simulate(coarse, pre, method="reduced")
    warned = [record.getMessage() for record in caplog.records
              if "is coarse for this basis" in record.getMessage()]
    assert len(warned) == 1, warned
    assert output.stats["warnings"] == warned
    assert "dt = 0.1 s is coarse" in warned[0] and "steps per period" in warned[0]
    assert simulate(bar_scene(500.0, steps=3), pre, method="reduced").stats["warnings"] == []
