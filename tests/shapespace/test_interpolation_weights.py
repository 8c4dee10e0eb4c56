"""Interpolation weights (paper eq. 5): exact simplex-constrained least squares."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize

from lbshape.errors import LbshapeError
from lbshape.shapespace.interpolation import SimplexWeights, simplex_weights


def test_recovers_a_known_convex_combination():
    rng = np.random.default_rng(3)
    E = rng.normal(size=(4, 30))
    w_true = np.array([0.1, 0.0, 0.6, 0.3])
    w = simplex_weights(E, w_true @ E)
    np.testing.assert_allclose(w, w_true, atol=1e-10)


def test_matches_a_generic_constrained_optimiser_outside_the_hull():
    rng = np.random.default_rng(7)
    for _ in range(20):
        E = rng.normal(size=(3, 12))
        c = rng.normal(size=12) * 2.0
        w = simplex_weights(E, c)
        assert w.min() >= 0.0 and w.sum() == pytest.approx(1.0, abs=1e-12)

        def objective(v, E=E, c=c):
            return 0.5 * np.sum((v @ E - c) ** 2)

        reference = minimize(
            objective, np.full(3, 1 / 3), method="SLSQP", bounds=[(0, 1)] * 3,
            constraints={"type": "eq", "fun": lambda v: v.sum() - 1}, options={"ftol": 1e-14},
        )
        # exact solver is never worse than a generic optimiser
        assert objective(w) <= reference.fun + 1e-9, (objective(w), reference.fun)


def test_single_and_identical_examples():
    e = np.array([[1.0, 2.0, 3.0]])
    np.testing.assert_array_equal(simplex_weights(e, np.zeros(3)), [1.0])
    twins = np.vstack([e, e])
    w = simplex_weights(twins, np.array([5.0, 0.0, 0.0]))
    assert w.sum() == pytest.approx(1.0) and (w >= 0).all()
    # a point on the segment between two examples gets its barycentric weights
    pair = np.array([[0.0, 0.0], [1.0, 0.0]])
    np.testing.assert_allclose(simplex_weights(pair, np.array([0.25, 3.0])), [0.75, 0.25])


def test_dimension_mismatch_is_a_clear_error():
    with pytest.raises(LbshapeError, match="dimension"):
        simplex_weights(np.zeros((2, 6)), np.zeros(5))
    with pytest.raises(LbshapeError, match="1 <= k <= 12"):
        simplex_weights(np.zeros((0, 6)), np.zeros(6))
    with pytest.raises(LbshapeError, match="1 <= k <= 12"):
        SimplexWeights(np.zeros((13, 6)))
    with pytest.raises(LbshapeError, match="dimension"):
        SimplexWeights(np.zeros((2, 6)), np.zeros((5, 3)))


def _both(E, c):
    """The weights of both entry points: the one-off call and the precomputed solver."""
    return simplex_weights(E, c), SimplexWeights(E)(c)


@pytest.mark.parametrize("c", [np.array([5.0, 0.0, 0.0]), np.zeros(3), np.array([1.0, 2.0, 3.0]),
                               np.array([-4.0, 1.0, 7.0])])
def test_two_identical_examples_share_their_weight_evenly(c):
    e = np.array([1.0, 2.0, 3.0])
    for w in _both(np.vstack([e, e]), c):
        np.testing.assert_allclose(w, [0.5, 0.5], atol=1e-12)


def test_a_tied_pair_beside_a_third_example_splits_its_share():
    E = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    cases = {(1.0, 0.0, 0.0): [0.5, 0.5, 0.0],  # at the tied pair
             (0.5, 0.5, 0.0): [0.25, 0.25, 0.5],  # half way to the third example
             (0.0, 0.0, 1.0): [0.25, 0.25, 0.5],  # equidistant, off the examples' plane
             (0.0, 2.0, 0.0): [0.0, 0.0, 1.0]}  # beyond the third example
    for c, expected in cases.items():
        for w in _both(E, np.array(c)):
            np.testing.assert_allclose(w, expected, atol=1e-12, err_msg=str(c))
    # the reduced path (descriptor D q) and a permutation of the examples agree
    rng = np.random.default_rng(11)
    D = rng.normal(size=(3, 5))
    q = np.linalg.lstsq(D, np.array([0.5, 0.5, 0.0]), rcond=None)[0]
    np.testing.assert_allclose(SimplexWeights(E, D)(q), [0.25, 0.25, 0.5], atol=1e-10)
    np.testing.assert_allclose(simplex_weights(E[[2, 0, 1]], np.array([0.5, 0.5, 0.0])),
                               [0.5, 0.25, 0.25], atol=1e-12)


def test_ties_among_distinct_examples_go_to_the_least_norm_minimiser():
    """Three collinear examples and a current shape at the middle one: every
    ``w = (t, 1 − 2t, t)`` reproduces it; the rule picks the least-norm one."""
    E = np.array([[0.0], [1.0], [2.0]])
    for w in _both(E, np.array([1.0])):
        np.testing.assert_allclose(w, [1 / 3, 1 / 3, 1 / 3], atol=1e-12)


def test_both_entry_points_agree_on_random_problems():
    rng = np.random.default_rng(17)
    for k in (1, 2, 3, 4, 6):
        for _ in range(25):
            E = rng.normal(size=(k, 9))
            if k > 2 and rng.uniform() < 0.3:
                E[1] = E[0]  # a tie now and then
            D = rng.normal(size=(9, 7))
            q = rng.normal(size=7) * rng.uniform(0.1, 3.0)
            reference = simplex_weights(E, D @ q)
            fast = SimplexWeights(E, D)(q, np.empty(k))
            np.testing.assert_allclose(fast, reference, atol=1e-10)
            assert reference.min() >= 0.0 and reference.sum() == pytest.approx(1.0, abs=1e-12)


def test_target_solver_reports_non_convergence(caplog):
    """A solve cut short by max_iterations says so instead of returning silently."""
    from lbshape.shapespace.interpolation import TargetSolver

    class Quartic:  # E(y) = Σ y⁴: Newton converges only linearly towards 0
        def energy(self, y):
            return float(np.sum(y**4))

        def force_and_tangent(self, y):
            return 4 * y**3, np.diag(12 * y**2)

    solver = TargetSolver([Quartic()], np.zeros((1, 3)), tolerance=1e-12, max_iterations=3)
    result = solver.solve(np.ones(1), start=np.ones(3))
    assert not result.converged and result.iterations == 3
    assert "max_iterations" in caplog.text
    converged = TargetSolver([Quartic()], np.ones((1, 3)), max_iterations=200).solve(
        np.ones(1), start=np.ones(3) * 1.5)
    assert converged.converged
