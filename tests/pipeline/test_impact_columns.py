"""Impact columns (``reduced.impact_columns``, :mod:`lbshape.pipeline.impact_columns`): the
key is read and refused where nothing models it, the stage appends columns from throws
at the hull's features with their own energy and a linear coupling, and the reduced free
body then holds a designed edge hit that its plain basis misses."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from conftest import golden

from lbshape.dynamics.full_examples import FullSpaceExamples
from lbshape.elastic.basis import NonlinearBasis
from lbshape.elastic.column_forces import ColumnForceModel
from lbshape.elastic.element_kernels import mass_matrix, tangent_stiffness
from lbshape.errors import LbshapeError
from lbshape.pipeline import impact_columns
from lbshape.pipeline.impact_columns import MIN_THROW_SPEED, impact_basis, throw, throw_speed
from lbshape.pipeline.precompute import precompute, stage_names
from lbshape.pipeline.precompute_key import scene_cache_key
from lbshape.pipeline.precomputed import ESTIMATE_FLAG, required_arrays
from lbshape.pipeline.simulate import example_stiffness, reduced_force_model
from lbshape.scene.reader import load_scene, scene_from_dict
from lbshape.scene.variants import with_impact_columns
from lbshape.studies.free_bodies import designed_impact

COLUMNS = 26


def _with_columns(scene, count: int = COLUMNS):
    """The scene with one set of ``count`` impact columns for the whole body (the sets
    per hull feature: ``test_impact_feature_sets.py``)."""
    return with_impact_columns(scene, count)


def _document(**extra) -> dict:
    return {"object": {"shape": "demo-bar"}, "reduced": {"impact_columns": 4}, **extra}


@pytest.mark.parametrize("extra, message", [
    ({"fixed": {"region": "z > 0.999"},
      "planes": [{"point": [0, 0, -1], "normal": [0, 0, 1], "stiffness": 1e6}]},
     "has '\\[fixed\\]'"),
    ({}, "has no '\\[\\[planes\\]\\]'"),
])
def test_the_key_is_refused_where_no_method_models_it(extra, message):
    with pytest.raises(LbshapeError, match=f"impact_columns.*{message}"):
        scene_from_dict(_document(**extra), name="x")
    with pytest.raises(LbshapeError, match="impact_columns"):
        scene_from_dict({"object": {"shape": "demo-bar"},
                         "reduced": {"impact_columns": -1}}, name="x")


def test_the_stage_and_its_key_come_with_the_columns_only():
    scene = _with_columns(load_scene("bar-s-cuboid"), 0)
    assert "impact-basis" not in stage_names(scene)
    assert "impact_columns" not in scene.precompute_key_fields()["reduced"]
    names = stage_names(_with_columns(scene))
    assert names.index("example-basis") < names.index("impact-basis") < names.index("cubature")
    assert scene_cache_key(_with_columns(scene)) != scene_cache_key(scene)
    assert scene_cache_key(_with_columns(scene, 12)) != scene_cache_key(_with_columns(scene))


def test_a_cached_artifact_must_hold_the_columns_arrays_only_with_columns():
    free, fixed = load_scene("bar-s-cuboid"), load_scene("bar-cuboid")
    assert ESTIMATE_FLAG in required_arrays(fixed)
    for scene in (free, _with_columns(free)):
        assert ESTIMATE_FLAG not in required_arrays(scene)
        assert ("impact_coupling" in required_arrays(scene)) == bool(
            scene.reduced.impact_columns)


def test_the_throw_speed_is_the_speed_at_the_floor():
    scene = load_scene("bar-s-cuboid")
    points = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.1, 0.0, 0.5]])
    floor = dataclasses.replace(scene.planes[0], point=(0.0, 0.0, -0.5))
    still = dataclasses.replace(scene, planes=(floor,), initial=dataclasses.replace(
        scene.initial, angular_velocity=(0.0, 0.0, 0.0)))
    assert throw_speed(still, points) == pytest.approx(np.sqrt(2 * 9.81 * 0.5))
    weightless = dataclasses.replace(still, loads=())
    assert throw_speed(weightless, points) == MIN_THROW_SPEED


@pytest.fixture(scope="module")
def bars():
    scene = _with_columns(load_scene("bar-s-cuboid"))
    return scene, precompute(_with_columns(scene, 0)), precompute(scene)


@pytest.mark.slow
def test_the_columns_are_appended_last_with_their_own_energy(bars):
    _, plain, with_columns = bars
    assert with_columns.r == plain.r + COLUMNS
    assert with_columns.elastic.leading == plain.r
    np.testing.assert_allclose(with_columns.U[:, :plain.r], plain.U, atol=1e-10)
    model = reduced_force_model(with_columns)
    assert isinstance(model, ColumnForceModel) and model.leading == plain.r
    assert model.columns.r == COLUMNS
    coupling = with_columns.elastic.impact_coupling
    np.testing.assert_allclose(coupling[:plain.r, :plain.r], plain.elastic.force_coefficients.K,
                               rtol=1e-9, atol=1e-9 * np.abs(coupling).max())


@pytest.mark.slow
@pytest.mark.parametrize("kind, speed, examples, entry", [
    ("edge", 1.5, False, "edge_hit"),
    # faster than the bar reaches its floor: held by throws faster than that
    ("edge", 3.0, False, "edge_hit_fast"),
    # the bar flies S-bent under its example's pull: columns from throws of the straight
    # bar left this hit 16 % off; the throws carry the pull
    ("face", 1.5, True, "face_hit_example"),
])
def test_the_columns_hold_designed_hits_the_plain_basis_misses(bars, kind, speed, examples,
                                                                entry):
    """A designed hit: its restitution far off on the plain basis (r = 32), within its
    target with the 26 impact columns."""
    scene, plain, with_columns = bars
    errors = [designed_impact(scene, pre, kind, speed, examples=examples).stats()[
        "restitution_error"] for pre in (plain, with_columns)]
    assert errors[0] > golden(f"impact_columns.{entry}_plain").limit
    assert errors[1] < golden(f"impact_columns.{entry}_with_columns").limit


@pytest.mark.slow
def test_the_throws_carry_the_example_pull():
    """A throw with the examples' pull bends the body as it hits (the S-bar's pull), one
    without it does not: their deformations differ by far more than round-off."""
    scene = load_scene("bar-s-cuboid")
    pre = precompute(scene)
    examples = FullSpaceExamples(pre.shape.eigenvalues, pre.shape.eigenvectors,
                                 pre.examples.example_coefficients,
                                 example_stiffness(scene, pre))
    direction = np.array([1.0, 0.0, 0.0])
    straight = throw(scene, pre.mesh, direction, 1.5)
    pulled = throw(scene, pre.mesh, direction, 1.5, examples)
    count = min(len(straight), len(pulled))
    assert count > 5
    change = np.abs(pulled[:count] - straight[:count]).max()
    assert change > 0.1 * np.abs(straight[:count]).max()


@pytest.mark.slow
def test_more_columns_than_the_throws_give_is_a_one_line_error(bars, monkeypatch):
    scene, plain, _ = bars
    mesh = plain.mesh
    rng = np.random.default_rng(5)
    # one snapshot per throw: 26 throws give at most 26 columns
    monkeypatch.setattr(impact_columns, "throw", lambda *args, **kwargs: 1e-3 * rng.standard_normal(
        (1, mesh.n_vertices, 3)))
    mass = mass_matrix(mesh, plain.material.density)
    stiffness = tangent_stiffness(mesh, plain.material, np.zeros(3 * mesh.n_vertices))
    basis = NonlinearBasis(plain.U, np.ones(plain.r), plain.r, np.ones(plain.r), plain.r, 0)
    grown = impact_basis(_with_columns(scene), mesh, mass, stiffness, basis)
    assert grown.basis.n_impact_columns == COLUMNS
    with pytest.raises(LbshapeError, match="impact_columns = 40: the 26 throws give 26"):
        impact_basis(_with_columns(scene, 40), mesh, mass, stiffness, basis)
    # per hull feature: one column a throw, one a set
    per_feature = with_impact_columns(scene, 1, "feature")
    one = impact_basis(per_feature, mesh, mass, stiffness, basis)
    assert one.basis.r == plain.r + len(one.directions) == plain.r + len(one.columns)
    with pytest.raises(LbshapeError, match="impact_columns = 3 per feature: 26 of the 26 "
                                           "throws reached their plane, the fewest independent "
                                           "columns a throw gave is 1; set impact_columns <= 1"):
        impact_basis(with_impact_columns(scene, 3, "feature"), mesh, mass, stiffness, basis)
