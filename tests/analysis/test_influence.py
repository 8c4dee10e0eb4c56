"""The example influence: against the same scene without examples, and the eq. 5 residual."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lbshape.analysis.free_body import body_deformations
from lbshape.analysis.influence import trajectory_influence
from lbshape.analysis.twist import end_twist_degrees
from lbshape.dynamics.loads import TimedLoad, TimeProfile
from lbshape.dynamics.reduced import ReducedSimulation
from lbshape.dynamics.rigid_frame import cayley
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.errors import LbshapeError
from lbshape.geometry.poses import twist
from lbshape.geometry.primitives import structured_box
from lbshape.pipeline.influence import (
    STATS_KEYS,
    Influence,
    compare_runs,
    descriptor,
    manifold_residual,
)
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import example_influence, simulate
from lbshape.scene import load_scene
from lbshape.scene.variants import with_impact_columns, with_stiffness, without_examples


@pytest.fixture(scope="module")
def demo():
    """The demo scene and its precompute, in the session's private cache."""
    scene = load_scene("demo")
    return scene, precompute(scene)


# ----------------------------------------------------------------- the measure itself
def test_trajectory_influence_of_identical_and_of_scaled_runs():
    mass = np.eye(6)
    u = np.linspace(0.0, 1.0, 5)[:, None] * np.arange(1.0, 7.0)[None, :]
    assert trajectory_influence(u, u.copy(), mass) == (0.0, 0.0)
    final, peak = trajectory_influence(1.5 * u, u, mass)
    np.testing.assert_allclose([final, peak], [0.5, 0.5], rtol=1e-12)
    # a reference that never moves: undefined unless the example run does not move either
    assert trajectory_influence(u, np.zeros_like(u), mass) == (None, None)
    assert trajectory_influence(np.zeros_like(u), np.zeros_like(u), mass) == (0.0, 0.0)


# ----------------------------------------------------------- body frame (free bodies)
def _box():
    mesh = structured_box((0.2, 0.3, 1.0), (3, 3, 8))
    mass = mass_matrix(mesh, 1000.0)
    return mesh, mass, mass[0::3, 0::3]


def _rigidly_moved(points, deformed, rotation_vector, translation):
    """World displacement of ``deformed`` positions turned by cay(w) about the origin and moved."""
    return deformed @ cayley(np.asarray(rotation_vector)).T + np.asarray(translation) - points


def test_rigid_motion_of_a_deformed_state_does_not_change_the_body_frame_measure():
    """The best rigid fit removes any rotation and translation: the deformation of a
    state moved rigidly is the deformation of the state; the world measure sees the move."""
    mesh, mass, scalar = _box()
    X = mesh.points
    bent = twist(X, angle=0.7, axis="z", anchor="min") + 0.05 * np.sin(3.0 * X[:, [2]]) * [1, 0, 0]
    body = body_deformations(scalar, X, (bent - X)[None])[0]
    assert np.linalg.norm(body) > 0.05
    for w, c in (((0.0, 0.0, 0.0), (0.0, 0.0, 0.0)), ((0.3, -1.2, 0.7), (2.0, -1.0, 0.5)),
                 ((4.0, 0.1, -3.0), (-0.3, 0.2, 9.0))):
        moved = body_deformations(scalar, X, _rigidly_moved(X, bent, w, c)[None])[0]
        np.testing.assert_allclose(moved, body, atol=1e-12)
    # the same state, moved: zero body-frame influence, a large world one
    still = (bent - X)[None]
    flown = _rigidly_moved(X, bent, (0.2, 0.5, -0.1), (1.0, 0.0, -0.3))[None]
    final, peak = trajectory_influence(body_deformations(scalar, X, flown),
                                       body_deformations(scalar, X, still), mass, atol=1e-12)
    assert final == 0.0 and peak == 0.0
    assert trajectory_influence(flown, still, mass)[0] > 1.0
    # a rigid motion alone has no deformation
    np.testing.assert_allclose(body_deformations(scalar, X, _rigidly_moved(X, X, w, c)[None]),
                               0.0, atol=1e-12)


