"""The tabulated interpolation target against the exact one, its slopes against finite
differences, its refusal, the fast weights, and the lb-table route.

Object: the coarse demo bar (90 vertices) fixed at its top; examples: its own twists
about z (same mesh), through the real pipeline with a private cache.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lbshape.elastic.element_kernels import mass_matrix
from lbshape.errors import LbshapeError
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.routes import exact_route, example_driver, target_solver
from lbshape.scene import scene_from_dict
from lbshape.shapespace.clamped_basis import clamp_profile
from lbshape.shapespace.example_driver import ExampleDriver
from lbshape.shapespace.interpolation import (
    SimplexWeights,
    TargetSolver,
    resolve_route,
    simplex_weights,
)
from lbshape.shapespace.target_table import (
    TableRefused,
    TargetTable,
    build_target_table,
    target_slope,
)


def _twist(angle: float) -> dict:
    return {"shape": "demo-bar", "pose": "twist",
            "parameters": {"angle": angle, "axis": "z", "anchor": "max"}}


def _scene(angles):
    return scene_from_dict({
        "name": "table-test", "object": {"shape": "demo-bar"},
        "reduced": {"m": 6, "r": 12, "s": 20}, "fixed": {"region": "z > 0.999"},
        "examples": {"stiffness": 100.0, "pose": [_twist(a) for a in angles]},
    })


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("LBSHAPE_CACHE", str(tmp_path_factory.mktemp("cache")))
        yield


@pytest.fixture(scope="module")
def two(cache):
    return precompute(_scene([0.8, -0.4]))


@pytest.fixture(scope="module")
def three(cache):
    return precompute(_scene([0.8, -0.4, 0.3]))


def _exact(pre) -> TargetSolver:
    setup = target_solver(pre, exact_route(pre))
    return TargetSolver(setup.solver.models, setup.solver.offsets, tolerance=1e-11,
                        max_iterations=100)


def _separation(offsets: np.ndarray) -> float:
    return max(np.linalg.norm(a - b) for i, a in enumerate(offsets) for b in offsets[i + 1:])


def test_precompute_tabulates_and_checks_the_target(two):
    table = two.examples.target_table
    assert table is not None and table.kind == "segment"
    assert table.check.max_error <= table.check.tolerance, table.check
    assert table.check.checks >= 40


@pytest.mark.parametrize("which", ["two", "three"])
def test_table_matches_the_exact_target_at_fresh_weights(which, request):
    """Independent of the precompute's own check: new random weights, a tight solver."""
    pre = request.getfixturevalue(which)
    table = pre.examples.target_table
    exact = _exact(pre)
    rng = np.random.default_rng(99)
    spread = _separation(exact.offsets)
    metric = _metric(pre)
    errors = []
    for w in rng.dirichlet(np.ones(table.k), size=25):
        z_table = table.z(w)
        z = exact.solve(w, start=z_table).z
        d = z_table - z
        errors.append(np.sqrt(d @ metric @ d) / spread)
    assert max(errors) < 0.005, f"table error {max(errors):.2e} of the separation"
    # and it interpolates: at its own nodes it returns the exact targets
    for w, z in zip(table.node_weights[::5], table.nodes[::5], strict=True):
        np.testing.assert_allclose(table.z(w), z, rtol=0, atol=1e-12 * spread)


def _metric(pre) -> np.ndarray:
    basis = pre.shape.lb_basis(clamped=pre.examples.target_boundary == "clamped")
    volume_mass = mass_matrix(pre.mesh, 1.0)
    return basis.T @ (volume_mass @ basis)


def test_hermite_slopes_match_finite_differences(two):
    exact = _exact(two)
    t, h = 0.37, 1e-4
    def z(s):
        return exact.solve(np.array([1 - s, s]), start=two.examples.target_table.z(
            np.array([1 - s, s]))).z

    finite = (z(t + h) - z(t - h)) / (2 * h)
    slope = target_slope(exact, z(t), np.array([1 - t, t]), np.array([-1.0, 1.0]))
    error = np.linalg.norm(finite - slope) / np.linalg.norm(slope)
    assert error < 1e-5, f"IFT slope vs central differences: {error:.2e}"


