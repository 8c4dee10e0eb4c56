"""Real files from outside the project: the sample CAD and STL files of Debian's
``occt-misc`` (installed by scripts/setup) and the PLY meshes bundled with pyvista.

Each file gets its expected outcome: read, repaired (with the reported counts), or
refused in one line that says how to go on (pieces with their volumes, holes with
``fill_holes``, no solid in a CAD file).
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np
import pytest

from lbshape.cli import main as cli_main
from lbshape.errors import LbshapeError
from lbshape.geometry.cad_files import step_unit
from lbshape.geometry.mesh import check_mesh
from lbshape.geometry.mesh_files import read_mesh_file, read_surface
from lbshape.geometry.surface_repair import pieces, repair_surface

OCCT = Path("/usr/share/opencascade/data")
needs_occt = pytest.mark.skipif(
    not OCCT.is_dir(), reason="Debian package occt-misc not installed (scripts/setup "
    "installs it): its sample CAD/STL files are missing")


def _pyvista_example(name: str) -> Path:
    import pyvista

    return Path(os.path.dirname(pyvista.__file__)) / "examples" / name


def _one_line_error(info) -> str:
    message = str(info.value)
    assert "\n" not in message
    return message


def _gmsh_mass(path: Path, tag_index: int = 0, unit: str = "") -> float:
    """The volume OpenCASCADE itself gives the solid (file units unless ``unit``)."""
    from lbshape.geometry.mesh import gmsh_model

    with gmsh_model("mass") as gmsh:
        gmsh.option.setString("Geometry.OCCTargetUnit", unit)
        gmsh.model.occ.importShapes(str(path))
        gmsh.model.occ.synchronize()
        gmsh.option.setString("Geometry.OCCTargetUnit", "")
        return gmsh.model.occ.getMass(3, gmsh.model.getEntities(3)[tag_index][1])


# ---------------------------------------------------------------- pyvista PLY
def test_ant_pieces_listed_with_volumes_then_chosen():
    ant = _pyvista_example("ant.ply")
    with pytest.raises(LbshapeError, match="15 disconnected pieces") as info:
        read_mesh_file(ant)
    message = _one_line_error(info)
    assert "volumes in m³: 0: 81.3, 1: 151," in message and "14: 166" in message
    assert "piece = k" in message and 'piece = "largest"' in message
    points, tris = read_surface(ant)
    _, volumes = pieces(*repair_surface(points, tris, piece="largest")[:2])
    largest = read_mesh_file(ant, piece="largest")
    assert largest.volume() == pytest.approx(volumes[0], rel=1e-9)
    assert largest.volume() == pytest.approx(165.59, rel=1e-4)
    with pytest.raises(LbshapeError, match="piece = 15 is not one of the 15 pieces"):
        read_mesh_file(ant, piece=15)


def test_airplane_holes_then_filled_then_a_piece(caplog):
    airplane = _pyvista_example("airplane.ply")
    with pytest.raises(LbshapeError, match="surface is open: 10 holes") as info:
        read_mesh_file(airplane)
    assert "fill_holes = true" in _one_line_error(info)
    with pytest.raises(LbshapeError, match="7 disconnected pieces"):
        read_mesh_file(airplane, fill_holes=True)
    with caplog.at_level(logging.WARNING):
        mesh = read_mesh_file(airplane, fill_holes=True, piece="largest")
    assert "filled 10 holes with 222 triangles, kept piece 2 of 7" in caplog.text
    assert mesh.volume() == pytest.approx(2.189e7, rel=1e-3)


@pytest.mark.parametrize("name", ["nut.ply", "sphere.ply"])
def test_clean_ply_reads_without_repair(name, caplog):
    with caplog.at_level(logging.WARNING):
        mesh = read_mesh_file(_pyvista_example(name))
    assert "repaired" not in caplog.text
    assert check_mesh(mesh).n_tets > 0


def test_units_scale_a_surface_volume_by_1e_minus_9():
    nut = _pyvista_example("nut.ply")
    metres, millimetres = read_mesh_file(nut), read_mesh_file(nut, units="mm")
    assert millimetres.volume() == pytest.approx(1e-9 * metres.volume(), rel=1e-9)
    np.testing.assert_allclose(millimetres.points, 1e-3 * metres.points, rtol=1e-12)
    inches = read_mesh_file(nut, scale=0.0254)
    assert inches.volume() == pytest.approx(0.0254 ** 3 * metres.volume(), rel=1e-9)
    with pytest.raises(LbshapeError, match="unknown units 'ft' .*m, mm, cm, in"):
        read_mesh_file(nut, units="ft")


# ------------------------------------------------------------ occt-misc STL
@needs_occt
def test_propeller_repair_counts():
    points, tris = read_surface(OCCT / "stl" / "propeller.stl")
    _, _, report = repair_surface(points, tris, source="propeller.stl")
    assert report.summary() == "removed 1 zero-area triangles, flipped 4 triangles"


@needs_occt
@pytest.mark.slow
def test_propeller_zero_area_triangle_repaired(caplog):
    with caplog.at_level(logging.WARNING):
        mesh = read_mesh_file(OCCT / "stl" / "propeller.stl")
    assert ("repaired " + str(OCCT / "stl" / "propeller.stl") +
            ": removed 1 zero-area triangles, flipped 4 triangles") in caplog.text
    assert mesh.volume() == pytest.approx(1.95292e6, rel=1e-5)


@needs_occt
@pytest.mark.parametrize("fill_holes", [False, True])
def test_bearing_zero_area_triangles_removed_then_its_missing_face_named(fill_holes):
    # 16 zero-area triangles (two vertices equal) go; what is left has a hole 98 % of
    # the diagonal wide: a missing face, which hole filling would only guess
    with pytest.raises(LbshapeError) as info:
        read_mesh_file(OCCT / "stl" / "bearing.stl", fill_holes=fill_holes)
    message = _one_line_error(info)
    assert (": removed 16 zero-area triangles; surface is open: 2 holes (boundary loops, 134 "
            "edges, the largest 108, the widest 158 m, 98 % of the diagonal)") in message
    assert "1 hole(s) wider than 50% of the diagonal are missing faces" in message
    assert "set fill_holes" not in message


@needs_occt
@pytest.mark.slow
def test_head_is_open_and_says_how_many_holes_and_how_wide():
    with pytest.raises(LbshapeError, match="surface is open: 45 holes") as info:
        read_mesh_file(OCCT / "stl" / "head.stl")
    message = _one_line_error(info)
    assert "the widest 85.2 m, 20 % of the diagonal); set fill_holes = true" in message


@needs_occt
@pytest.mark.slow
def test_head_holes_left_by_filling_are_counted_with_their_cause():
    with pytest.raises(LbshapeError) as info:
        read_mesh_file(OCCT / "stl" / "head.stl", fill_holes=True)
    assert ("surface is open: fill_holes closed 23 of 45 holes, 22 holes (boundary loops, 136 "
            "edges, the largest 23) remain; the surface has 64 non-manifold edges") in (
                _one_line_error(info))


@needs_occt
@pytest.mark.slow
def test_piece_on_a_file_of_one_piece_is_refused(capsys):
    shape = OCCT / "stl" / "shape.stl"
    with pytest.raises(LbshapeError, match=r"piece = 1, but the surface has one piece "
                       r"\(volume 3.29e\+05 m³\); leave out piece") as info:
        read_mesh_file(shape, piece=1)
    _one_line_error(info)
    assert read_mesh_file(shape, piece=0).volume() == pytest.approx(328753, rel=1e-5)
    assert cli_main(["mesh", str(OCCT / "occ" / "wedge_ok.brep"), "--piece", "2",
                     "--size", "2"]) == 2
    error = capsys.readouterr().err.strip()
    assert error.count("\n") == 0
    assert "piece = 2, but the CAD file has one piece (volume 560 m³)" in error


@needs_occt
@pytest.mark.slow
def test_piece_out_of_range_lists_the_solids():
    with pytest.raises(LbshapeError, match=r"piece = 5 is not one of the 2 pieces "
                       r"\(volumes in m³: 0: 4.71e-07, 1: 4.14e-06\)"):
        read_mesh_file(OCCT / "occ" / "Ball.brep", size=2e-3, units="mm", piece=5)


@needs_occt
def test_clean_stl_reads():
    mesh = read_mesh_file(OCCT / "stl" / "shape.stl")
    assert mesh.volume() == pytest.approx(328753, rel=1e-5)


# --------------------------------------------------------- occt-misc CAD
@needs_occt
def test_step_solid_meshes_to_occ_volume():
    screw = OCCT / "step" / "screw.step"  # recorded in millimetres
    mesh = read_mesh_file(screw, size=0.004)
    assert check_mesh(mesh).n_tets > 100
    assert mesh.volume() == pytest.approx(_gmsh_mass(screw, unit="M"), rel=0.08)


@needs_occt
@pytest.mark.slow
def test_step_converts_from_its_recorded_millimetres():
    rods = OCCT / "step" / "linkrods.step"  # recorded in millimetres
    mass = _gmsh_mass(rods, unit="M")
    assert mass == pytest.approx(3.847e-9, rel=1e-3)
    for units in ("m", "mm"):  # STEP records its unit: the same metres either way
        assert read_mesh_file(rods, size=0.002, units=units).volume() == pytest.approx(
            mass, rel=0.03)


@needs_occt
@pytest.mark.slow
def test_step_units_and_scale_override_its_recorded_unit(caplog):
    rods = OCCT / "step" / "linkrods.step"
    assert step_unit(rods) == "mm" and step_unit(OCCT / "step" / "screw.step") == "mm"
    box_mm = np.array([5.02028, 1.49379, 2.0])  # the numbers as written
    with caplog.at_level(logging.WARNING):
        inches = read_mesh_file(rods, size=0.05, units="in")
    assert "linkrods.step records its numbers in mm; read as in" in caplog.text
    np.testing.assert_allclose(np.ptp(inches.points, axis=0), 0.0254 * box_mm, rtol=2e-3)
    tenfold = read_mesh_file(rods, size=0.02, scale=0.01)  # a 10:1 model of the part
    np.testing.assert_allclose(np.ptp(tenfold.points, axis=0), 0.01 * box_mm, rtol=2e-3)
    # the size scales with the part: the same tetrahedra at h / 10 in metres
    assert tenfold.n_tets == read_mesh_file(rods, size=0.002, scale=0.001).n_tets


@needs_occt
@pytest.mark.slow
def test_brep_in_millimetres_scales_volume_by_1e_minus_9():
    wedge = OCCT / "occ" / "wedge_ok.brep"
    mass = _gmsh_mass(wedge)
    assert mass == pytest.approx(560.0, rel=1e-9)
    in_m = read_mesh_file(wedge, size=2.0)
    in_mm = read_mesh_file(wedge, size=2e-3, units="mm")
    assert in_m.volume() == pytest.approx(mass, rel=1e-9)
    assert in_mm.volume() == pytest.approx(1e-9 * mass, rel=1e-9)
    assert in_mm.n_tets == in_m.n_tets


@needs_occt
@pytest.mark.slow
def test_brep_of_two_solids_lists_them():
    ball = OCCT / "occ" / "Ball.brep"
    with pytest.raises(LbshapeError, match="CAD file has 2 solids") as info:
        read_mesh_file(ball, size=2e-3, units="mm")
    assert "volumes in m³: 0: 4.71e-07, 1: 4.14e-06" in _one_line_error(info)
    mesh = read_mesh_file(ball, size=2e-3, units="mm", piece="largest")
    assert mesh.volume() == pytest.approx(4.14e-6, rel=0.02)


@needs_occt
@pytest.mark.parametrize("path, found", [("iges/hammer.iges", "45 faces"),
                                         ("occ/face.brep", "1 faces")])
def test_cad_file_without_solid_is_one_line(path, found):
    with pytest.raises(LbshapeError, match=f"no solid in the CAD file \\(found {found}") as info:
        read_mesh_file(OCCT / path, size=1.0)
    _one_line_error(info)


@needs_occt
@pytest.mark.slow
def test_cli_mesh_brep_in_millimetres(tmp_path, capsys):
    out = tmp_path / "wedge.msh"
    assert cli_main(["mesh", str(OCCT / "occ" / "wedge_ok.brep"), "--units", "mm",
                     "--size", "0.002", "-o", str(out)]) == 0
    assert "tets" in capsys.readouterr().out
    assert read_mesh_file(out).volume() == pytest.approx(5.6e-7, rel=1e-9)
    with pytest.raises(SystemExit):
        cli_main(["mesh", str(OCCT / "occ" / "wedge_ok.brep"), "--units", "ft"])
