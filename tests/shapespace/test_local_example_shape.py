"""Where the runtime places a region's example (the local examples' pictures draw it)."""

from __future__ import annotations

import numpy as np
import pytest

from lbshape.elastic.element_kernels import mass_matrix
from lbshape.pipeline.precompute import precompute
from lbshape.scene.reader import load_scene
from lbshape.shapespace.local_driver import local_example_shape
from lbshape.shapespace.local_regions import anchor_fit


@pytest.fixture(autouse=True)
def _private_cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("LBSHAPE_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))


def _placed_by_hand(mesh, space, indices) -> np.ndarray | None:
    """The placement written out: each region's first example of ``indices`` as
    ``L_R c_k − Q_R F_R (L_R c_k)_anchor`` (the rest state's anchor fit), the mean
    where regions share a vertex, None when no region uses one of them."""
    u, count = np.zeros((mesh.n_vertices, 3)), np.zeros(mesh.n_vertices)
    for region in space.regions:
        hits = np.flatnonzero(np.isin(region.examples, indices))
        if hits.size == 0:
            continue
        shape = region.displacement(region.example_coefficients[hits[0]]).reshape(-1)
        part = region.submesh(mesh)
        Q, F, rows = anchor_fit(part.points, mass_matrix(part, 1.0), region.anchor)
        u[region.vertices] += (shape - Q @ (F @ shape[rows])).reshape(-1, 3)
        count[region.vertices] += 1
    if not count.any():
        return None
    return u / np.maximum(count, 1)[:, None]


@pytest.mark.slow
def test_local_example_shape_is_the_anchored_example_on_the_cross():
    pre = precompute(load_scene("cross"))
    k = max(int(reg.examples.max()) for reg in pre.local.regions) + 1
    for index in range(k):
        placed = local_example_shape(pre.mesh, pre.local, index)
        assert placed is not None and placed.shape == (pre.mesh.n_vertices, 3)
        np.testing.assert_array_equal(placed, _placed_by_hand(pre.mesh, pre.local, [index]))
    strongest = [int(reg.examples[-1]) for reg in pre.local.regions]
    np.testing.assert_array_equal(local_example_shape(pre.mesh, pre.local, strongest),
                                  _placed_by_hand(pre.mesh, pre.local, strongest))
    assert local_example_shape(pre.mesh, pre.local, k) is None
    # attached where each region is attached: the anchor barely moves
    region = pre.local.regions[0]
    placed = local_example_shape(pre.mesh, pre.local, int(region.examples[0]))[region.vertices]
    assert np.abs(placed[region.anchor]).max() < np.abs(placed).max()