@pytest.mark.parametrize(("a_none", "a_ex"), [(0.01, 0.03), (0.02, -0.01), (-0.05, -0.04)])
def test_body_frame_influence_of_two_uniform_stretches_flying_differently(a_none, a_ex):
    """Hand-built: the object stretched uniformly by (1 + a) about its centre of mass, then
    turned and moved (differently in the two runs). The best fit of a uniform stretch is
    the identity, so the deformations are a·X̄ and the influence is |a_ex − a_none| / |a_none|
    whatever the two rigid motions; the world measure is not."""
    mesh, mass, scalar = _box()
    X = mesh.points
    weights = np.asarray(scalar.sum(axis=1)).ravel()
    centre = weights @ X / weights.sum()
    stretched = [centre + (1.0 + a) * (X - centre) for a in (a_ex, a_none)]
    u_ex = np.stack([_rigidly_moved(X, stretched[0], (0.0, 0.1 * t, 0.3 * t), (t, 0.0, -t))
                     for t in (0.5, 1.0)])
    u_none = np.stack([_rigidly_moved(X, stretched[1], (0.2 * t, 0.0, 0.0), (0.0, t, 0.0))
                       for t in (0.5, 1.0)])
    body_ex, body_none = (body_deformations(scalar, X, u) for u in (u_ex, u_none))
    np.testing.assert_allclose(body_ex[-1], a_ex * (X - centre), atol=1e-12)
    final, peak = trajectory_influence(body_ex, body_none, mass)
    expected = abs(a_ex - a_none) / abs(a_none)
    np.testing.assert_allclose([final, peak], [expected, expected], rtol=1e-9)
    world, _ = trajectory_influence(u_ex, u_none, mass)
    assert abs(world - expected) > 0.05 * expected  # the world measure mixes in the flight


def test_influence_frame_is_checked_and_reported():
    stats = Influence(0.7, 0.9, None, None, "body", 0.1, 0.2).stats()
    assert tuple(stats) == STATS_KEYS
    assert stats["influence_frame"] == "body" and stats["example_influence_world"] == 0.1
    with pytest.raises(LbshapeError, match="frame"):
        Influence(0.1, 0.1, frame="inertial")


class _Linear:
    """Reduced elastic model ``f = K q`` (mass-orthonormal coordinates)."""

    def __init__(self, omega2):
        self.K = np.diag(np.asarray(omega2, dtype=float))

    def force_and_tangent(self, q):
        return self.K @ q, self.K

    def energy(self, q):
        return 0.5 * float(q @ self.K @ q)


class _RestTarget:
    """An example driver whose examples are the rest shape: the target is always q* = 0."""

    def __init__(self, r):
        self.r = r

    def target(self, q):
        return type("Info", (), {"q_target": np.zeros(self.r)})()


def _settled(k_ex, *, omega2=(400.0, 900.0), steps=1500):
    force = np.array([1.0, -2.0])
    sim = ReducedSimulation(
        _Linear(omega2), r=2, dt=2e-3, alpha=80.0, loads=[TimedLoad(force, TimeProfile())],
        driver=_RestTarget(2) if k_ex else None, k_ex=k_ex)
    return np.asarray(sim.run(steps).states)


def test_influence_grows_with_k_ex_on_a_constructed_case():
    """Two modes under a constant load, examples equal to the rest shape: after the
    (heavily damped) motion settles, q = F / (ω² + k_ex), so the influence per mode is
    k_ex / (ω² + k_ex) and the total grows monotonically with k_ex."""
    omega2 = np.array([400.0, 900.0])
    force = np.array([1.0, -2.0])
    reference = _settled(0.0)
    np.testing.assert_allclose(reference[-1], force / omega2, rtol=1e-6)
    values = []
    for k_ex in (100.0, 400.0, 1600.0, 6400.0):
        with_examples = _settled(k_ex)
        final, peak = trajectory_influence(with_examples, reference, np.eye(2))
        expected = np.linalg.norm(force / omega2 - force / (omega2 + k_ex)) / np.linalg.norm(
            force / omega2)
        np.testing.assert_allclose(final, expected, rtol=1e-5, err_msg=f"k_ex={k_ex}")
        assert peak >= final - 1e-12
        values.append(final)
    assert np.all(np.diff(values) > 0), f"influence for growing k_ex: {values}"


