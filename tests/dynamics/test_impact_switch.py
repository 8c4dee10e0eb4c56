"""The impact switch (:mod:`lbshape.dynamics.impact_switch`) on the Figure 4 bar without
its example: the leading columns' frame, the hand-over both ways, the onset step taken
again on the columns, a slow touch left to the plain basis, and the columns on from the
impact until the body rests, beside the same run with the columns throughout."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import golden

from lbshape.analysis.norms import trajectory_error
from lbshape.dynamics.fictitious import frame_tensors
from lbshape.dynamics.impact_switch import ImpactSwitchedBody
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.errors import LbshapeError
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import reduced_simulation
from lbshape.scene.reader import load_scene
from lbshape.scene.variants import with_impact_columns, without_examples

#: the bar's first contact is at 0.287 s (dt = 1 ms)
IN_FLIGHT = 100


def _body(scene):
    """One set of 26 impact columns for the whole body (the sets per hull feature:
    ``tests/pipeline/test_impact_feature_sets.py``)."""
    return with_impact_columns(scene, 26)


@pytest.fixture(scope="module")
def bar():
    scene = _body(load_scene("bar-s-cuboid"))
    return without_examples(scene), precompute(scene, progress=False)


def _engine(bar, **options):
    scene, pre = bar
    return reduced_simulation(scene, pre, **options)


def test_the_leading_columns_frame_is_their_own_basis_frame(bar):
    _, pre = bar
    r0 = pre.elastic.leading
    own = frame_tensors(pre.mesh.points, pre.mesh.tets,
                        mass_matrix(pre.mesh, pre.material.density), pre.U[:, :r0])
    cut = pre.frame.leading(r0)
    for name in ("Y0", "G", "C", "H", "S", "translation"):
        ours, theirs = getattr(cut, name), getattr(own, name)
        np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-12 * np.abs(theirs).max())
    with pytest.raises(LbshapeError, match="no leading"):
        pre.frame.leading(pre.r + 1)


def test_a_hand_over_lifts_the_columns_to_their_static_answer_and_drops_them(bar):
    _, pre = bar
    engine = _engine(bar)
    assert isinstance(engine, ImpactSwitchedBody) and not engine.columns_on
    for _ in range(IN_FLIGHT):
        engine.step()
    plain, r0 = engine.plain, engine.leading
    before, time = plain._now.data.copy(), plain.time
    engine.switch_columns(True)
    lifted = engine.columns._now
    coupling = pre.elastic.impact_coupling
    for name in ("q", "qd", "qa"):
        value = getattr(lifted, name)
        np.testing.assert_array_equal(value[:r0], getattr(plain._now, name))
        # the columns' linear force K_zq q + K_zz z vanishes: their static answer
        load = np.abs(coupling[r0:, :r0] @ value[:r0]).max()
        assert load > 0 and np.abs(coupling[r0:] @ value).max() < 1e-9 * load
    for name in ("c", "p", "R", "L"):
        np.testing.assert_array_equal(getattr(lifted, name), getattr(plain._now, name))
    assert engine.time == time and engine.columns.steps_taken == IN_FLIGHT
    np.testing.assert_array_equal(engine.q[:r0], plain._now.q)
    engine.switch_columns(False)
    np.testing.assert_allclose(plain._now.data, before, rtol=0,
                               atol=1e-13 * np.abs(before).max())
    assert engine.onsets == 1 and engine.rests == 1


def test_an_onset_step_is_taken_again_on_the_columns(bar):
    """The step that first touches the floor, from its start, on the columns: bit for bit
    the step of an engine handed over by hand before it."""
    engine = _engine(bar)
    steps = 0
    while not engine.columns_on:
        engine.step()
        steps += 1
        assert steps < 400, "no onset"
    assert engine.onsets == 1 and engine.columns.contact.scalars[1] > 0
    again = _engine(bar)
    for _ in range(steps - 1):
        again.step()
    assert not again.columns_on and not again._touching
    again.switch_columns(True)
    again.step()
    np.testing.assert_array_equal(again.columns._now.data, engine.columns._now.data)
    assert again.time == engine.time and again.steps_taken == steps


def test_a_slow_touch_stays_on_the_plain_basis(bar):
    """Every onset slower than the design impact's share (here: all of them) leaves the
    body to the plain engine: the run is the plain engine's own, bit for bit."""
    engine = _engine(bar)
    engine.impact_energy = math.inf
    record = engine.run(600)  # past the first impact (0.287 s) and a bounce
    alone = _engine(bar).plain
    own = alone.run(600)
    r0 = engine.leading
    assert record.stable and engine.onsets == 0 and engine.column_steps == 0
    np.testing.assert_array_equal(record.states[:, :r0], own.states)
    assert not record.states[:, r0:].any()
    np.testing.assert_array_equal(record.centers, own.centers)
    assert np.abs(own.contact_depth).max() > 0


def test_the_columns_act_from_the_impact_until_the_body_rests(bar):
    """The whole run: the columns on at the impact and off once the bar rests, its
    trajectory beside the same run with the columns throughout."""
    scene, pre = bar
    steps = scene.simulation.steps
    engine = _engine(bar)
    record = engine.run(steps)
    assert record.stable and engine.onsets >= 1 and engine.rests >= 1
    assert not engine.columns_on and 0 < engine.column_steps < steps
    throughout = _engine(bar, impact_switch=False)
    assert not isinstance(throughout, ImpactSwitchedBody)
    other = throughout.run(steps)
    mass = mass_matrix(pre.mesh, pre.material.density)
    distance = trajectory_error(engine.displacements(record), throughout.displacements(other),
                                mass)
    assert distance < golden("impact_switch.rest_against_throughout").limit


def test_with_examples_the_columns_start_at_their_answer_to_the_example_spring(bar):
    """The bar with its example in flight: handed over, the columns balance their
    coupling to q and the example spring's pull to its target's columns part."""
    _, pre = bar
    engine = reduced_simulation(_body(load_scene("bar-s-cuboid")), pre)
    for _ in range(IN_FLIGHT):
        engine.step()
    k_ex, r0 = engine.plain.k_ex, engine.leading
    target = engine.plain.driver.target_entries(np.arange(r0, pre.r)).copy()
    assert k_ex > 0 and np.abs(target).max() > 0
    engine.switch_columns(True)
    q = engine.columns._now.q
    coupling = pre.elastic.impact_coupling
    balance = coupling[r0:] @ q + k_ex * (q[r0:] - target)
    scale = np.abs(k_ex * target).max() + np.abs(coupling[r0:, :r0] @ q[:r0]).max()
    assert np.abs(balance).max() < 1e-9 * scale
