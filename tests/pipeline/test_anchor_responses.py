"""Local examples: the precomputed basis holds the object's responses to each region's
anchor fit (its loads ``M_R Q_R`` and its read-out ``F_Rᵀ``, shifted by the example
spring), the feedback through which the reduced run drifted from the full one
(``docs/decisions.md``, "Local examples' anchor responses: built, off by default")."""

from __future__ import annotations

import dataclasses

import numpy as np

from lbshape.elastic.element_kernels import mass_matrix
from lbshape.pipeline import responses
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.responses import (
    anchor_responses,
    anchor_room,
    example_response_stiffness,
)
from lbshape.pipeline.simulate import full_simulation
from lbshape.scene.reader import load_scene
from lbshape.scene.schema import LocalRegion, Selection


def test_example_basis_holds_the_anchor_responses_of_local_examples(tmp_path, monkeypatch):
    monkeypatch.setenv("LBSHAPE_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(responses, "ANCHOR_RESPONSE_SETS", 2)  # both sets, all columns
    demo = load_scene("demo")
    scene = dataclasses.replace(demo, name="demo-two-regions", regions=(
        LocalRegion("low", Selection(region="z < 0.5"), (0,)),
        LocalRegion("high", Selection(region="z >= 0.5"), (1,))))
    pre = precompute(scene, save=False)
    full = full_simulation(scene, pre)
    n3 = pre.U.shape[0]
    K = full.elastic.tangent(np.zeros(n3))
    load, readout = anchor_responses(K, full._local.mass, example_response_stiffness(scene),
                                     pre.mesh, pre.material.density, pre.local.regions,
                                     pre.fixed_vertices, sets=2)
    anchored = sum(region.anchor.any() for region in pre.local.regions)
    assert anchored >= 1 and load.shape == readout.shape == (n3, 6 * anchored)
    mass = mass_matrix(pre.mesh, pre.material.density)
    for X in (load, readout):
        outside = X - pre.U @ (pre.U.T @ (mass @ X))
        share = (np.sqrt(np.einsum("ij,ij->j", outside, mass @ outside))
                 / np.sqrt(np.einsum("ij,ij->j", X, mass @ X)))
        assert share.max() < 1e-6, share.max()




def test_anchor_room_keeps_the_exact_polynomial_force():
    """The anchor responses enter only while the reduced force stays the exact polynomial
    one: all under ``polynomial``, none under ``cubature``, and under ``auto`` as many as
    its build budget allows (teddy-local's 1896 elements at r = 48: 16)."""
    scene = load_scene("teddy-local")

    def forces(choice):
        return dataclasses.replace(scene, reduced=dataclasses.replace(scene.reduced,
                                                                      forces=choice))

    assert anchor_room(forces("polynomial"), 1896, 48, 48) == 48
    assert anchor_room(forces("cubature"), 1896, 48, 48) == 0
    assert anchor_room(forces("auto"), 1896, 48, 48) == 16
    assert anchor_room(forces("auto"), 1896, 70, 48) == 0
