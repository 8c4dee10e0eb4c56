"""The elements of the example energies: squeezed reconstructions leave theirs out, and
every route, the LB cubature and the full-space reference sum over the same ones."""

from __future__ import annotations

import numpy as np
import pytest

from lbshape.elastic.materials import Material
from lbshape.geometry.primitives import structured_box
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.routes import target_solver
from lbshape.pipeline.simulate import full_simulation
from lbshape.scene import scene_from_dict
from lbshape.shapespace.euclidean_energy import EuclideanExampleEnergy
from lbshape.shapespace.example_shapes import (
    MIN_VOLUME_RATIO,
    energy_elements,
    example_rest_shapes,
    volume_ratios,
)
from lbshape.shapespace.interpolation import TargetSolver


def squeezed_in_x(points: np.ndarray, slope: float) -> np.ndarray:
    """Rest shape with x ↦ slope·x on x < 0.5 and continuous unit slope beyond."""
    out = points.copy()
    x = points[:, 0]
    out[:, 0] = np.where(x < 0.5, slope * x, 0.5 * slope + (x - 0.5))
    return out


def test_elements_squeezed_below_the_ratio_in_any_example_are_left_out():
    mesh = structured_box((1.0, 0.25, 0.25), (4, 1, 1))
    centres = mesh.points[mesh.tets].mean(axis=1)
    left = centres[:, 0] < 0.5
    # every element on the left keeps `slope` of its volume, on the right all of it
    for slope, expected in [(0.2, ~left), (MIN_VOLUME_RATIO, np.ones_like(left)),
                            (-0.5, ~left)]:
        rests = [mesh.points, squeezed_in_x(mesh.points, slope)]
        ratios = volume_ratios(mesh.points, mesh.tets, rests)
        assert np.allclose(ratios[1][left], slope) and np.allclose(ratios[1][~left], 1.0)
        kept = energy_elements(mesh.points, mesh.tets, rests)
        assert np.array_equal(kept, np.flatnonzero(expected)), slope
    # one example squeezing is enough; no example keeps every element
    rests = [squeezed_in_x(mesh.points, 1.0), squeezed_in_x(mesh.points, 0.25)]
    assert np.array_equal(energy_elements(mesh.points, mesh.tets, rests), np.flatnonzero(~left))
    assert energy_elements(mesh.points, mesh.tets, []).size == mesh.n_tets
    phi = np.random.default_rng(0).standard_normal((mesh.n_vertices, 3))
    c = np.random.default_rng(1).standard_normal((2, 3, 3))
    shapes = example_rest_shapes(mesh.points, phi, c)
    assert len(shapes) == 2 and np.allclose(shapes[1], mesh.points + phi @ c[1])


def _twist(angle: float) -> dict:
    return {"shape": "demo-bar", "pose": "twist",
            "parameters": {"angle": angle, "axis": "z", "anchor": "max"}}


@pytest.fixture(scope="module")
def squeezed():
    """The coarse demo bar (187 elements) with a 2.5 rad twist example: m = 6 LB
    functions reconstruct it squeezing 14 elements below 30 % of their volume."""
    scene = scene_from_dict({
        "name": "squeezed-examples", "object": {"shape": "demo-bar"},
        "reduced": {"m": 6, "r": 12, "s": 20}, "fixed": {"region": "z > 0.999"},
        "examples": {"stiffness": 100.0, "pose": [_twist(2.5), _twist(-0.3)]}})
    return scene, precompute(scene)


def test_every_route_and_the_full_reference_use_the_same_elements(squeezed):
    scene, pre = squeezed
    assert pre.examples.target_boundary == "free"  # the full reference's basis, compared below
    kept = pre.examples.energy_elements()
    assert 0 < pre.mesh.n_tets - kept.size < pre.mesh.n_tets // 4
    exact = {route: target_solver(pre, route, tolerance=1e-12, max_iterations=100)
             for route in ("lb-exact", "euclidean")}
    for setup in exact.values():
        assert np.array_equal(setup.elements, kept)
    assert np.isin(target_solver(pre, "modal").elements, kept).all()
    lb_rules = pre.examples.lb_cubatures.elements
    assert np.isin(lb_rules[lb_rules >= 0], kept).all()
    weights = np.array([0.4, 0.6])
    targets = {route: setup.solver.solve(weights).z for route, setup in exact.items()}
    full = full_simulation(scene, pre)._target_solver.solve(weights).z
    scale = np.linalg.norm(targets["euclidean"])
    assert np.linalg.norm(targets["lb-exact"] - targets["euclidean"]) < 1e-8 * scale
    assert np.linalg.norm(full - targets["euclidean"]) < 1e-6 * scale
    # the squeezed elements matter: with them the target moves
    L = pre.shape.lb_basis()
    everything = TargetSolver(
        [EuclideanExampleEnergy(pre.examples.rest_points(i), pre.mesh.tets, pre.material, L)
         for i in range(2)], exact["euclidean"].offsets, tolerance=1e-12, max_iterations=100)
    assert np.linalg.norm(everything.solve(weights).z - targets["euclidean"]) > 1e-3 * scale


def test_a_region_leaves_out_the_elements_its_examples_squeeze():
    """Local examples apply the rule on the region's own mesh: a region covering the
    right three quarters of a box, example 1 squeezing x < 0.5 to 20 % of its length."""
    from lbshape.shapespace.local_driver import region_energy_models
    from lbshape.shapespace.local_space import RegionSpace

    mesh = structured_box((1.0, 0.25, 0.25), (4, 1, 1))
    centres = mesh.points[mesh.tets].mean(axis=1)
    cells = np.flatnonzero(centres[:, 0] > 0.25)
    vertices = np.unique(mesh.tets[cells])
    x = mesh.points[vertices, 0]
    phi = np.column_stack([np.ones_like(x), np.minimum(x, 0.5)])  # (n_R, 2)
    coefficients = np.zeros((2, 2, 3))
    coefficients[1, 1, 0] = 0.2 - 1.0  # x ↦ 0.2 x below 0.5, unit slope beyond
    zeros = np.zeros((1, 6))
    region = RegionSpace(
        name="right", cells=cells, vertices=vertices, examples=np.arange(2),
        eigenvalues=np.ones(2), eigenvectors=phi, example_coefficients=coefficients,
        alignment_residuals=np.zeros(2), to_reduced=np.zeros((1, 6)), rigid_reduced=zeros,
        rigid_coefficients=np.zeros((6, 6)), anchor_reduced=zeros,
        anchor=np.zeros(vertices.size, dtype=bool), rigid_lb=np.zeros((6, 6)))
    rests, tets = region.example_energy_shapes(mesh)
    local_centres = mesh.points[vertices][tets].mean(axis=1)
    expected = int(np.sum(centres[cells, 0] > 0.5))
    assert len(rests) == 2 and tets.shape == (expected, 4) and (local_centres[:, 0] > 0.5).all()
    assert 0 < expected < cells.size
    material = Material(young=1.0e5, poisson=0.3, density=1000.0)
    for model in region_energy_models(mesh, material, region, route="euclidean"):
        assert model.n_elements == expected