# ------------------------------------------------------------------------- on a scene
def test_influence_is_zero_when_the_examples_are_the_rest_shape(demo):
    """Examples equal to the rest shape (twist 0 of the object itself), no loads: the
    example force never acts and the run equals the one without examples; the same
    scene with the twisted examples moves away from rest on its own."""
    scene, _ = demo
    rest_pose = dataclasses.replace(
        scene.examples.poses[0], source=scene.object,
        parameters={**scene.examples.poses[0].parameters, "angle": 0.0})
    rest_examples = dataclasses.replace(scene, loads=(), examples=dataclasses.replace(
        scene.examples, poses=(rest_pose,)))
    pre = precompute(rest_examples)
    np.testing.assert_allclose(pre.examples.example_coefficients, 0.0, atol=1e-10)
    output = simulate(rest_examples, pre, steps=60)
    effect, reference = example_influence(rest_examples, pre, output, method="reduced", steps=60)
    assert effect.final == 0.0 and effect.maximum == 0.0, effect
    assert np.abs(output.displacements).max() < 1e-12  # round-off of the alignment

    twisted = dataclasses.replace(scene, loads=())
    pre_twisted = precompute(twisted)
    moved = simulate(twisted, pre_twisted, steps=60)
    effect, reference = example_influence(twisted, pre_twisted, moved, method="reduced", steps=60)
    assert np.abs(reference.displacements).max() == 0.0
    assert np.abs(moved.displacements[-1]).max() > 0.01, "twisted examples did not move the bar"
    assert effect.final is None  # u_none = 0: relative influence undefined


@pytest.mark.slow
@pytest.mark.parametrize("method", ["reduced", "full"])
def test_free_body_influence_is_zero_when_the_examples_are_the_rest_shape(method):
    """A free bar thrown without loads, examples equal to its rest shape: it flies
    undeformed with and without them (influence 0 in the body frame, although its
    world displacement is large); an S example deforms it while the reference stays
    undeformed (undefined, None). Same measure for the reduced engine and the full one."""
    scene = load_scene("bar-s-cuboid")
    pose = scene.examples.poses[0]
    rest_pose = dataclasses.replace(pose, parameters={**pose.parameters, "amplitude": 0.0})
    thrown = dataclasses.replace(
        with_impact_columns(scene, 0), loads=(), planes=(),
        initial=dataclasses.replace(
            scene.initial, velocity=(1.0, 0.0, 0.5), angular_velocity=(0.0, 0.0, 0.0)))
    rest_examples = dataclasses.replace(thrown, examples=dataclasses.replace(
        thrown.examples, poses=(rest_pose,)))
    steps = 40
    pre = precompute(rest_examples)
    output = simulate(rest_examples, pre, method=method, steps=steps)
    effect, reference = example_influence(rest_examples, pre, output, method=method, steps=steps)
    assert effect.frame == "body"
    assert effect.final == 0.0 and effect.maximum == 0.0, effect
    assert np.abs(reference.displacements[-1]).max() > 0.03  # it flew

    pre_s = precompute(thrown)
    bent = simulate(thrown, pre_s, method=method, steps=steps)
    effect, reference = example_influence(thrown, pre_s, bent, method=method, steps=steps)
    assert effect.frame == "body" and effect.final is None, effect
    assert effect.world_final is not None and effect.world_final > 0.0


def test_influence_grows_with_k_ex_on_the_demo_scene(demo):
    """The maximum over time (the value at T depends on the phase of the oscillation)."""
    scene, pre = demo
    steps = 150
    reference = simulate(without_examples(scene), pre, steps=steps)
    values = []
    for k_ex in (500.0, 2000.0, 8000.0):
        output = simulate(with_stiffness(scene, k_ex), pre, steps=steps)
        values.append(compare_runs(pre, output, reference).maximum)
    assert np.all(np.diff(values) > 0), f"influence for k_ex 500, 2000, 8000: {values}"
    assert values[-1] >= 0.5, f"the demo's examples barely matter: {values}"


