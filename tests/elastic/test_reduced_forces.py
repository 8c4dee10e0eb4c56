"""Reduced energy, force and tangent by cubature vs full space and finite differences."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import central_difference_errors, observed_rates, rel

from lbshape.elastic.element_kernels import ElementKernel, FullSpaceElasticity
from lbshape.elastic.materials import Material
from lbshape.elastic.reduced_forces import ReducedForceModel
from lbshape.errors import LbshapeError
from lbshape.geometry.primitives import structured_box

MODELS = ("stvk", "neohookean")
R = 9


def material(model: str) -> Material:
    return Material(model, young=2.0e5, poisson=0.35, density=1100.0)


@pytest.fixture(scope="module")
def bar(load_script):
    """A coarse 0.2 × 0.2 × 1 m bar (81 vertices, 192 tets) and a smooth basis (3n, 9)."""
    mesh = structured_box((0.2, 0.2, 1.0), (2, 2, 8))
    U = load_script("bench_cubature").polynomial_basis(mesh, R, density=1100.0)
    return mesh, U


def poses(U: np.ndarray, count: int, rng: np.random.Generator, *, largest: float = 0.1):
    """count reduced coordinates (count, r) whose largest vertex displacement is ``largest`` m."""
    Q = rng.normal(size=(count, U.shape[1]))
    peak = np.linalg.norm((Q @ U.T).reshape(count, -1, 3), axis=2).max(axis=1)
    return Q * (largest / peak)[:, None]


def all_elements(mesh, model, U, points=None):
    points = mesh.points if points is None else points
    return ReducedForceModel(
        points, mesh.tets, material(model), U, np.arange(mesh.n_tets), np.ones(mesh.n_tets)
    )


@pytest.mark.parametrize("model", MODELS)
def test_all_elements_with_unit_weights_are_the_exact_reduced_quantities(bar, model):
    mesh, U = bar
    full = FullSpaceElasticity(mesh, material(model))
    reduced = all_elements(mesh, model, U)
    for q in poses(U, 3, np.random.default_rng(1)):
        u = U @ q
        f_exact = U.T @ full.force(u)
        K_exact = U.T @ (full.tangent(u) @ U)
        f, K = reduced.force_and_tangent(q)
        assert rel(f, f_exact) < 1e-10, f"force: relative error {rel(f, f_exact):.2e}"
        assert rel(K, K_exact) < 1e-10, f"tangent: relative error {rel(K, K_exact):.2e}"
        np.testing.assert_allclose(reduced.force(q), f, rtol=0, atol=1e-14 * np.abs(f).max())
        np.testing.assert_allclose(reduced.tangent(q), K, rtol=0, atol=1e-14 * np.abs(K).max())
        e_exact = full.energy(u)
        assert abs(reduced.energy(q) - e_exact) <= 1e-10 * e_exact, (reduced.energy(q), e_exact)
        jac = full.kernel.min_jacobian(u.reshape(-1, 3)[mesh.tets])
        assert reduced.min_jacobian(q) == pytest.approx(jac, rel=1e-12)


@pytest.mark.parametrize("model", MODELS)
def test_element_forces_are_the_projected_element_forces(bar, model):
    mesh, U = bar
    rng = np.random.default_rng(2)
    elements = rng.choice(mesh.n_tets, size=7, replace=False)
    reduced = ReducedForceModel(mesh.points, mesh.tets, material(model), U, elements, np.ones(7))
    kernel = ElementKernel(mesh.points, mesh.tets[elements], material(model))
    Q = poses(U, 4, rng)
    contributions = reduced.element_forces(Q.T)  # (P, r, s)
    assert contributions.shape == (4, R, 7)
    for p, q in enumerate(Q):
        fe = kernel.forces((U @ q).reshape(-1, 3)[mesh.tets[elements]]).reshape(7, 12)
        expected = np.einsum("ekr,ek->re", reduced.element_basis, fe)
        assert rel(contributions[p], expected) < 1e-12, rel(contributions[p], expected)


@pytest.fixture(scope="module")
def cubature_model_factory(bar):
    mesh, U = bar
    rng = np.random.default_rng(3)
    elements = rng.choice(mesh.n_tets, size=25, replace=False)
    weights = rng.uniform(0.5, 8.0, size=25)

    def make(model):
        return ReducedForceModel(mesh.points, mesh.tets, material(model), U, elements, weights)

    return make


@pytest.mark.parametrize("model", MODELS)
def test_tangent_is_the_derivative_of_the_force(bar, cubature_model_factory, model):
    _, U = bar
    reduced = cubature_model_factory(model)
    rng = np.random.default_rng(4)
    q = poses(U, 1, rng)[0]
    direction = rng.normal(size=R)
    direction *= np.linalg.norm(q) / np.linalg.norm(direction)
    steps = np.array([0.04, 0.02, 0.01])
    errors = central_difference_errors(reduced.force, reduced.tangent, q, direction, steps)
    rates = observed_rates(errors, steps)
    assert np.all(rates > 1.8), f"observed FD convergence rates {rates} (errors {errors})"
    small = central_difference_errors(reduced.force, reduced.tangent, q, direction, [1e-4])[0]
    assert small < 1e-7, f"FD of the force at h = 1e-4: relative error {small:.2e}"
    K = reduced.tangent(q)
    assert rel(K, K.T) < 1e-13, f"tangent asymmetry {rel(K, K.T):.2e}"


@pytest.mark.parametrize("model", MODELS)
def test_force_is_the_derivative_of_the_energy(bar, cubature_model_factory, model):
    _, U = bar
    reduced = cubature_model_factory(model)
    rng = np.random.default_rng(5)
    q = poses(U, 1, rng)[0]
    direction = rng.normal(size=R)
    direction *= np.linalg.norm(q) / np.linalg.norm(direction)
    steps = np.array([0.04, 0.02, 0.01])

    def energy(x):
        return np.array([reduced.energy(x)])

    def gradient(x):
        return reduced.force(x)[None, :]

    errors = central_difference_errors(energy, gradient, q, direction, steps)
    rates = observed_rates(errors, steps)
    assert np.all(rates > 1.8), f"observed FD convergence rates {rates} (errors {errors})"
    small = central_difference_errors(energy, gradient, q, direction, [1e-4])[0]
    assert small < 1e-7, f"FD of the energy at h = 1e-4: relative error {small:.2e}"


@pytest.mark.parametrize("model", MODELS)
def test_any_rest_shape_example_pose(bar, model):
    """The rest shape is an arbitrary (example) shape: zero energy and force there, and
    the full-space quantities of that rest shape with all elements."""
    mesh, U = bar
    rng = np.random.default_rng(6)
    z = mesh.points[:, 2]
    angle = 0.6 * z  # a twist about the bar axis, 0.6 rad at the end
    c, s = np.cos(angle), np.sin(angle)
    example = np.column_stack(
        [c * (mesh.points[:, 0] - 0.1) - s * (mesh.points[:, 1] - 0.1) + 0.1,
         s * (mesh.points[:, 0] - 0.1) + c * (mesh.points[:, 1] - 0.1) + 0.1, 1.1 * z]
    )
    reduced = all_elements(mesh, model, U, points=example)
    full = FullSpaceElasticity(mesh.with_points(example), material(model))
    q = poses(U, 1, rng)[0]
    f, K = reduced.force_and_tangent(q)
    zero = np.zeros(R)
    assert reduced.energy(zero) == 0.0
    at_rest = np.abs(reduced.force(zero)).max()
    assert at_rest <= 1e-12 * np.abs(f).max(), f"force at rest {at_rest:.2e}, at q {f}"
    assert rel(f, U.T @ full.force(U @ q)) < 1e-10
    assert rel(K, U.T @ (full.tangent(U @ q) @ U)) < 1e-10
    # a different rest shape gives a different force at the same q
    assert rel(f, all_elements(mesh, model, U).force(q)) > 1e-2


def test_bad_inputs_raise_lbshape_error(bar):
    mesh, U = bar
    mat = material("stvk")
    els, w = np.arange(5), np.ones(5)
    cases = [
        (lambda: ReducedForceModel(mesh.points, mesh.tets, mat, U[:-3], els, w), "basis U"),
        (lambda: ReducedForceModel(mesh.points, mesh.tets, mat, U[:, 0], els, w), "basis U"),
        (lambda: ReducedForceModel(mesh.points, mesh.tets, mat, U * np.nan, els, w), "NaN"),
        (lambda: ReducedForceModel(mesh.points, mesh.tets, mat, U, els, -w), ">= 0"),
        (lambda: ReducedForceModel(mesh.points, mesh.tets, mat, U, els, w[:3]), "shape"),
        (lambda: ReducedForceModel(mesh.points, mesh.tets, mat, U, els + mesh.n_tets, w),
         "out of range"),
        (lambda: ReducedForceModel(mesh.points, mesh.tets, mat, U, els * 1.0, w), "integers"),
        (lambda: ReducedForceModel(mesh.points, mesh.tets, mat, U, els[:0], w[:0]), "non-empty"),
    ]
    for make, message in cases:
        with pytest.raises(LbshapeError, match=message):
            make()
    reduced = ReducedForceModel(mesh.points, mesh.tets, mat, U, els, w)
    for method in (reduced.energy, reduced.force, reduced.tangent, reduced.force_and_tangent,
                   reduced.min_jacobian):
        with pytest.raises(LbshapeError, match="reduced coordinates"):
            method(np.zeros(R + 1))
    with pytest.raises(LbshapeError, match="poses"):
        reduced.element_forces(np.zeros(R))
