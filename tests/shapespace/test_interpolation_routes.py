"""Setting up the interpolation routes: bad input gives one clear LbshapeError each.

Runs the real pipeline (:func:`lbshape.pipeline.precompute.precompute`) on small scenes: the
coarse demo bar (90 vertices) as the object, with a private cache.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lbshape.elastic.reduced_forces import ReducedForceModel
from lbshape.errors import LbshapeError
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.routes import ROUTES, example_driver, target_solver
from lbshape.scene import scene_from_dict
from lbshape.shapespace.example_driver import ExampleDriver
from lbshape.shapespace.interpolation import TargetSolver

TWIST = {"shape": "demo-bar", "pose": "twist",
         "parameters": {"angle": 0.6, "axis": "z", "anchor": "max"}}


def _scene(examples, *, m: int = 6):
    data = {"name": "route-test", "object": {"shape": "demo-bar"},
            "reduced": {"m": m, "r": 12, "s": 20}, "fixed": {"region": "z > 0.999"}}
    if examples:
        data["examples"] = {"stiffness": 100.0, "pose": examples}
    return scene_from_dict(data)


@pytest.fixture(scope="module")
def pre():
    return precompute(_scene([TWIST, dict(TWIST, parameters={"angle": -0.3, "axis": "z",
                                                            "anchor": "max"})]))


def test_a_valid_scene_sets_up_every_route(pre):
    """The control for the error cases below: same object, corresponding examples."""
    assert pre.examples.alignment_residuals.max() < 1e-8, pre.examples.alignment_residuals
    q = 0.5 * pre.examples.lb_to_reduced @ pre.examples.example_coefficients[0].ravel()
    targets = {}
    for route in ROUTES:
        info = example_driver(pre, route=route).target(q)
        assert info.q_target.shape == (pre.r,) and np.isfinite(info.q_target).all()
        assert info.weights.min() >= 0 and info.weights.sum() == pytest.approx(1.0)
        targets[route] = info.q_target
    # halfway to example 1 from the rest, all routes pull towards example 1's side
    for route, q_target in targets.items():
        assert q_target @ q > 0, f"{route}: target {q_target} points away from the state"


def test_unknown_route(pre):
    with pytest.raises(LbshapeError, match="unknown interpolation route 'cubature'"):
        target_solver(pre, "cubature")
    with pytest.raises(LbshapeError, match="unknown interpolation route"):
        example_driver(pre, route="Modal")


def test_scene_without_examples():
    bare = precompute(_scene([]))
    for route in ROUTES:
        with pytest.raises(LbshapeError, match="has no examples"):
            target_solver(bare, route)


def test_examples_of_mismatched_dimension(pre):
    m = pre.shape.eigenvalues.size
    truncated = dataclasses.replace(pre, examples=dataclasses.replace(
        pre.examples, example_coefficients=pre.examples.example_coefficients[:, :-1]))
    for route in ROUTES:
        with pytest.raises(LbshapeError, match=f"5 LB coefficients .* m={m}"):
            target_solver(truncated, route)
    flat = dataclasses.replace(pre, examples=dataclasses.replace(
        pre.examples, example_coefficients=pre.examples.example_coefficients[..., :2]))
    with pytest.raises(LbshapeError, match=r"\(k, m, 3\)"):
        target_solver(flat, "lb")
    # descriptors of another shape space handed to the runtime driver
    setup = target_solver(pre, "modal")
    with pytest.raises(LbshapeError, match="dimension 15, the object's descriptor 18"):
        ExampleDriver(pre.examples.descriptor_matrix, pre.examples.example_descriptors[:, :15],
                      setup.solver)
    # example offsets that do not fit the energy models' coordinates
    model = ReducedForceModel(pre.mesh.points, pre.mesh.tets, pre.material, pre.U,
                              pre.elastic.cubature_elements, pre.elastic.cubature_weights)
    solver = TargetSolver([model], np.zeros((1, pre.r + 3)))
    with pytest.raises(LbshapeError, match=f"shape \\({pre.r},\\)"):
        solver.solve(np.ones(1))


def test_lb_route_needs_the_lb_cubature(pre):
    missing = dataclasses.replace(pre, examples=dataclasses.replace(pre.examples,
                                                                    lb_cubatures=None))
    with pytest.raises(LbshapeError, match="no LB-subspace cubature"):
        target_solver(missing, "lb")
    assert target_solver(missing, "modal").solver.dimension == pre.r  # the others still work


def test_m_too_large_for_an_example_mesh():
    """The bar at element size 1 m has 10 vertices: at most m = 8 non-constant modes."""
    coarse = dict(TWIST, shape="bar-cuboid", size=1.0)
    with pytest.raises(LbshapeError, match="example 0 .*m=12 is too large for an example mesh "
                                           "with 10 vertices"):
        precompute(_scene([coarse], m=12))


def test_an_unrelated_example_fails_alignment():
    """A cube is no pose of a bar: its frame alignment leaves a residual above the
    threshold (the LB basis alignment would refuse it next)."""
    with pytest.raises(LbshapeError, match=r"^example 0 \(cube\): example does not correspond "
                                           r"to the object: frame alignment residual 0\.\d+ "
                                           r"exceeds 0\.2 [^\n]*$"):
        precompute(_scene([{"shape": "cube"}]))


def test_benchmark_script_smoke(tmp_path, load_script):
    """scripts/bench_interpolation.py on the demo scene, a few calls: files and sanity."""
    import csv

    bench = load_script("bench_interpolation")
    written = bench.main(["demo", "--m", "4", "--calls", "6", "--steps", "30", "--repeats", "1",
                          "--out-dir", str(tmp_path)])
    assert sorted(p.name for p in written) == [
        "interpolation_benchmark.csv", "interpolation_benchmark.md", "interpolation_benchmark.png"]
    with open(tmp_path / "interpolation_benchmark.csv") as handle:
        table = list(csv.DictReader(handle))
    main_basis = next(row["boundary"] for row in table if row["route"] == "lb-table")
    rows = {row["route"]: row for row in table if row["boundary"] == main_basis}
    assert set(rows) == set(ROUTES)
    for row in table:
        reference = next(r for r in table if r["route"] == "euclidean"
                         and r["boundary"] == row["boundary"])
        assert float(reference["error_max"]) == 0.0 and float(reference["speedup"]) == 1.0
        assert int(reference["elements"]) == int(reference["n_tets"])
        assert int(row["calls"]) == 6 and float(row["t_median_ms"]) > 0
        assert 0 <= float(row["error_median"]) <= float(row["error_max"])
        assert 0 <= float(row["separation_error_median"]) <= float(row["separation_error_max"])
    # the demo's per-example lb cubature (s = 20 of 187 elements) and the table stay
    # within 2 % of the examples' separation; lb-exact is the same energy as euclidean
    assert float(rows["lb"]["separation_error_max"]) < 0.02, rows["lb"]
    assert float(rows["lb-table"]["separation_error_max"]) < 0.005, rows["lb-table"]
    assert float(rows["lb-exact"]["separation_error_max"]) < 1e-8, rows["lb-exact"]
    # the tabulated target is the fastest route
    assert float(rows["lb-table"]["t_median_ms"]) < float(rows["lb-exact"]["t_median_ms"])
    text = (tmp_path / "interpolation_benchmark.md").read_text()
    assert "## Targets" in text and "OMP_NUM_THREADS" in text
    assert (tmp_path / "interpolation_benchmark.png").stat().st_size > 10_000
    assert not list(tmp_path.glob(".*"))  # no temporary files left behind
