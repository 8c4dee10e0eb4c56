"""The engine protocol (:mod:`lbshape.dynamics.engine`) on every engine: the reduced engine
of a fixed object, its full-space reference, a free body's reduced engine and a free body
with impact columns switched at its impacts — stepping,
runs, world displacements, snapshots and resets (bit for bit), the examples switch and a
drag."""

from __future__ import annotations

import numpy as np
import pytest

from lbshape.dynamics.engine import Drag, Engine, EngineState, NewtonSettings
from lbshape.errors import LbshapeError, SolverError
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import full_simulation, reduced_simulation
from lbshape.scene import load_scene
from lbshape.scene.reader import scene_from_dict

STEPS = 12

#: a small free bar thrown at a floor, with the demo's examples
FREE = {
    "name": "free-demo",
    "object": {"shape": "demo-bar"},
    "material": {"young": 1e6, "density": 1000.0},
    "damping": {"beta": 0.005},
    "reduced": {"m": 6, "r": 10, "s": 20},
    "initial": {"velocity": [0.0, 0.0, -1.0], "angular_velocity": [0.0, 0.0, 0.3]},
    "loads": [{"type": "gravity", "vector": [0.0, 0.0, -9.81]}],
    "planes": [{"point": [0.0, 0.0, -0.02], "normal": [0.0, 0.0, 1.0], "stiffness": 1e5}],
    "examples": {"stiffness": 2000.0, "pose": [
        {"shape": "demo-cylinder", "pose": "twist",
         "parameters": {"angle": 1.0, "axis": "z", "anchor": "max"}}]},
    "simulation": {"dt": 0.002, "steps": 100},
}


@pytest.fixture(scope="module")
def demo():
    scene = load_scene("demo")
    return scene, precompute(scene, progress=False)


@pytest.fixture(scope="module")
def free():
    scene = scene_from_dict(FREE, name="free-demo")
    return scene, precompute(scene, progress=False)


@pytest.fixture(scope="module")
def switched():
    """The free bar with 4 impact columns (:mod:`lbshape.dynamics.impact_switch`)."""
    scene = scene_from_dict({**FREE, "reduced": {**FREE["reduced"], "impact_columns": 4}},
                            name="free-demo")
    return scene, precompute(scene, progress=False)


@pytest.fixture(scope="module")
def feature_sets():
    """The free bar with 2 impact columns for each hull feature."""
    scene = scene_from_dict({**FREE, "reduced": {**FREE["reduced"], "impact_columns": 2,
                                                 "impact_columns_per": "feature"}},
                            name="free-demo")
    return scene, precompute(scene, progress=False)


@pytest.fixture(params=["reduced", "full", "free-body", "impact-switch", "feature-sets"])
def engine(request, demo, free, switched, feature_sets):
    """``(engine, precompute, scene)`` of each kind."""
    bodies = {"free-body": free, "impact-switch": switched, "feature-sets": feature_sets}
    if request.param in bodies:
        scene, pre = bodies[request.param]
        return reduced_simulation(scene, pre), pre, scene
    scene, pre = demo
    make = reduced_simulation if request.param == "reduced" else full_simulation
    return make(scene, pre), pre, scene


def _equal_records(a, b) -> None:
    np.testing.assert_array_equal(a.times, b.times)
    np.testing.assert_array_equal(a.states, b.states)
    np.testing.assert_array_equal(a.newton_iterations, b.newton_iterations)


def test_every_engine_has_the_protocol(engine):
    sim, pre, scene = engine
    assert isinstance(sim, Engine)
    assert isinstance(sim.newton, NewtonSettings) and sim.dt == scene.simulation.dt
    assert sim.time == 0.0
    iterations = sim.step()
    assert isinstance(iterations, int | np.integer) and iterations >= 0
    assert sim.time == pytest.approx(sim.dt, rel=1e-12)
    u = sim.displacement()
    assert u.shape == (pre.mesh.n_vertices, 3) and np.isfinite(u).all()
    assert np.abs(u).max() > 0


def test_run_records_and_ends_on_a_failure_without_raising(engine):
    sim, pre, _ = engine
    record = sim.run(STEPS, stride=4)
    assert record.stable and record.steps == STEPS and len(record.times) == 4
    frames = sim.displacements(record)  # the record's world displacements, every engine
    assert frames.shape == (4, pre.mesh.n_vertices, 3)
    np.testing.assert_allclose(frames[-1], sim.displacement(), rtol=0,
                               atol=1e-12 * np.abs(frames[-1]).max())
    # the timed parts of a step: named by the engine, one column each (none for full)
    assert isinstance(sim.phases, tuple)
    if sim.phases:
        assert sim.phase_seconds.shape == (STEPS, len(sim.phases))
    calls = []

    def failing() -> int:
        calls.append(1)
        raise SolverError(f"Newton did not converge at step {len(calls)} (t = 0 s)")

    sim.step = failing  # the run steps through step()
    stopped = sim.run(5)
    assert not stopped.stable and stopped.steps == 0 and "at step 1" in stopped.message
    with pytest.raises(LbshapeError):
        sim.run(0)


