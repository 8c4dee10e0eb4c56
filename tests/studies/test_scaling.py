"""The cost-growth benchmark: scaled scenes, the report files, the CLI's checks."""

from __future__ import annotations

import csv
import dataclasses

import pytest

from lbshape.cli.main import main
from lbshape.errors import LbshapeError
from lbshape.scene import load_scene
from lbshape.studies import scaling


def point(size, vertices, wall, peak, t_total, ranks=1):
    return scaling.ScalingPoint(
        size=size, n_vertices=vertices, n_tets=5 * vertices, ranks=ranks, wall_seconds=wall,
        peak_mb=peak, stage_seconds={"mesh": 0.1 * wall, "cubature": 0.5 * wall},
        stage_peak_mb={"mesh": 0.5 * peak, "cubature": peak},
        t_total_ms=[t_total, 1.1 * t_total, 0.9 * t_total], t_interp_ms=[0.1, 0.1, 0.1])


def test_scaled_scene_changes_only_the_object_size(tmp_path):
    path = scaling.scaled_scene("bar-cylinder", 0.02, tmp_path)
    scaled, base = load_scene(path), load_scene("bar-cylinder")
    assert scaled.object.size == 0.02 and scaled.object.shape == base.object.shape
    assert scaled.name == "bar-cylinder-h0.02"
    same_forces = dataclasses.replace(base.reduced, forces="cubature")  # one model at every size
    assert (scaled.examples, scaled.reduced, scaled.material, scaled.loads, scaled.fixed) == \
        (base.examples, same_forces, base.material, base.loads, base.fixed)
    with pytest.raises(LbshapeError, match="built-in scene"):
        scaling.scaled_scene("no-such-scene", 0.02, tmp_path)
    with pytest.raises(LbshapeError, match="sizes"):
        scaling.scaled_scene("bar-cylinder", -1.0, tmp_path)


def test_report_files_and_verdicts(tmp_path):
    points = [point(0.0665, 330, 3.0, 400.0, 0.12), point(0.0068, 103_000, 290.0, 9000.0, 0.15)]
    paths = scaling.write_scaling(points, tmp_path)
    assert [p.name for p in paths] == ["scaling.csv", "scaling.md", "scaling.png"]
    rows = list(csv.DictReader((tmp_path / "scaling.csv").open()))
    assert [int(r["n_vertices"]) for r in rows] == [330, 103_000]
    assert float(rows[1]["cubature_s"]) == pytest.approx(145.0)
    assert float(rows[1]["cubature_peak_mb"]) == pytest.approx(9000.0)
    lines = scaling.verdicts(points)
    assert "290 s (target <= 300 s: met)" in lines[0]
    assert "not met, missed by 10%" in lines[1]  # 9000 MB against 8192 MB
    assert "1.25 x" in lines[2] and "missed by 4%" in lines[2]  # 0.15 / 0.12 against 1.2
    text = (tmp_path / "scaling.md").read_text()
    assert "| 103000 |" in text and "not met" in text
    assert "no object with" in scaling.verdicts(points[:1])[0]
    assert len(lines) == 3  # no common-route timings: no fourth verdict


def test_common_route_verdict_and_columns(tmp_path):
    """The per-step time with the same target route at every size gets its own verdict."""
    points = [point(0.0665, 330, 3.0, 400.0, 0.12), point(0.0068, 103_000, 290.0, 900.0, 2.4)]
    points[0].t_total_common_ms = [1.00, 1.05, 0.95]
    points[1].t_total_common_ms = [1.10, 1.30, 1.00]
    lines = scaling.verdicts(points)
    assert "20 x" in lines[2] and "not met" in lines[2]  # the scene's own routes differ
    assert scaling.COMMON_ROUTE in lines[3] and "1.1 x" in lines[3] and ": met" in lines[3]
    scaling.write_scaling(points, tmp_path)
    rows = list(csv.DictReader((tmp_path / "scaling.csv").open()))
    assert [float(r["t_total_common_route_ms"]) for r in rows] == [1.0, 1.1]


def test_memory_verdict_under_mpi_counts_every_rank():
    """Under mpirun the memory target is the machine's: the per-stage sums over the ranks
    (here 2 × 3000 MB in one stage), not the largest process (4000 MB)."""
    small, big = point(0.0665, 330, 3.0, 400.0, 0.12), point(0.0068, 103_000, 250.0, 4000.0,
                                                              0.12, ranks=2)
    big.stage_peak_mb = {"mesh": 1000.0, "cubature": 9000.0}
    assert big.total_peak_mb == 9000.0 and small.total_peak_mb == 400.0
    line = scaling.verdicts([small, big])[1]
    assert "all 2 ranks" in line and "9e+03 MB" in line and "not met" in line
    big.stage_peak_mb = {"mesh": 1000.0, "cubature": 3000.0}
    assert big.total_peak_mb == 4000.0  # never below the largest process


