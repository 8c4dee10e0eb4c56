"""The force model with linear trailing columns
(:class:`lbshape.elastic.linear_columns.LinearColumnsForceModel`): its force is the
gradient of its energy, its tangent the force's derivative, it is the base model where
the columns are zero, and it agrees with the exact energy on every column at small
amplitude."""

from __future__ import annotations

import numpy as np
import pytest

from lbshape.elastic.element_kernels import tangent_stiffness
from lbshape.elastic.linear_columns import LinearColumnsForceModel
from lbshape.elastic.polynomial_forces import PolynomialForceModel
from lbshape.pipeline.precompute import precompute
from lbshape.scene.reader import load_scene

LEADING = 8


@pytest.fixture(scope="module")
def models():
    pre = precompute(load_scene("demo"))
    mesh, U = pre.mesh, np.ascontiguousarray(pre.U)
    K0 = tangent_stiffness(mesh, pre.material, np.zeros(3 * mesh.n_vertices))
    base = PolynomialForceModel(mesh.points, mesh.tets, pre.material,
                                np.ascontiguousarray(U[:, :LEADING]))
    every = PolynomialForceModel(mesh.points, mesh.tets, pre.material, U)
    return LinearColumnsForceModel(base, U.T @ (K0 @ U), LEADING), base, every


def _point(r: int, scale: float, seed: int = 0) -> np.ndarray:
    return scale * np.random.default_rng(seed).standard_normal(r)


def test_the_force_is_the_energy_gradient_and_the_tangent_its_derivative(models):
    model = models[0]
    y, v, h = _point(model.r, 0.05), _point(model.r, 1.0, seed=1), 1e-6
    f, K = model.force_and_tangent(y)
    slope = (model.energy(y + h * v) - model.energy(y - h * v)) / (2 * h)
    assert slope == pytest.approx(f @ v, rel=1e-6)
    change = (model.force(y + h * v) - model.force(y - h * v)) / (2 * h)
    np.testing.assert_allclose(change, K @ v, rtol=1e-5, atol=1e-6 * np.abs(K @ v).max())
    np.testing.assert_allclose(K, K.T, atol=1e-9 * np.abs(K).max())


def test_without_the_columns_it_is_the_base_model(models):
    model, base, _ = models
    q = _point(LEADING, 0.05)
    y = np.concatenate([q, np.zeros(model.r - LEADING)])
    f, K = model.force_and_tangent(y)
    f0, K0 = base.force_and_tangent(q)
    np.testing.assert_array_equal(f[:LEADING], f0)
    np.testing.assert_array_equal(K[:LEADING, :LEADING], K0)
    assert model.energy(y) == base.energy(q)
    np.testing.assert_allclose(f[LEADING:], model.linear[LEADING:, :LEADING] @ q, rtol=1e-12)


def test_at_small_amplitude_it_is_the_exact_energy_on_every_column(models):
    model, _, every = models
    for scale in (1e-4, 1e-3):
        y = _point(model.r, scale, seed=2)
        exact, linear = every.energy(y), model.energy(y)
        # the columns' nonlinear terms are O(|y|³) against the O(|y|²) energy
        assert abs(linear - exact) < 20 * scale * abs(exact)
    y = _point(model.r, 1e-4, seed=3)
    np.testing.assert_allclose(model.force(y), every.force(y), rtol=0,
                               atol=1e-2 * np.abs(every.force(y)).max())