def test_reset_reproduces_the_run_bit_for_bit(engine):
    sim, _, _ = engine
    first = sim.run(STEPS)
    sim.reset()
    assert sim.time == 0.0
    _equal_records(sim.run(STEPS), first)
    # a snapshot in the middle of a run: the rest of the run again from it
    sim.reset()
    sim.run(STEPS // 2)
    middle = sim.state
    assert isinstance(middle, EngineState) and middle.time == sim.time
    rest = sim.run(STEPS - STEPS // 2)
    sim.reset(middle)
    assert sim.time == middle.time
    _equal_records(sim.run(STEPS - STEPS // 2), rest)


@pytest.mark.parametrize("method", ["reduced", "full"])
def test_a_state_carries_to_a_new_engine(free, method):
    """A snapshot of a free body with ramped examples, restored into a freshly built
    engine, continues the run: bit for bit in the reduced method; to round-off in the
    full one (the new engine factorises its own Newton matrices: 5e-16 m apart)."""
    scene, pre = free
    ramped = scene_from_dict({**FREE, "examples": {**FREE["examples"], "ramp": 0.05}},
                             name="free-demo")
    make = reduced_simulation if method == "reduced" else full_simulation
    first = make(ramped, pre)
    first.run(STEPS // 2)
    middle = first.state
    rest = first.run(STEPS - STEPS // 2)
    second = make(ramped, pre)
    second.reset(middle)
    again = second.run(STEPS - STEPS // 2)
    if method == "reduced":
        _equal_records(again, rest)
    else:
        scale = np.abs(rest.states).max()
        np.testing.assert_allclose(again.states, rest.states, rtol=0, atol=1e-9 * scale)


def test_examples_switch(engine):
    sim, _, _ = engine
    assert sim.set_examples(True) is True
    with_examples = sim.run(STEPS)
    assert sim.set_examples(False) is False
    sim.reset()
    without = sim.run(STEPS)
    assert not np.array_equal(without.states, with_examples.states)
    assert sim.set_examples(True) is True
    sim.reset()
    _equal_records(sim.run(STEPS), with_examples)


def test_drag_pulls_the_vertex_towards_the_target_and_lets_go(engine):
    sim, pre, _ = engine
    free_run = sim.run(STEPS)
    vertex = int(np.argmin(pre.mesh.points[:, 2]))  # a bottom vertex (free in each scene)
    u_free = sim.displacement()[vertex]
    pull = np.array([0.02, 0.0, 0.0])
    sim.reset()
    target = pre.mesh.points[vertex] + pull
    sim.set_drag(Drag(vertex, target, 2000.0 * pre.material.density * pre.mesh.volume()))
    sim.run(STEPS)
    u_dragged = sim.displacement()[vertex]
    assert (u_dragged - u_free) @ pull > 0.05 * pull @ pull
    sim.set_drag(None)
    sim.reset()
    _equal_records(sim.run(STEPS), free_run)


def test_newton_settings_are_read_at_each_step(engine):
    sim, _, _ = engine
    sim.newton = NewtonSettings(1e-15, 1)  # one update cannot reach round-off
    stopped = sim.run(STEPS)
    assert not stopped.stable and "did not converge at step 1 " in stopped.message


def test_settings_and_drag_are_checked():
    with pytest.raises(LbshapeError):
        NewtonSettings(0.0, 20)
    with pytest.raises(LbshapeError):
        NewtonSettings(1e-8, 0)
    with pytest.raises(LbshapeError):
        Drag(0, (0.0, 0.0, 0.0), 0.0)
    with pytest.raises(LbshapeError):
        Drag(-1, (0.0, 0.0, 0.0), 1.0)
    drag = Drag(np.int64(3), [1, 2, 3], 5)
    assert drag.vertex == 3 and drag.stiffness == 5.0 and drag.target.dtype == float


@pytest.mark.parametrize("kind", ["reduced", "free-body"])
@pytest.mark.parametrize("enabled", [True, False])
def test_a_reduced_run_pauses_the_garbage_collector(demo, free, kind, enabled):
    """No cyclic collection runs among a reduced run's steps, even at a threshold that
    collects at almost every allocation; after a run, a stopped one too, the collector is
    as it was (a full collection of a large process landed among the steps otherwise)."""
    import gc

    scene, pre = free if kind == "free-body" else demo
    sim = reduced_simulation(scene, pre)
    collections = []
    during = []

    def count(phase, info):
        if phase == "start":
            collections.append(info["generation"])

    threshold = gc.get_threshold()
    was = gc.isenabled()
    gc.callbacks.append(count)
    try:
        gc.enable() if enabled else gc.disable()
        gc.set_threshold(1)
        sim.run(STEPS, on_step=lambda *_: during.append(len(collections)))
        def failing() -> int:
            raise SolverError("Newton did not converge at step 1 (t = 0 s)")

        sim.step = failing  # the next run stops at its first step
        assert not sim.run(STEPS).stable
        assert gc.isenabled() is enabled
        assert len(during) == STEPS and len(set(during)) == 1, during
    finally:
        gc.callbacks.remove(count)
        gc.set_threshold(*threshold)
        gc.enable() if was else gc.disable()
