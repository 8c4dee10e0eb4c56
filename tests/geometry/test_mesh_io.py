"""Mesh loading and checks: every kind of bad input gets a clear one-line error."""

from __future__ import annotations

import numpy as np
import pytest

from lbshape.errors import LbshapeError
from lbshape.geometry.mesh import (
    TetMesh,
    boundary_faces,
    check_mesh,
    gmsh_session,
    interpolate_at,
    load_mesh,
    locate_points,
)
from lbshape.geometry.primitives import structured_box


def _write_msh(path, points, tets, *, element_type=4):
    """Write a mesh with gmsh (format 4.1) from raw arrays; element type 4 = tet4."""
    with gmsh_session() as gmsh:
        gmsh.clear()
        gmsh.model.add("fixture")
        tag = gmsh.model.addDiscreteEntity(3)
        n = len(points)
        gmsh.model.mesh.addNodes(3, tag, list(range(1, n + 1)), np.asarray(points).ravel())
        nodes = (np.asarray(tets) + 1).ravel().tolist()
        n_per = {4: 4, 5: 8}[element_type]
        count = len(nodes) // n_per
        gmsh.model.mesh.addElementsByType(tag, element_type, list(range(1, count + 1)), nodes)
        gmsh.write(str(path))
        gmsh.clear()


def test_round_trip_through_msh(tmp_path):
    box = structured_box((2.0, 1.0, 0.5), (4, 2, 2))
    path = tmp_path / "box.msh"
    _write_msh(path, box.points, box.tets)
    loaded = load_mesh(path)
    np.testing.assert_allclose(loaded.points, box.points, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(loaded.tets, box.tets)
    assert loaded.volume() == pytest.approx(1.0, rel=1e-12)


def test_boundary_faces_are_closed_and_outward():
    box = structured_box((2.0, 1.0, 0.5), (3, 2, 2))
    faces = boundary_faces(box.tets)
    p = box.points[faces]
    normals = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]) / 2.0
    # divergence theorem: sum of (x . n) dA over the closed surface = 3 * volume
    flux = np.einsum("ij,ij->", p.mean(axis=1), normals)
    assert flux == pytest.approx(3.0 * box.volume(), rel=1e-12)
    assert np.allclose(normals.sum(axis=0), 0.0, atol=1e-12)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (None, "not found"),
        ("this is not a mesh\n", "not a readable gmsh file"),
        ("$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n1 2\n", "not a readable gmsh file"),
    ],
)
def test_missing_or_garbage_file(tmp_path, content, message):
    path = tmp_path / "bad.msh"
    if content is not None:
        path.write_text(content)
    with pytest.raises(LbshapeError, match=message) as info:
        load_mesh(path)
    assert "\n" not in str(info.value)


def test_wrong_extension(tmp_path):
    path = tmp_path / "mesh.obj"
    path.write_text("v 0 0 0\n")
    with pytest.raises(LbshapeError, match="unsupported mesh format"):
        load_mesh(path)


def test_no_tetrahedra(tmp_path):
    path = tmp_path / "hexes.msh"
    cube = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0],
                     [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], dtype=float)
    _write_msh(path, cube, [list(range(8))], element_type=5)
    with pytest.raises(LbshapeError, match="only 4-node tetrahedra"):
        load_mesh(path)


def test_nan_coordinates():
    box = structured_box((1, 1, 1), (2, 2, 2))
    points = box.points.copy()
    points[5, 1] = np.nan
    with pytest.raises(LbshapeError, match="NaN or infinite coordinates.*vertex 5"):
        check_mesh(TetMesh(points, box.tets))


def test_degenerate_tet():
    box = structured_box((1, 1, 1), (2, 2, 2))
    points = np.vstack([box.points, [[3, 3, 3], [4, 3, 3], [5, 3, 3], [6, 3, 3]]])
    flat = np.array([[len(points) - 4, len(points) - 3, len(points) - 2, len(points) - 1]])
    with pytest.raises(LbshapeError, match="degenerate"):
        check_mesh(TetMesh(points, np.vstack([box.tets, flat])), require_connected=False)


