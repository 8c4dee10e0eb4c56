"""The exact polynomial reduced StVK energy equals the all-element energy."""

from __future__ import annotations

import numpy as np
import pytest

from lbshape.elastic.element_kernels import FullSpaceElasticity
from lbshape.elastic.materials import Material
from lbshape.elastic.polynomial_energy import StVKPolynomialEnergy
from lbshape.errors import LbshapeError
from lbshape.geometry.primitives import structured_box

MATERIAL = Material("stvk", young=1e5, poisson=0.3, density=1000.0)


@pytest.fixture(scope="module")
def setup():
    mesh = structured_box((0.2, 0.2, 1.0), (2, 2, 5))
    rng = np.random.default_rng(5)
    rest = mesh.points + 0.01 * rng.normal(size=mesh.points.shape)  # a non-trivial rest
    basis = rng.normal(size=(3 * mesh.n_vertices, 7)) * 0.05
    return mesh, rest, basis


@pytest.mark.parametrize("scale", [1e-3, 0.1, 1.0])
def test_matches_full_space_energy_gradient_and_hessian(setup, scale):
    mesh, rest, B = setup
    model = StVKPolynomialEnergy(rest, mesh.tets, MATERIAL, B)
    full = FullSpaceElasticity(mesh.with_points(rest), MATERIAL)
    y = np.random.default_rng(1).normal(size=B.shape[1]) * scale
    g, H = model.force_and_tangent(y)
    u = B @ y
    np.testing.assert_allclose(model.energy(y), full.energy(u), rtol=1e-11)
    np.testing.assert_allclose(g, B.T @ full.force(u), rtol=1e-11,
                               atol=1e-12 * np.abs(g).max())
    np.testing.assert_allclose(H, B.T @ (full.tangent(u) @ B), rtol=1e-11,
                               atol=1e-12 * np.abs(H).max())


def test_only_for_stvk(setup):
    mesh, rest, B = setup
    with pytest.raises(LbshapeError, match="StVK"):
        StVKPolynomialEnergy(rest, mesh.tets, Material("neohookean"), B)
    with pytest.raises(LbshapeError, match="basis"):
        StVKPolynomialEnergy(rest, mesh.tets, MATERIAL, B[:-1])


def _tensors(model):
    return model.K, model._C_first, model._D_cubic


@pytest.mark.parametrize("poisson", [0.3, -0.2])  # λ > 0 and λ < 0 (weights of both signs)
def test_streamed_chunks_and_the_lb_basis_path_give_the_same_tensors(setup, poisson):
    """Many element chunks (byte bound of one element) equal one chunk; for ``B = Φ ⊗ I₃``
    the m-sized path equals the general one; both match the all-element energy."""
    from lbshape.shapespace.projections import block_basis

    mesh, rest, _ = setup
    material = Material("stvk", young=1e5, poisson=poisson, density=1000.0)
    phi = np.random.default_rng(3).normal(size=(mesh.n_vertices, 4)) * 0.05
    B = block_basis(phi)
    one = StVKPolynomialEnergy(rest, mesh.tets, material, B, structured=False)
    many = StVKPolynomialEnergy(rest, mesh.tets, material, B, structured=False, max_bytes=1)
    fast = StVKPolynomialEnergy(rest, mesh.tets, material, B, max_bytes=1)
    for model in (many, fast):
        for mine, reference in zip(_tensors(model), _tensors(one), strict=True):
            np.testing.assert_allclose(mine, reference, rtol=0,
                                       atol=1e-12 * np.abs(reference).max())
    full = FullSpaceElasticity(mesh.with_points(rest), material)
    y = np.random.default_rng(4).normal(size=B.shape[1]) * 0.3
    energy, g, H = fast.energy_force_and_tangent(y)
    u = B @ y
    np.testing.assert_allclose(energy, full.energy(u), rtol=1e-11)
    np.testing.assert_allclose(g, B.T @ full.force(u), rtol=1e-11, atol=1e-12 * np.abs(g).max())
    np.testing.assert_allclose(H, B.T @ (full.tangent(u) @ B), rtol=1e-11,
                               atol=1e-12 * np.abs(H).max())


def test_element_chunks_split_across_ranks(setup):
    from test_cubature import on_ranks

    mesh, rest, B = setup
    serial = StVKPolynomialEnergy(rest, mesh.tets, MATERIAL, B)
    ranked = on_ranks(2, lambda comm: StVKPolynomialEnergy(rest, mesh.tets, MATERIAL, B,
                                                           max_bytes=1, comm=comm))
    for model in ranked:
        for mine, reference in zip(_tensors(model), _tensors(serial), strict=True):
            np.testing.assert_allclose(mine, reference, rtol=0,
                                       atol=1e-12 * np.abs(reference).max())
