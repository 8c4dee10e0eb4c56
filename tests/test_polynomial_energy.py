"""The exact polynomial reduced StVK energy equals the all-element energy."""

from __future__ import annotations

import numpy as np
import pytest

from lbshape.elastic.element_kernels import FullSpaceElasticity
from lbshape.elastic.materials import Material
from lbshape.errors import LbshapeError
from lbshape.geometry.primitives import structured_box
from lbshape.shapespace.polynomial_energy import StVKPolynomialEnergy

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