def test_simulate_reports_influence_and_the_examples_bring_the_shape_to_their_manifold(demo):
    scene, pre = demo
    output = simulate(scene, pre, influence=True)  # the scene's 0.3 s
    stats = output.stats
    assert set(STATS_KEYS) <= set(stats)
    assert stats["example_influence"] > 0.5, stats
    assert stats["example_influence_max"] >= 0.5 * stats["example_influence"], stats
    # with examples the final shape is closer to the example manifold than without
    # (observed 0.31 against 0.34)
    assert stats["example_residual"] < 0.95 * stats["example_residual_none"], stats
    plain = simulate(without_examples(scene), pre, steps=20, influence=True)
    assert not set(STATS_KEYS) & set(plain.stats)


def test_descriptor_of_an_example_is_its_descriptor_and_on_the_manifold(demo):
    _, pre = demo
    for k in range(pre.examples.example_coefficients.shape[0]):
        u = pre.examples.rest_points(k) - pre.mesh.points
        np.testing.assert_allclose(descriptor(pre, u), pre.examples.example_descriptors[k],
                                   rtol=1e-8,
                                   atol=1e-10 * np.abs(pre.examples.example_descriptors).max())
        assert manifold_residual(pre, u) < 1e-8
    # the rest shape is off the hull of a +90 / -45 degree twist pair
    assert manifold_residual(pre, np.zeros_like(pre.mesh.points)) > 0.05


# ------------------------------------------------------------------------------ twist
@pytest.mark.parametrize("angle", [-0.6, 0.3, 1.2])
def test_end_twist_of_an_analytic_twist(angle):
    mesh = structured_box((0.2, 0.2, 1.0), (4, 4, 10))
    u = twist(mesh.points, angle=angle, axis="z", anchor="max") - mesh.points
    np.testing.assert_allclose(end_twist_degrees(mesh.points, u), np.degrees(angle), rtol=1e-9)
    np.testing.assert_allclose(end_twist_degrees(mesh.points, u, end="max"), 0.0, atol=1e-9)


def test_bench_records_the_influence_of_reduced_and_full_in_table2(demo, tmp_path):
    from lbshape.studies.bench import bench_scene
    from lbshape.studies.tables import write_table2

    scene, pre = demo
    result = bench_scene(scene, steps=40, repeats=1, methods=("full", "reduced"), pre=pre)
    effects = dict(result.influence)
    assert set(effects) == {"reduced", "full"}
    for method, stats in effects.items():
        assert set(stats) == set(STATS_KEYS), method
        reference = simulate(without_examples(scene), pre, method=method, steps=40)
        run = simulate(scene, pre, method=method, steps=40)
        np.testing.assert_allclose(stats["example_influence"],
                                   compare_runs(pre, run, reference).final, rtol=1e-9)
        assert stats["influence_frame"] == "world"  # the demo bar is fixed
        assert stats["example_influence_world"] == stats["example_influence"]
    md, js = write_table2([result], tmp_path)
    assert "## Example influence" in md.read_text()
    assert (f"| demo | reduced | world | {effects['reduced']['example_influence']:.3f} |"
            in md.read_text())


@pytest.mark.parametrize("clamped", ["max", "min"])
def test_end_twist_measures_the_free_end(clamped):
    """A bar clamped at z = max (the built-in bars) or z = min (a user's tube): the free
    end turns by the angle, the clamped one not at all."""
    from lbshape.analysis.twist import free_end

    mesh = structured_box((0.2, 0.2, 1.0), (4, 4, 10))
    z = mesh.points[:, 2]
    fixed = np.flatnonzero(np.abs(z - (z.max() if clamped == "max" else z.min())) < 1e-9)
    u = twist(mesh.points, angle=0.7, axis="z", anchor=clamped) - mesh.points
    assert free_end(mesh.points, fixed) == ("min" if clamped == "max" else "max")
    np.testing.assert_allclose(end_twist_degrees(mesh.points, u, end="free", fixed=fixed),
                               np.degrees(0.7), rtol=1e-9)
    np.testing.assert_allclose(end_twist_degrees(mesh.points, u, end=clamped), 0.0, atol=1e-9)