@pytest.mark.parametrize("arguments, message", [
    (["--scaling", "--sweep"], "different benchmarks"),
    (["--sizes", "0.1"], "belong to --scaling"),
    (["--scaling", "--ranks", "0"], "--ranks"),
    (["--scaling", "bar-cuboid", "bar-cylinder"], "one built-in scene"),
])
def test_cli_rejects_bad_scaling_arguments(arguments, message, capsys):
    assert main(["bench", *arguments]) != 0
    assert message in capsys.readouterr().err


@pytest.mark.slow
def test_two_coarse_sizes_end_to_end(tmp_path):
    points = scaling.run_scaling([0.15, 0.1], scene="demo", steps=20, repeats=1)
    assert [p.n_vertices for p in points] == sorted(p.n_vertices for p in points)
    for p in points:
        assert p.wall_seconds > p.stages_seconds > 0 and p.peak_mb > 50
        assert set(p.stage_peak_mb) == set(p.stage_seconds) and len(p.t_total_ms) == 1
        assert len(p.t_total_common_ms) == 1 and p.t_total_common_ms[0] > 0


def test_fine_scene_is_bar_cylinder_with_a_finer_object():
    """bar-cylinder-fine: only the object's size differs from bar-cylinder (its precompute,
    ≥ 100k vertices, is measured by ``bench --scaling``, not here)."""
    fine, base = load_scene("bar-cylinder-fine"), load_scene("bar-cylinder")
    assert fine.object.shape == base.object.shape and fine.object.size == 0.0065
    assert (fine.examples, fine.reduced, fine.material, fine.loads, fine.fixed) == \
        (base.examples, base.reduced, base.material, base.loads, base.fixed)
    assert fine.precompute_key_fields() != base.precompute_key_fields()


def test_each_size_reports_its_basis_columns(tmp_path):
    """The step's cost follows r, which the appended responses make differ between sizes:
    the table, the CSV and the step verdicts name it."""
    points = [point(0.0665, 330, 3.0, 400.0, 0.12), point(0.0068, 103_000, 290.0, 900.0, 0.13)]
    points[0].r, points[1].r = 32, 37
    assert "(r = 37 / 32)" in scaling.verdicts(points)[2]
    scaling.write_scaling(points, tmp_path)
    assert [r["r"] for r in csv.DictReader((tmp_path / "scaling.csv").open())] == ["32", "37"]
    assert "| 103000 | 515000 | 37 | 1 |" in (tmp_path / "scaling.md").read_text()


def test_same_r_verdict_compares_the_small_bar_precomputed_with_the_large_r(tmp_path):
    """The step ratio at the same (m, r, s): the largest size against the smallest one
    precomputed again with the largest size's r, besides the ratio at each size's own r."""
    points = [point(0.0665, 330, 3.0, 400.0, 0.12), point(0.0068, 103_000, 290.0, 900.0, 0.15)]
    points[0].r, points[1].r, points[0].s, points[1].s = 32, 37, 60, 60
    assert not any("same (m, r, s)" in line for line in scaling.verdicts(points))
    points[0].same_r, points[0].same_r_s = 37, 60
    points[0].t_total_same_r_ms = [0.14, 0.13, 0.145]
    line = scaling.verdicts(points)[-1]
    assert "same (m, r, s)" in line and "(r = 37 / 37, s = 60 / 60" in line
    assert "1.07 x" in line and ": met" in line  # 0.15 / 0.14
    assert scaling.point_payload(points[0])["t_total_same_r_ms"] == [0.14, 0.13, 0.145]


@pytest.mark.slow
def test_scaled_scene_with_r_and_matched_precompute(tmp_path):
    """scaled_scene(r=...) sets [reduced] r; matched_r_precompute reaches a target r."""
    scene = load_scene(scaling.scaled_scene("demo", 0.15, tmp_path, r=7))
    assert scene.reduced.r == 7 and scene.name == "demo-h0.15-r7"
    # asked 4 gives 12 columns (appended responses): the target 15 needs asked r = 8
    loaded, pre = scaling.matched_r_precompute("demo", 0.15, 15, 4, tmp_path)
    assert pre.r == 15 and loaded.reduced.r == 8
    assert scaling.matched_r_precompute("demo", 0.15, 15, 4, tmp_path, tries=1) is None