def test_inverted_tets_are_reoriented_consistently(caplog):
    box = structured_box((1, 1, 1), (2, 2, 2))
    tets = box.tets.copy()
    tets[::3] = tets[::3][:, [1, 0, 2, 3]]
    fixed = check_mesh(TetMesh(box.points, tets))
    assert (fixed.signed_volumes() > 0).all()
    assert fixed.volume() == pytest.approx(1.0, rel=1e-12)
    assert "re-oriented" in caplog.text


def test_disconnected_pieces(tmp_path):
    a = structured_box((1, 1, 1), (1, 1, 1))
    b = structured_box((1, 1, 1), (1, 1, 1), origin=(5, 0, 0))
    points = np.vstack([a.points, b.points])
    tets = np.vstack([a.tets, b.tets + a.n_vertices])
    path = tmp_path / "two.msh"
    _write_msh(path, points, tets)
    with pytest.raises(LbshapeError, match="2 disconnected pieces"):
        load_mesh(path)
    assert load_mesh(path, require_connected=False).n_tets == 12


def test_unused_vertices_are_dropped():
    box = structured_box((1, 1, 1), (1, 1, 1))
    points = np.vstack([[[9.0, 9.0, 9.0]], box.points])
    mesh = check_mesh(TetMesh(points, box.tets + 1))
    assert mesh.n_vertices == box.n_vertices
    np.testing.assert_allclose(mesh.points, box.points)


def test_index_out_of_range():
    box = structured_box((1, 1, 1), (1, 1, 1))
    tets = box.tets.copy()
    tets[0, 0] = 100
    with pytest.raises(LbshapeError, match="out of range"):
        check_mesh(TetMesh(box.points, tets))


def test_locate_points_interpolates_a_linear_field_exactly_across_meshes():
    """Points of a coarse box located in a finer box's elements: the barycentric weights
    reproduce each point and any linear field (P1 holds it exactly); a point beyond the
    mesh is clipped onto its nearest element and reported outside."""
    fine = structured_box(size=(0.3, 0.1, 0.1), divisions=(6, 3, 3))
    coarse = structured_box(size=(0.3, 0.1, 0.1), divisions=(2, 1, 1))
    rng = np.random.default_rng(0)
    inside = rng.uniform((0.0, 0.0, 0.0), (0.3, 0.1, 0.1), size=(50, 3))
    queries = np.vstack([coarse.points, inside])
    cells, weights, outside = locate_points(fine.points, fine.tets, queries)
    assert np.all(weights >= 0.0) and np.allclose(weights.sum(axis=1), 1.0)
    assert outside.max() < 1e-9
    corners = fine.points[fine.tets[cells]]  # (q, 4, 3)
    np.testing.assert_allclose(np.einsum("qk,qkd->qd", weights, corners), queries, atol=1e-12)
    A = np.array([[1.0, 2.0, 0.0], [0.0, -1.0, 3.0], [0.5, 0.0, 1.0]])
    frames = np.stack([fine.points @ A + 0.2, 2.0 * fine.points])  # (2, n, 3)
    values = interpolate_at(fine.points, fine.tets, frames, queries)
    np.testing.assert_allclose(values[0], queries @ A + 0.2, atol=1e-12)
    np.testing.assert_allclose(values[1], 2.0 * queries, atol=1e-12)
    far = np.array([[0.35, 0.05, 0.05]])  # 0.05 m beyond the box's end
    _, weights, outside = locate_points(fine.points, fine.tets, far)
    assert outside[0] > 0.5 and np.all(weights >= 0.0)
    with pytest.raises(LbshapeError, match="1 points lie outside"):
        interpolate_at(fine.points, fine.tets, frames, far)
