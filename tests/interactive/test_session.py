"""The live session's pacing (no window): a slow renderer drops frames, never simulated
time; only steps slower than the time they simulate put it behind the clock (capped).
A fake clock stands in for the wall clock: nothing here is timed."""

from __future__ import annotations

import numpy as np
import pytest

from lbshape.interactive.session import MAX_DEBT, STEP_BUDGET, LiveSession
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulation import Simulation
from lbshape.scene import load_scene


class FakeClock:
    """A wall clock that moves only when told."""

    def __init__(self):
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture(scope="module")
def demo():
    scene = load_scene("demo")
    return scene, precompute(scene, progress=False)


@pytest.fixture
def session(demo):
    session = LiveSession(*demo)
    session._clock = FakeClock()
    return session


def test_a_slow_frame_is_made_up_by_steps_not_dropped(session):
    # a renderer taking 0.5 s per frame: each frame owes 0.5 s, and all of it is stepped
    for frame in range(1, 4):
        steps = session.advance(0.5)
        assert steps == pytest.approx(0.5 / session.dt, abs=1)
        assert session.time == pytest.approx(0.5 * frame, abs=session.dt)
        assert not session.behind and session.last_steps == steps
    assert session.dropped == 0.0


def test_steps_slower_than_the_clock_fall_behind_capped(session):
    clock, step = session._clock, session.simulation.step

    def slow_step() -> int:  # each step costs twice the time it simulates
        clock.now += 2 * session.dt
        return step()

    session.simulation.step = slow_step
    taken = session.advance(1.0)
    # stepping stops once the budget is spent; what stays owed is capped
    assert taken == pytest.approx(STEP_BUDGET / (2 * session.dt), abs=2)
    assert session.behind
    assert session._debt == pytest.approx(MAX_DEBT)
    assert session.dropped == pytest.approx(1.0 - taken * session.dt - MAX_DEBT, abs=1e-9)
    session.simulation.step = step
    session.advance(0.0)  # the owed time is stepped next, and the flag clears
    assert not session.behind and session.last_steps == pytest.approx(MAX_DEBT / session.dt,
                                                                       abs=1)


def test_pause_steps_nothing_and_forgets_the_debt(session):
    session.pause(True)
    assert session.advance(1.0) == 0 and session.time == 0.0
    session.pause(False)
    assert session.advance(0.0) == 0


def test_the_session_delegates_to_a_simulation(demo, session):
    """The drag, the switch, the reset and the points are the Simulation's: the same
    calls on a Simulation give the same state bit for bit."""
    scene, pre = demo
    sim = Simulation(scene, pre, method="reduced")
    vertex, target = 5, pre.mesh.points[5] + np.array([0.1, 0.0, 0.0])
    for handle in (session, sim):
        handle.grab(vertex, target)
        for _ in range(20):
            handle.simulation.step() if handle is session else handle.step()
        handle.release()
        handle.set_examples(False)
    np.testing.assert_array_equal(session.points(), sim.points())
    assert session.drags == 1 and session.drag is None and not session.examples_on
    session.reset()
    assert session.time == 0.0 and not session.examples_on
    np.testing.assert_array_equal(session.points(), pre.mesh.points)
