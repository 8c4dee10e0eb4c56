"""Local examples: with a strong pull the precomputed basis holds the object's responses to
each region's anchor fit, carried through the anchored operator's adjoint — the feedback
through which the reduced run drifted from the full one (``docs/decisions.md``, "Local
examples: k_ex raised to the regions' static equilibrium")."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from lbshape.elastic.element_kernels import mass_matrix
from lbshape.elastic.polynomial_forces import POLYNOMIAL_BUILD_FLOPS, polynomial_build_flops
from lbshape.geometry.mesh import free_dof_mask
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.responses import (
    anchor_fit_fields,
    anchor_responses,
    anchor_room,
    anchored_readout_responses,
    strongly_pulled_regions,
)
from lbshape.pipeline.simulate import full_simulation
from lbshape.scene.reader import load_scene
from lbshape.scene.schema import LocalRegion, Selection
from lbshape.scene.variants import with_stiffness


def _two_regions(k_ex: float):
    """The demo bar with its two examples as local examples on its two halves."""
    demo = load_scene("demo")
    scene = dataclasses.replace(demo, name="demo-two-regions", regions=(
        LocalRegion("low", Selection(region="z < 0.5"), (0,)),
        LocalRegion("high", Selection(region="z >= 0.5"), (1,))))
    return with_stiffness(scene, k_ex)


def _outside_share(U, X, mass) -> float:
    outside = X - U @ (U.T @ (mass @ X))
    return float((np.sqrt(np.einsum("ij,ij->j", outside, mass @ outside))
                  / np.sqrt(np.einsum("ij,ij->j", X, mass @ X))).max())


@pytest.mark.slow
def test_a_strong_pull_puts_the_anchored_read_outs_in_the_basis(tmp_path, monkeypatch):
    """k_ex at or above the softest region example's ω² (21,470 1/s² here): the basis
    holds every anchored read-out response (to 1e-6 of a column); far below it none is
    added."""
    monkeypatch.setenv("LBSHAPE_CACHE", str(tmp_path / "cache"))
    strong, weak = _two_regions(30000.0), _two_regions(1.0)
    pre = precompute(strong, save=False)
    full = full_simulation(strong, pre)
    K = full.elastic.tangent(np.zeros(pre.U.shape[0]))
    def pulled(k):
        return strongly_pulled_regions(k, pre.mesh, pre.material, pre.local.regions)

    assert pulled(30000.0) == ("low", "high") and pulled(1.0) == ()
    assert pulled(25000.0) == ("low",)  # the softer half only (ω_e² 21,470 / 29,659)
    X = anchored_readout_responses(K, full._local.mass, 30000.0, pre.mesh,
                                   pre.material.density, pre.local.regions,
                                   pre.fixed_vertices)
    anchored = sum(region.anchor.any() for region in pre.local.regions)
    assert anchored >= 1 and X.shape == (pre.U.shape[0], 6 * anchored)
    mass = mass_matrix(pre.mesh, pre.material.density)
    assert _outside_share(pre.U, X, mass) < 1e-6
    assert _outside_share(precompute(weak, save=False).U, X, mass) > 1e-2
    low = anchored_readout_responses(K, full._local.mass, 30000.0, pre.mesh,
                                     pre.material.density, pre.local.regions,
                                     pre.fixed_vertices, pulled=("low",))
    assert low.shape[1] == 6 and np.abs(low - X[:, :6]).max() <= 1e-10 * np.abs(X).max()


@pytest.mark.slow
def test_the_adjoint_read_outs_solve_the_anchored_operator():
    """``anchored_readout_responses`` (Woodbury on the spring-shifted Cholesky) equals a
    direct sparse solve ``Aᵀ Y = B⁻¹ F_Rᵀ``, A = K + k (S − G) built from the full-space
    force's own coupling G, to 1e-8; and G is the fit's ``L Rᵀ``."""
    scene = load_scene("teddy-local")
    pre = precompute(scene)
    full = full_simulation(scene, pre)
    n3, k = pre.U.shape[0], 2500.0
    K = full.elastic.tangent(np.zeros(n3)).tocsr()
    S, G = full._local.mass, full._local.anchor_coupling()
    L, R = anchor_fit_fields(pre.mesh, pre.material.density, pre.local.regions)
    assert abs(G - sp.csr_matrix(L @ R.T)).max() < 1e-12 * abs(G).max()
    free = free_dof_mask(pre.mesh.n_vertices, pre.fixed_vertices)
    (readout,) = anchor_responses(K, S, k, pre.mesh, pre.material.density,
                                  pre.local.regions, pre.fixed_vertices, sets=2)[1:]
    A = (K + k * (S - G)).tocsr()[free][:, free]
    direct = spla.splu(A.T.tocsc()).solve(readout[free])
    X = anchored_readout_responses(K, S, k, pre.mesh, pre.material.density,
                                   pre.local.regions, pre.fixed_vertices)
    assert np.abs(X[~free]).max() == 0.0
    assert np.abs(X[free] - direct).max() < 1e-8 * np.abs(direct).max()


def test_anchor_room_keeps_the_exact_polynomial_force():
    """The anchor responses enter only while the reduced force stays the exact polynomial
    one: all under ``polynomial``, none under ``cubature``, and under ``auto`` as many as
    its build budget allows (teddy-local's 1896 elements: up to the largest r it builds)."""
    scene = load_scene("teddy-local")

    def forces(choice):
        return dataclasses.replace(scene, reduced=dataclasses.replace(scene.reduced,
                                                                      forces=choice))

    largest = max(r for r in range(1, 200)
                  if polynomial_build_flops(1896, r) <= POLYNOMIAL_BUILD_FLOPS)
    assert largest >= 72  # teddy-local's 48 columns and its 24 read-outs
    assert anchor_room(forces("polynomial"), 1896, 48, 48) == 48
    assert anchor_room(forces("cubature"), 1896, 48, 48) == 0
    assert anchor_room(forces("auto"), 1896, 48, 48) == largest - 48
    assert anchor_room(forces("auto"), 1896, largest + 1, 48) == 0
