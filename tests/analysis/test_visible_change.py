"""What a person sees of the examples: the visible change and the closest example.

* ``visible_change``: the largest vertex distance between two shapes over the rest
  bounding-box diagonal — checked on constructed shapes, and on a free body where a
  rigid motion must not count.
* ``closest_example``: the rest shape or the example a shape is closest to in shape
  space — every example's own reconstruction is closest to itself (global and per
  region), the rest shape to "rest", and a shape past the midpoint to the example.
"""

from __future__ import annotations

import meshio
import numpy as np
import pytest

from lbshape.analysis.free_body import body_deformations
from lbshape.analysis.influence import REST, nearest_shape, visible_change
from lbshape.dynamics.rigid_frame import cayley
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.geometry.primitives import structured_box
from lbshape.pipeline.influence import STATS_KEYS, closest_example
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import simulate
from lbshape.scene import load_scene
from lbshape.scene.reader import scene_from_dict


def test_nearest_shape_on_constructed_descriptors():
    examples = np.array([[2.0, 0.0, 0.0], [0.0, 4.0, 0.0]])
    closest, distances = nearest_shape(np.array([0.1, 0.0, 0.0]), examples)
    assert closest == REST
    np.testing.assert_allclose(distances[REST], 0.1 / 4.0)
    assert nearest_shape(np.array([1.2, 0.0, 0.0]), examples)[0] == 0  # past the midpoint
    closest, distances = nearest_shape(np.array([0.0, 3.0, 0.1]), examples, labels=[4, 7])
    assert closest == 7 and set(distances) == {REST, "4", "7"}
    np.testing.assert_allclose(distances["7"], np.hypot(1.0, 0.1) / 4.0)


def test_visible_change_is_the_largest_vertex_distance_over_the_diagonal():
    mesh = structured_box((0.2, 0.3, 1.0), (2, 2, 6))
    diagonal = np.linalg.norm([0.2, 0.3, 1.0])
    a = np.zeros_like(mesh.points)
    b = a.copy()
    b[5] = [0.0, 0.03, 0.04]  # 5 cm at one vertex
    b[9] = [0.01, 0.0, 0.0]
    np.testing.assert_allclose(visible_change(mesh.points, b, a), 0.05 / diagonal)
    assert visible_change(mesh.points, a, a) == 0.0


def test_visible_change_of_a_free_body_ignores_its_rigid_motion():
    mesh = structured_box((0.2, 0.3, 1.0), (2, 2, 6))
    scalar_mass = mass_matrix(mesh, 500.0)[0::3, 0::3]
    X = mesh.points
    bent = 0.05 * np.column_stack([X[:, 2] ** 2, np.zeros(len(X)), np.zeros(len(X))])
    R = cayley(np.array([0.3, -0.5, 0.8]))
    moved = (X + bent - X.mean(axis=0)) @ R.T + [3.0, -1.0, 2.0] - X
    body = body_deformations(scalar_mass, X, np.stack([bent, moved]))
    # the same deformation, flown and turned, is no visible change of shape
    assert visible_change(X, body[1], body[0]) < 1e-10
    # against the undeformed body it is (a bend of 5 cm at the tip, less the best fit)
    change = visible_change(X, body[1], np.zeros_like(X))
    assert 0.005 < change < 0.05 / np.linalg.norm(np.ptp(X, axis=0)) + 1e-12


@pytest.fixture(scope="module")
def demo():
    scene = load_scene("demo")
    return scene, precompute(scene)


def test_each_demo_example_is_closest_to_itself_and_rest_to_rest(demo):
    _, pre = demo
    rest = np.zeros_like(pre.mesh.points)
    assert closest_example(pre, rest)[0] == REST
    for k in range(len(pre.shape.example_names)):
        u = pre.examples.rest_points(k) - pre.mesh.points
        closest, distances = closest_example(pre, u)
        assert closest == k and distances[str(k)] < 1e-8, distances
        # a third of the way from rest the shape is still nearer rest, two thirds on the example
        assert closest_example(pre, u / 3.0)[0] == REST
        assert closest_example(pre, 2.0 * u / 3.0)[0] == k


def test_simulate_reports_visible_change_and_closest_example(demo):
    scene, pre = demo
    stats = simulate(scene, pre, influence=True).stats
    assert {"visible_change", "closest_example", "example_distances"} <= set(STATS_KEYS)
    # the demo's bar twists towards its +90 degree example (a person sees the twist)
    assert stats["closest_example"] in (0, 1), stats["example_distances"]
    assert stats["example_distances"][str(stats["closest_example"])] < \
        stats["example_distances"][REST]
    assert 0.0 < stats["visible_change"] < 1.0


def test_each_region_is_closest_to_its_own_example(tmp_path):
    bar = structured_box((0.2, 0.2, 1.0), (2, 2, 8))
    meshio.write(tmp_path / "bar.vtu", meshio.Mesh(bar.points, [("tetra", bar.tets)]))
    poses = [{"mesh": "bar.vtu", "pose": "twist", "parameters": {"angle": 1.0, "axis": "z",
                                                                  "anchor": "min"}},
             {"mesh": "bar.vtu", "pose": "twist", "parameters": {"angle": -0.7, "axis": "z",
                                                                  "anchor": "min"}}]
    scene = scene_from_dict(
        {"object": {"mesh": "bar.vtu"}, "reduced": {"m": 4, "r": 12, "s": 20},
         "fixed": {"region": "z < 0.001"}, "simulation": {"steps": 10},
         "examples": {"stiffness": 200.0, "pose": poses},
         "regions": [{"name": "low", "region": "z < 0.5", "examples": [0]},
                     {"name": "high", "region": "z > 0.5", "examples": [1]}]},
        name="two-regions", base_dir=tmp_path)
    pre = precompute(scene)
    assert closest_example(pre, np.zeros_like(bar.points))[0] == {"low": REST, "high": REST}
    for region in pre.local.regions:
        u = np.zeros_like(bar.points)
        u[region.vertices] = region.displacement(region.example_coefficients[0]).reshape(-1, 3)
        closest, distances = closest_example(pre, u)
        assert closest[region.name] == int(region.examples[0]), distances
        other = "high" if region.name == "low" else "low"
        assert closest[other] == REST, distances
