"""The density convention of the shape-space maps, through the real pipeline.

``projection`` is ``T = Uᵀ M L`` with U orthonormal in the elastic mass ``M = ρ M₃``
(:mod:`lbshape.shapespace.projections`). Two checks that a missed or doubled density
factor (a silent ×√ρ, ×31.6 at ρ = 1000) cannot pass:

* on a precompute: ``U T c`` is the M-projection of ``L c`` onto span U, and the
  descriptor matrix reads the full-space descriptor of ``U q``
  (:func:`lbshape.pipeline.influence.descriptor`, computed on the n-sized field);
* physics: scaling the density and Young's modulus by one factor (gravity and the
  example pull scale with ρ, the elastic force with E) leaves every displacement and
  every example weight of a run unchanged, while the reduced coordinates scale by √10.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np
import pytest

from lbshape.dynamics.record import RunRecord
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.pipeline.influence import descriptor
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.precomputed import Precomputed
from lbshape.pipeline.simulate import reduced_simulation
from lbshape.scene import scene_from_dict

STEPS = 25
SCALE = 10.0


def _scene(density: float, young: float):
    twist = {"shape": "demo-bar", "pose": "twist",
             "parameters": {"angle": 0.8, "axis": "z", "anchor": "max"}}
    back = {"shape": "demo-bar", "pose": "twist",
            "parameters": {"angle": -0.4, "axis": "z", "anchor": "max"}}
    return scene_from_dict({
        "name": f"density-{density:g}", "object": {"shape": "demo-bar"},
        "material": {"model": "stvk", "young": young, "poisson": 0.3, "density": density},
        "reduced": {"m": 6, "r": 12, "s": 20}, "fixed": {"region": "z > 0.999"},
        "examples": {"stiffness": 2000.0, "pose": [twist, back]},
        "loads": [{"type": "gravity", "vector": [3.0, 0.0, -9.81]}],
        "simulation": {"dt": 0.002, "steps": STEPS},
    })


class Run(NamedTuple):
    pre: Precomputed
    record: RunRecord
    weights: np.ndarray  #: (steps, k) the example weights after each step


def _run(scale: float) -> Run:
    scene = _scene(1000.0 * scale, 1.0e5 * scale)
    pre = precompute(scene, save=False)
    sim = reduced_simulation(scene, pre)
    weights = []
    record = sim.run(STEPS, on_step=lambda *_: weights.append(sim.driver.w.copy()))
    assert record.stable, record.message
    return Run(pre, record, np.array(weights))


@pytest.fixture(scope="module")
def runs() -> dict[float, Run]:
    return {scale: _run(scale) for scale in (1.0, SCALE)}


def test_projection_is_the_mass_projection_and_descriptors_read_the_field(runs):
    pre = runs[SCALE].pre
    rng = np.random.default_rng(0)
    M = mass_matrix(pre.mesh, pre.material.density)  # elastic mass (kg)
    U, L, T = pre.U, pre.shape.lb_basis(), pre.examples.lb_to_reduced
    c = rng.normal(size=L.shape[1])
    projected = U @ np.linalg.solve(U.T @ (M @ U), U.T @ (M @ (L @ c)))
    np.testing.assert_allclose(U @ (T @ c), projected, rtol=0,
                               atol=1e-9 * np.abs(projected).max())
    q = rng.normal(size=pre.r)
    expected = descriptor(pre, (U @ q).reshape(-1, 3))
    np.testing.assert_allclose(pre.examples.descriptor_matrix @ q, expected, rtol=0,
                               atol=1e-9 * np.abs(expected).max())
    # the clamped basis' map obeys the same convention
    clamped = dataclasses.replace(pre.examples, projection=pre.examples.projection_clamped)
    L_F = pre.shape.lb_basis(clamped=True)
    projected = U @ np.linalg.solve(U.T @ (M @ U), U.T @ (M @ (L_F @ c)))
    np.testing.assert_allclose(U @ (clamped.lb_to_reduced @ c), projected, rtol=0,
                               atol=1e-9 * np.abs(projected).max())


def test_scaling_density_and_stiffness_together_changes_no_displacement(runs):
    one, scaled = runs[1.0], runs[SCALE]
    u1, u2 = one.record.displacements(one.pre.U), scaled.record.displacements(scaled.pre.U)
    w1, w2 = one.weights, scaled.weights
    assert np.abs(u1).max() > 1e-3  # the run moves
    np.testing.assert_allclose(u2, u1, rtol=0, atol=1e-7 * np.abs(u1).max())
    np.testing.assert_allclose(w2, w1, rtol=0, atol=1e-7)
    assert 0.05 < w1[-1].min() and w1[-1].max() < 0.95  # both examples pull
    # the reduced coordinates carry the √ρ of U's normalisation
    q1, q2 = np.asarray(one.record.states), np.asarray(scaled.record.states)
    np.testing.assert_allclose(q2, np.sqrt(SCALE) * q1, rtol=0, atol=1e-7 * np.abs(q2).max())
