"""The force model of a basis ending with impact columns
(:class:`lbshape.elastic.column_forces.ColumnForceModel`): its force is the gradient of
its energy and its tangent the force's derivative, with the columns' energy quadratic or
exact; it is the base model where the columns are zero and the columns' model where the
rest is; and it agrees with the exact energy on every column at small amplitude."""

from __future__ import annotations

import numpy as np
import pytest

from lbshape.elastic.column_forces import ColumnForceModel
from lbshape.elastic.element_kernels import tangent_stiffness
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
    columns = PolynomialForceModel(mesh.points, mesh.tets, pre.material,
                                   np.ascontiguousarray(U[:, LEADING:]))
    every = PolynomialForceModel(mesh.points, mesh.tets, pre.material, U)
    coupling = U.T @ (K0 @ U)
    return (ColumnForceModel(base, coupling, LEADING),
            ColumnForceModel(base, coupling, LEADING, columns), base, columns, every)


def _point(r: int, scale: float, seed: int = 0) -> np.ndarray:
    return scale * np.random.default_rng(seed).standard_normal(r)


@pytest.mark.parametrize("exact", [False, True])
def test_the_force_is_the_energy_gradient_and_the_tangent_its_derivative(models, exact):
    model = models[int(exact)]
    y, v, h = _point(model.r, 0.05), _point(model.r, 1.0, seed=1), 1e-6
    f, K = model.force_and_tangent(y)
    slope = (model.energy(y + h * v) - model.energy(y - h * v)) / (2 * h)
    assert slope == pytest.approx(f @ v, rel=1e-6)
    change = (model.force(y + h * v) - model.force(y - h * v)) / (2 * h)
    np.testing.assert_allclose(change, K @ v, rtol=1e-5, atol=1e-6 * np.abs(K @ v).max())
    np.testing.assert_allclose(K, K.T, atol=1e-9 * np.abs(K).max())


@pytest.mark.parametrize("exact", [False, True])
def test_without_the_columns_it_is_the_base_model(models, exact):
    model, base = models[int(exact)], models[2]
    q = _point(LEADING, 0.05)
    y = np.concatenate([q, np.zeros(model.r - LEADING)])
    f, K = model.force_and_tangent(y)
    f0, K0 = base.force_and_tangent(q)
    np.testing.assert_array_equal(f[:LEADING], f0)
    np.testing.assert_array_equal(K[:LEADING, :LEADING], K0)
    assert model.energy(y) == base.energy(q)
    np.testing.assert_allclose(f[LEADING:], model.linear[LEADING:, :LEADING] @ q, rtol=1e-12)


def test_the_columns_alone_have_their_own_exact_energy(models):
    model, columns = models[1], models[3]
    z = _point(model.r - LEADING, 0.05, seed=4)
    y = np.concatenate([np.zeros(LEADING), z])
    assert model.energy(y) == pytest.approx(columns.energy(z), rel=1e-12)
    np.testing.assert_allclose(model.force(y)[LEADING:], columns.force(z), rtol=1e-12)
    # quadratic instead: the same at small amplitude, not at a crush's
    linear = models[0]
    ratio = [linear.energy(a * y) / model.energy(a * y) for a in (1e-3, 1.0)]
    assert ratio[0] == pytest.approx(1.0, abs=1e-2)
    assert abs(ratio[1] - 1.0) > 1e-2


@pytest.mark.parametrize("exact", [False, True])
def test_at_small_amplitude_it_is_the_exact_energy_on_every_column(models, exact):
    model, every = models[int(exact)], models[4]
    for scale in (1e-4, 1e-3):
        y = _point(model.r, scale, seed=2)
        exact, linear = every.energy(y), model.energy(y)
        # the columns' nonlinear terms are O(|y|³) against the O(|y|²) energy
        assert abs(linear - exact) < 20 * scale * abs(exact)
    y = _point(model.r, 1e-4, seed=3)
    np.testing.assert_allclose(model.force(y), every.force(y), rtol=0,
                               atol=1e-2 * np.abs(every.force(y)).max())
