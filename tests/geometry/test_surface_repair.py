"""Surface repair on a synthetic box: each defect repaired and counted exactly."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from lbshape.errors import LbshapeError
from lbshape.geometry.mesh_files import tetrahedralise_surface
from lbshape.geometry.primitives import structured_box
from lbshape.geometry.surface_repair import repair_surface, signed_volume

SIZE = (1.0, 0.6, 0.4)


@pytest.fixture(scope="module")
def box():
    mesh = structured_box(SIZE, (3, 2, 2))
    tris = mesh.boundary_faces()
    used = np.unique(tris)
    index = np.full(mesh.n_vertices, -1)
    index[used] = np.arange(used.size)
    return mesh.points[used], index[tris]


def test_every_defect_counted_in_one_warning(box, caplog):
    points, tris = box
    soup = points[tris].reshape(-1, 3)  # an STL: each triangle its own three vertices
    faces = np.arange(soup.shape[0]).reshape(-1, 3)
    faces[:3] = faces[:3, ::-1]  # three triangles wound the wrong way
    collapsed = [[faces[5, 0], faces[5, 1], faces[5, 1]]]
    faces = np.vstack([faces, faces[7:9], collapsed])  # two duplicates, one zero-area
    with caplog.at_level(logging.WARNING):
        p, t, report = repair_surface(soup, faces, source="part.stl")
    merged = soup.shape[0] - points.shape[0]
    assert caplog.messages == [
        f"repaired part.stl: merged {merged} duplicate vertices, removed 1 zero-area "
        "triangles, removed 2 duplicate triangles, flipped 3 triangles"]
    assert t.shape == tris.shape and signed_volume(p, t) == pytest.approx(np.prod(SIZE))
    assert report.flipped == 3


def test_a_clean_surface_is_left_alone(box, caplog):
    with caplog.at_level(logging.WARNING):
        p, t, report = repair_surface(*box)
    assert caplog.messages == [] and report.summary() == ""
    assert p.shape == box[0].shape and t.shape == box[1].shape


def test_holes_counted_then_filled(box, caplog):
    points, tris = box
    holed = np.delete(tris, [0, 9], axis=0)  # two holes, apart
    with pytest.raises(LbshapeError, match="surface is open: 2 holes .*fill_holes = true"):
        repair_surface(points, holed, source="holed")
    with caplog.at_level(logging.WARNING):
        p, t, report = repair_surface(points, holed, source="holed", fill_holes=True)
    assert report.holes_filled == 2 and "filled 2 holes" in caplog.text
    mesh = tetrahedralise_surface(p, t, source="holed")
    assert mesh.volume() == pytest.approx(np.prod(SIZE), rel=1e-9)


def test_pieces_listed_then_chosen(box):
    points, tris = box
    two = np.vstack([points, 0.5 * points + [3.0, 0, 0]])
    faces = np.vstack([tris, tris + points.shape[0]])
    with pytest.raises(LbshapeError, match=r"2 disconnected pieces \(volumes in m³: 0: 0.24, "
                       r"1: 0.03\); choose one with piece = k .* or piece = \"largest\""):
        repair_surface(two, faces, source="two")
    for piece, volume in ((1, 0.03), ("largest", 0.24)):
        p, t, _ = repair_surface(two, faces, piece=piece)
        assert signed_volume(p, t) == pytest.approx(volume)
