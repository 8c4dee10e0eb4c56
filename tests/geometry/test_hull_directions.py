"""The hull directions a plane can meet an object from
(:mod:`lbshape.geometry.hull_directions`): faces, edges and corners of the convex hull."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from lbshape.errors import LbshapeError
from lbshape.geometry.hull_directions import MAX_FACES, hull_directions


def _box(extent, inside: int = 300) -> np.ndarray:
    corners = np.array(list(itertools.product(*[(0.0, e) for e in extent])))
    rng = np.random.default_rng(0)
    return np.vstack([corners, rng.uniform(0.0, 1.0, (inside, 3)) * np.asarray(extent)])


def _rows_match(a: np.ndarray, b: np.ndarray) -> bool:
    """Every row of a equals one row of b (to 1e-12), and the counts agree."""
    return len(a) == len(b) and all(np.min(np.linalg.norm(b - row, axis=1)) < 1e-12
                                    for row in a)


def test_a_box_has_six_faces_twelve_edges_and_eight_corners():
    directions = hull_directions(_box((0.1, 0.2, 1.0)))
    axes = np.vstack([np.eye(3), -np.eye(3)])
    edges = np.array([(a + b) / np.sqrt(2.0) for a, b in itertools.combinations(axes, 2)
                      if abs(a @ b) < 0.5])
    corners = np.array(list(itertools.product((-1.0, 1.0), repeat=3))) / np.sqrt(3.0)
    assert _rows_match(directions.faces, axes)
    assert _rows_match(directions.edges, edges)
    assert _rows_match(directions.corners, corners)
    assert directions.kinds.count("edge") == 12 and directions.all.shape == (26, 3)


def test_a_rounded_object_keeps_its_largest_sides():
    angles = np.linspace(0.0, 2.0 * np.pi, 64, endpoint=False)
    ring = np.column_stack([np.cos(angles), np.sin(angles)])
    points = np.vstack([np.column_stack([ring, np.full(64, z)]) for z in (0.0, 3.0)])
    directions = hull_directions(points)
    assert len(directions.faces) == MAX_FACES
    # the 64-gon's sides (each 0.29 m² of side face) group by 10°: about 36 groups, the
    # two caps (3.1 m² each) are the largest
    caps = [np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, -1.0])]
    assert all(np.min(np.linalg.norm(directions.faces - cap, axis=1)) < 1e-12 for cap in caps)
    np.testing.assert_allclose(np.linalg.norm(directions.all, axis=1), 1.0, atol=1e-12)


def test_flat_points_have_no_hull():
    flat = np.column_stack([np.random.default_rng(1).uniform(size=(20, 2)), np.zeros(20)])
    with pytest.raises(LbshapeError, match="no convex hull"):
        hull_directions(flat)