def test_hermite_table_converges_at_fourth_order(two):
    """Doubling the nodes divides the worst midpoint error by about 16 once asymptotic
    (the worst interval is the last one, where the target turns fast towards example 2)."""
    exact = _exact(two)
    spread = _separation(exact.offsets)
    errors = []
    for n in (32, 64):
        table = build_target_table(exact, intervals=n, tolerance=1.0, checks=1)
        mids = [(j + 0.5) / n for j in range(n)]
        errors.append(max(np.linalg.norm(table.z(np.array([1 - t, t]))
                                         - exact.solve(np.array([1 - t, t])).z) / spread
                          for t in mids))
    rate = np.log2(errors[0] / errors[1])
    assert rate > 3.0, f"observed order {rate:.2f} (errors {errors})"


def test_a_table_that_cannot_meet_its_tolerance_is_refused(two):
    exact = _exact(two)
    with pytest.raises(TableRefused, match="exceeds"):
        build_target_table(exact, intervals=1, max_intervals=2, tolerance=1e-12)
    with pytest.raises(LbshapeError, match="1 to 3 examples"):
        build_target_table(TargetSolver(exact.models * 2, np.tile(exact.offsets, (2, 1))))


def test_table_round_trips_through_the_cache_arrays(three):
    table = three.examples.target_table
    again = TargetTable.from_arrays(table.to_arrays())
    w = np.array([0.2, 0.5, 0.3])
    np.testing.assert_array_equal(again.z(w), table.z(w))
    assert again.check == table.check


def test_lb_table_route_is_the_default_and_falls_back_without_a_table(two):
    assert resolve_route("auto", "stvk") == "lb-table"
    setup = target_solver(two, "lb-table")
    assert setup.solver.table is two.examples.target_table
    driver = example_driver(two, route="lb-table")
    q = 0.5 * two.examples.lb_to_reduced_for(clamped=two.examples.target_boundary == "clamped") \
        @ two.examples.example_coefficients[0].ravel()
    out = np.zeros(two.r)
    driver.target_into(q, out)
    info = example_driver(two, route="lb-exact").target(q)
    np.testing.assert_allclose(driver.w, info.weights, atol=1e-12)
    scale = np.linalg.norm(info.q_target)
    assert np.linalg.norm(out - info.q_target) < 1e-3 * scale
    # without a table the route solves the exact target at run time
    bare = dataclasses.replace(two, examples=dataclasses.replace(two.examples,
                                                                 target_table=None))
    fallback = target_solver(bare, "lb-table")
    assert fallback.route == "lb-exact" and fallback.solver.max_iterations == 1
    # one warm-started Newton step per call tracks the exact target as the state moves
    driver = ExampleDriver(bare.examples.descriptor_matrix, bare.examples.example_descriptors,
                           fallback.solver, to_reduced=fallback.to_reduced)
    exact = _exact(two)
    spread = _separation(exact.offsets)
    for t in np.linspace(0.0, 1.0, 40):
        driver.target_into(t * q, out)
    z = exact.solve(driver.w).z
    assert np.linalg.norm(fallback.solver._last - z) < 0.02 * spread


def test_simplex_weights_precomputed_match_the_reference():
    rng = np.random.default_rng(5)
    for k in (1, 2, 3, 4):
        for _ in range(30):
            E = rng.normal(size=(k, 9))
            D = rng.normal(size=(9, 7))
            q = rng.normal(size=7) * rng.uniform(0.1, 3.0)
            fast = SimplexWeights(E, D)(q)
            np.testing.assert_allclose(fast, simplex_weights(E, D @ q), atol=1e-9)


def test_clamp_profile_is_zero_on_the_fixed_vertices_and_one_far_away():
    points = np.stack([np.zeros(11), np.zeros(11), np.linspace(0.0, 1.0, 11)], axis=1)
    chi = clamp_profile(points, np.array([10]), blend=0.3)
    assert chi[10] == 0.0 and np.all(chi[:8] == 1.0)
    assert np.all(np.diff(chi[7:]) < 0)  # fades monotonically towards the fixed end


def test_a_non_stvk_material_is_tabulated_from_the_all_element_energy(cache):
    """No polynomial energy for stable Neo-Hookean: the table's exact solves use the
    all-element energy, and it still meets its checked tolerance."""
    scene = _scene([0.8, -0.4])
    scene = dataclasses.replace(scene, material=dataclasses.replace(scene.material,
                                                                     model="neohookean"))
    pre = precompute(scene)
    assert exact_route(pre) == "euclidean"
    table = pre.examples.target_table
    assert table is not None and table.check.max_error <= table.check.tolerance
    exact = _exact(pre)
    w = np.array([0.35, 0.65])
    d = table.z(w) - exact.solve(w, start=table.z(w)).z
    assert np.sqrt(d @ _metric(pre) @ d) < 0.005 * _separation(exact.offsets)
