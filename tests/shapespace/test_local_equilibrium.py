"""The local examples' linear static equilibrium and the k_ex that takes every region near
an example (:mod:`lbshape.shapespace.local_equilibrium`), on teddy-local."""

from __future__ import annotations

import numpy as np
import pytest

from lbshape.elastic.element_kernels import mass_matrix
from lbshape.geometry.mesh import free_dof_mask
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.responses import static_load
from lbshape.pipeline.simulate import full_simulation
from lbshape.scene.reader import load_scene
from lbshape.scene.variants import with_stiffness
from lbshape.shapespace.local_equilibrium import (
    CLOSEST_RATIO,
    GROWTH,
    equilibrium_stiffness,
    region_closeness,
    static_equilibrium,
)
from lbshape.shapespace.local_full_force import FullSpaceLocalForce


@pytest.fixture(scope="module")
def teddy():
    scene = load_scene("teddy-local")
    pre = precompute(scene)
    n3 = pre.U.shape[0]
    K = full_simulation(scene, pre).elastic.tangent(np.zeros(n3)).tocsr()
    load = static_load(scene, pre.mesh, mass_matrix(pre.mesh, pre.material.density))
    force = FullSpaceLocalForce(pre.mesh, pre.material, pre.local)
    return scene, pre, K, free_dof_mask(pre.mesh.n_vertices, pre.fixed_vertices), load, force


@pytest.mark.slow
def test_the_equilibrium_balances_the_loads_and_the_pull(teddy):
    """At the returned u the linear equations hold on the free DOFs with the weights u
    itself gives: ``K u + k (S u − pull(u)) = f`` to 1e-8 of f's size, and the pull moved
    it (a nonzero example force)."""
    _, _, K, free, load, force = teddy
    k = 2000.0
    u = static_equilibrium(force, K, free, k, load)
    residual = K @ u + k * (force.mass @ u - force.pull(u)) - load
    assert np.abs(u[~free]).max() == 0.0
    assert np.linalg.norm(residual[free]) < 1e-8 * np.linalg.norm(load)
    without = static_equilibrium(force, K, free, 1e-9, load)
    assert np.linalg.norm(u - without) > 0.1 * np.linalg.norm(without)


@pytest.mark.slow
def test_the_static_equilibrium_predicts_the_full_run(teddy):
    """The regions of the full-space run after 0.5 s sit within 0.1 of the static
    equilibrium's closeness (k_ex = 2000: the right leg 0.97 statically, 0.87 in the
    run), and both say the same region by region: nearer an example or nearer rest."""
    scene, pre, K, free, load, force = teddy
    k = 2000.0
    static = region_closeness(pre.mesh, pre.local.regions,
                              static_equilibrium(force, K, free, k, load),
                              pre.material.density)
    full = full_simulation(with_stiffness(scene, k), pre)
    for _ in range(500):
        full.step()
    dynamic = region_closeness(pre.mesh, pre.local.regions, full.full_displacement(),
                               pre.material.density)
    for name, ratio in static.items():
        assert abs(dynamic[name] - ratio) < 0.1, (name, dynamic[name], ratio)
        assert (dynamic[name] < 1.0) == (ratio < 1.0), (name, dynamic[name], ratio)


@pytest.mark.slow
def test_the_stiffness_is_the_smallest_that_reaches_every_region(teddy):
    """From the rule's 958 1/s² the search ends where every region is within
    CLOSEST_RATIO of an example, and a few per cent lower one is not."""
    _, pre, K, free, load, force = teddy
    k, ratios = equilibrium_stiffness(force, K, free, 958.0, load, pre.mesh,
                                      pre.material.density)
    assert k > 958.0 and max(ratios.values()) <= CLOSEST_RATIO
    below = region_closeness(pre.mesh, pre.local.regions,
                             static_equilibrium(force, K, free, k / GROWTH ** 0.25, load),
                             pre.material.density)
    assert max(below.values()) > CLOSEST_RATIO
    same, _ = equilibrium_stiffness(force, K, free, k * 1.5, load, pre.mesh,
                                    pre.material.density)
    assert same == k * 1.5  # a start that already reaches every region stands
