"""Region expressions are evaluated safely and correctly."""

from __future__ import annotations

import numpy as np
import pytest

from lbshape.errors import LbshapeError
from lbshape.geometry.regions import evaluate_region, region_vertices

POINTS = np.array([[0.0, 0.0, 0.0], [0.5, -0.2, 1.0], [1.0, 0.3, 0.2]])


@pytest.mark.parametrize(
    ("expression", "expected"),
    [
        ("z > 0.5", [False, True, False]),
        ("x < 1e-6", [True, False, False]),
        ("(x > 0.1) & (abs(y) < 0.25)", [False, True, False]),
        ("x > 0.1 and y > 0", [False, False, True]),
        ("not (z > 0.5) or x == 0.5", [True, True, True]),
        ("0.2 < x <= 1.0", [False, True, True]),
        ("sqrt(x**2 + y**2) < 0.6", [True, True, False]),
        ("~(x > 0.7) | (z > 0.9)", [True, True, False]),
        ("sin(pi * x) > 0.5", [False, True, False]),
    ],
)
def test_evaluates(expression, expected):
    np.testing.assert_array_equal(evaluate_region(expression, POINTS), expected)


@pytest.mark.parametrize(
    "expression",
    [
        "__import__('os').system('true')",
        "x.__class__",
        "open('f')",
        "[x for x in y]",
        "lambda: 1",
        "x if y else z",
        "'text' == x",
        "w > 0",
    ],
)
def test_rejects_unsafe_or_unknown(expression):
    with pytest.raises(LbshapeError, match="region expression"):
        evaluate_region(expression, POINTS)


@pytest.mark.parametrize("expression", ["", "x >", "x + 1"])
def test_rejects_malformed_or_non_boolean(expression):
    with pytest.raises(LbshapeError):
        evaluate_region(expression, POINTS)


def test_empty_selection_is_an_error():
    with pytest.raises(LbshapeError, match="selects no vertex"):
        region_vertices("z > 5", POINTS, what="fixed region")
    np.testing.assert_array_equal(region_vertices("z >= 0.2", POINTS), [1, 2])
