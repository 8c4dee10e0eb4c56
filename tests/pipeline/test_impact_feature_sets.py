"""Impact columns per hull feature (``reduced.impact_columns_per = "feature"``): each
throw's own columns as one set, M-orthonormal and outside the plain basis, its frame the
blocks of the whole one; the set of the plane a hit touches is the one switched on, and
the Figure 4 bar then holds a designed edge hit and its whole run."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from conftest import golden
from scipy.spatial.transform import Rotation

from lbshape.analysis.norms import trajectory_error
from lbshape.dynamics.fictitious import frame_tensors
from lbshape.dynamics.impact_switch import ImpactSwitchedBody
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.errors import LbshapeError
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.precompute_key import scene_cache_key
from lbshape.pipeline.precomputed import required_arrays
from lbshape.pipeline.simulate import reduced_simulation
from lbshape.pipeline.simulation import Simulation
from lbshape.scene.reader import load_scene, scene_from_dict
from lbshape.scene.variants import with_impact_columns, without_examples
from lbshape.studies.free_bodies import designed_impact

#: columns a set
COLUMNS = 3


@pytest.fixture(scope="module")
def bar():
    """The Figure 4 bar without its example, 3 columns a hull feature."""
    scene = with_impact_columns(without_examples(load_scene("bar-s-cuboid")), COLUMNS, "feature")
    return scene, precompute(scene, progress=False)


def _sets(pre):
    return pre.elastic.leading, pre.elastic.impact_column_sets()


def test_the_key_needs_columns_and_names_a_choice():
    document = {"object": {"shape": "demo-bar"},
                "planes": [{"point": [0, 0, -1], "normal": [0, 0, 1], "stiffness": 1e6}]}
    with pytest.raises(LbshapeError, match="impact_columns_per. needs impact_columns > 0"):
        scene_from_dict({**document, "reduced": {"impact_columns_per": "feature"}}, name="x")
    with pytest.raises(LbshapeError, match="impact_columns_per"):
        scene_from_dict({**document, "reduced": {"impact_columns": 2,
                                                 "impact_columns_per": "side"}}, name="x")
    body = with_impact_columns(load_scene("bar-s-cuboid"), COLUMNS)
    feature = with_impact_columns(body, COLUMNS, "feature")
    assert scene_cache_key(body) != scene_cache_key(feature)
    assert "impact_directions" in required_arrays(feature)
    assert "impact_directions" not in required_arrays(body)


def test_each_set_is_orthonormal_and_outside_the_plain_basis(bar):
    _, pre = bar
    mass = mass_matrix(pre.mesh, pre.material.density)
    r0, sets = _sets(pre)
    directions = pre.elastic.impact_directions
    assert len(sets) == len(directions) >= 26 and pre.r == r0 + COLUMNS * len(sets)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0, atol=1e-12)
    plain = pre.U[:, :r0]
    for index in sets:
        V = pre.U[:, index]
        np.testing.assert_allclose(V.T @ (mass @ V), np.eye(COLUMNS), atol=1e-10)
        assert np.abs(plain.T @ (mass @ V)).max() < 1e-10
    # the sets are the throws' own: two of them are not one space
    first, second = (pre.U[:, sets[j]] for j in (0, 1))
    assert np.linalg.svd(first.T @ (mass @ second), compute_uv=False).min() < 0.9


def test_a_sets_frame_is_its_own_basis_frame(bar):
    _, pre = bar
    r0, sets = _sets(pre)
    index = np.concatenate([np.arange(r0), sets[5]])
    own = frame_tensors(pre.mesh.points, pre.mesh.tets,
                        mass_matrix(pre.mesh, pre.material.density), pre.U[:, index])
    cut = pre.frame.columns(index)
    for name in ("Y0", "G", "C", "H", "S", "translation"):
        ours, theirs = getattr(cut, name), getattr(own, name)
        np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-12 * np.abs(theirs).max())
    with pytest.raises(LbshapeError, match="no columns"):
        pre.frame.columns(np.array([pre.r]))


def test_the_plane_the_body_is_deepest_behind_picks_the_set(bar):
    """A body turned at random, one plane touching it along a set's direction (turned to
    the world) and another clear of it: that set, for every set."""
    scene, pre = bar
    engine = reduced_simulation(scene, pre)
    assert isinstance(engine, ImpactSwitchedBody) and engine.per_feature
    hull = engine._hull
    rng = np.random.default_rng(3)
    for j, direction in enumerate(pre.elastic.impact_directions):
        R = Rotation.random(random_state=rng).as_matrix()
        c = rng.normal(size=3)
        world = c + hull @ R.T
        touching, clear = R @ direction, R @ pre.elastic.impact_directions[(j + 7) % 26]
        # a point on each plane: 1 mm inside the body along the first, 1 cm off the second
        points = np.array([world[np.argmin(world @ touching)] + 1e-3 * touching,
                           world[np.argmin(world @ clear)] - 1e-2 * clear])
        body = SimpleNamespace(_now=SimpleNamespace(c=c, R=R), contact=SimpleNamespace(
            normals=np.array([touching, clear])[::(-1) ** j],
            points=points[::(-1) ** j]))
        assert engine.choose_set(body) == j


def test_the_edge_hit_is_held_by_its_own_set(bar):
    scene, pre = bar
    hit = designed_impact(scene, pre, "edge", 1.5, examples=False).stats()
    assert not hit["message"], hit["message"]
    assert hit["restitution_error"] < golden("impact_feature_sets.edge_hit").limit


def test_the_whole_run_switches_sets_and_follows_the_full_reference(bar):
    scene, pre = bar
    steps = scene.simulation.steps
    reduced = Simulation(scene, pre, method="reduced")
    record = reduced.run(steps)
    engine = reduced.engine
    assert record.stable and engine.onsets >= 1 and engine.rests >= 1
    assert 0 < engine.column_steps < steps and not engine.columns_on
    # the columns of no set but one are ever moved at a time: the record's q is lifted
    r0, sets = _sets(pre)
    moving = [np.abs(record.states[:, index]).max(axis=1) > 0 for index in sets]
    assert (np.sum(moving, axis=0) <= 1).all() and np.any(moving)
    full = Simulation(scene, pre, method="full")
    reference = full.run(steps)
    mass = mass_matrix(pre.mesh, pre.material.density)
    error = trajectory_error(reduced.displacements(record), full.displacements(reference),
                             mass)
    assert error < golden("impact_feature_sets.whole_run").limit


def test_per_feature_columns_run_switched_only(bar):
    scene, pre = bar
    with pytest.raises(LbshapeError, match="run switched only"):
        reduced_simulation(scene, pre, impact_switch=False)
    with pytest.raises(LbshapeError, match="per feature"):
        reduced_simulation(scene, pre, exact_forces=True)

