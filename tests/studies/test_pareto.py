"""The Pareto front of the speed-versus-error sweep and its report."""

from __future__ import annotations

import dataclasses
import json

import pytest

from lbshape.io.machine import machine_description
from lbshape.studies import pareto
from lbshape.studies.sweep import SweepPoint


def _point(m, r, s, ms, error, forces="cubature"):
    return SweepPoint(m=m, r=r, s_max=s, s=s, t_interp_ms=0.5 * ms, t_total_ms=ms,
                      t_total_min_ms=0.9 * ms, t_total_max_ms=1.1 * ms, error_vs_full=error,
                      cubature_holdout_error=0.03, forces=forces)


POINTS = (
    _point(10, 10, 30, 0.2, 0.20),   # fastest: on the front
    _point(10, 20, 30, 0.4, 0.05),   # front
    _point(10, 20, 60, 0.5, 0.08),   # dominated by (20, 30)
    _point(10, 30, 60, 0.8, 0.015),  # front, meets 2 % and 1 ms
    _point(10, 40, 120, 1.8, 0.005),  # front, too slow
    _point(6, 30, 60, 0.6, None),    # failed run: never on the front
    _point(14, 30, 60, 1.8, 0.006),  # dominated by (40, 120)
)


def test_the_targets_are_two_percent_at_one_millisecond():
    assert (pareto.TARGET_ERROR, pareto.TARGET_MS) == (0.02, 1.0)


def test_pareto_front_keeps_exactly_the_non_dominated_points():
    front = pareto.pareto_front(POINTS)
    assert [(p.r, p.s) for p in front] == [(10, 30), (20, 30), (30, 60), (40, 120)]
    # no point of the front is beaten in both time and error by any other point
    for p in front:
        assert not any(q.error_vs_full is not None and q.t_total_ms <= p.t_total_ms
                       and q.error_vs_full < p.error_vs_full for q in POINTS)


def test_target_verdicts_name_the_meeting_setting_or_the_closest_miss():
    good = pareto.meeting(POINTS)
    assert [(p.r, p.s) for p in good] == [(30, 60)]
    sweep = pareto.ParetoSweep("bar", (10, 30, 60), 500, 1e-3, 2, POINTS)
    assert "**met**" in pareto.verdict(sweep)
    assert "cubature m=10 r=30 s=60" in pareto.verdict(sweep)
    assert sweep.paper_point() is POINTS[3]

    slow = tuple(p for p in POINTS if p.r != 30)
    near = pareto.closest_miss(slow)
    # (20, 30): error 2.5x the target; (40, 120): time 1.8x the target -> the latter is closer
    assert (near.r, near.s) == (40, 120)
    text = pareto.verdict(pareto.ParetoSweep("bar", (10, 30, 60), 500, 1e-3, 2, slow))
    assert "NOT met" in text and "time 1.80× the 1 ms target" in text, text


POLY = (
    _point(10, 30, 60, 0.09, 0.018, "polynomial"),  # the scene's own (auto → polynomial)
    _point(10, 50, 60, 0.45, 0.012, "polynomial"),  # meets, most accurate under 1 ms
    _point(10, 30, 60, 0.15, 0.034),                # cubature at the same (m, r, s)
)


def test_the_scene_setting_is_found_with_its_force_model():
    sweep = pareto.ParetoSweep("bar", (10, 30, 60), 500, 1e-3, 2, POLY, "polynomial")
    assert sweep.paper_point() is POLY[0]
    assert pareto.ParetoSweep("bar", (10, 30, 60), 500, 1e-3, 2, POLY,
                              "cubature").paper_point() is POLY[2]
    text = pareto.verdict(sweep)
    assert text.startswith("**met** by 2 setting(s); fastest polynomial m=10 r=30: "), text
    assert "most accurate polynomial m=10 r=50: 0.450 ms/step, error 1.20%" in text


def test_write_pareto_writes_table_json_and_plot(tmp_path):
    sweep = pareto.ParetoSweep("bar", (10, 30, 60), 500, 1e-3, 2, POINTS + POLY[1:2],
                               "cubature")
    md, js, png = pareto.write_pareto([sweep], tmp_path)
    text = md.read_text()
    assert "| bar | (10, 30, 60), cubature | 0.800 ms, 1.50% | **met**" in text, text
    assert "Target: error ≤ 2% at ≤ 1 ms per step." in text
    # the polynomial forces' s is not a cubature size
    assert "| polynomial | 10 | 50 (50) | exact (60) | 0.450 " in text
    assert "| cubature | 10 | 30 (30) | 60 (60) | 0.800 " in text
    payload = json.loads(js.read_text())
    assert payload["target"] == {"error_vs_full": 0.02, "t_total_ms": 1.0}
    scene = payload["scenes"][0]
    assert scene["paper_forces"] == "cubature"
    assert {p["forces"] for p in scene["points"]} == {"cubature", "polynomial"}
    assert [p["r"] for p in scene["pareto"]] == [10, 20, 50, 40]
    assert png.stat().st_size > 10_000


def test_sweep_forces_follow_the_material():
    import dataclasses

    from lbshape.errors import LbshapeError
    from lbshape.scene import load_scene

    scene = load_scene("demo")
    assert pareto.sweep_forces(scene) == ("polynomial", "cubature")
    rubber = dataclasses.replace(scene, material=dataclasses.replace(
        scene.material, model="neohookean"))
    assert pareto.sweep_forces(rubber) == ("cubature",)
    with pytest.raises(LbshapeError, match="stvk"):
        pareto.sweep_forces(rubber, ("polynomial",))


@pytest.mark.slow
def test_sweep_runs_the_polynomials_once_per_r_and_the_cubature_per_r_and_s():
    from lbshape.scene import load_scene
    from lbshape.studies.sweep import speed_error_sweep

    scene = load_scene("demo")  # r = 20, s = 40
    points = speed_error_sweep(scene, r_values=(8,), s_values=(10, 20), steps=15, repeats=1,
                               forces=("polynomial", "cubature"), polynomial_r_values=(8, 12))
    got = sorted((p.forces, p.r, p.s_max) for p in points)
    # a point's r is its basis' size: the swept r and the example responses appended
    import dataclasses

    from lbshape.pipeline.precompute import precompute

    r8, r12 = (precompute(dataclasses.replace(
        scene, reduced=dataclasses.replace(scene.reduced, r=r))).r for r in (8, 12))
    assert r8 > 8 and r12 > 12
    assert got == [("cubature", r8, 10), ("cubature", r8, 20), ("polynomial", r8, 40),
                   ("polynomial", r12, 40)]
    assert all(p.error_vs_full is not None for p in points)


def test_the_scene_s_own_setting_is_found_by_the_r_it_asked_for():
    # the bar asks for r = 30 and its static responses grow the basis to 32
    grown = dataclasses.replace(_point(10, 32, 60, 0.2, 0.005, "polynomial"), r_asked=30)
    other = dataclasses.replace(_point(10, 30, 60, 0.1, 0.04, "polynomial"), r_asked=28)
    sweep = pareto.ParetoSweep("bar", (10, 30, 60), 500, 1e-3, 2, (other, grown), "polynomial")
    assert sweep.paper_point() is grown
    assert "| 32 (30) |" in pareto.pareto_markdown([sweep], machine_description())


def _free(ms, error, none, split, split_none):
    keys = ("com_path_error", "rotation_error_deg", "body_deformation_error")
    return dataclasses.replace(
        _point(10, 30, 60, ms, error, "polynomial"), error_no_examples=none,
        free_body=dict(zip(keys, split, strict=True)),
        free_body_no_examples=dict(zip(keys, split_none, strict=True)))


def test_a_free_body_is_judged_by_its_worst_error_against_five_percent():
    # whole field 3 % / 2 %, but the run without examples is 6 % off in the deformation
    deformed = _free(0.4, 0.03, 0.02, (0.01, 40.0, 0.02), (0.01, 1.0, 0.06))
    assert pareto.judged_error(deformed) == pytest.approx(0.06)  # not the 40° rotation
    good = _free(0.6, 0.03, 0.02, (0.04, 3.0, 0.02), (0.01, 1.0, None))  # never deforms
    assert pareto.judged_error(good) == pytest.approx(0.04)
    failed = dataclasses.replace(good, error_no_examples=None)
    assert pareto.judged_error(failed) is None
    assert pareto.judged_error(POINTS[1]) == POINTS[1].error_vs_full  # fixed object
    sweep = pareto.ParetoSweep("car", (6, 30, 60), 800, 1e-3, 3, (deformed, good, failed),
                               "polynomial")
    assert sweep.free and sweep.target_error == pareto.FREE_BODY_TARGET_ERROR == 0.05
    assert pareto.pareto_front(sweep.points) == [deformed, good]
    assert pareto.meeting(sweep.points, error=sweep.target_error) == [good]
    assert "**met** by 1 setting(s)" in pareto.verdict(sweep)
    missed = pareto.ParetoSweep("car", (10, 30, 60), 800, 1e-3, 3, (deformed,), "polynomial")
    text = pareto.verdict(missed)
    assert "NOT met" in text and "worst judged error 1.20× the 5% target" in text, text
    md = pareto.pareto_markdown([missed], machine_description())
    assert "| 3.00% | 2.00% | 1.00% / 40.0° / 2.00% | 1.00% / 1.0° / 6.00% | 6.00% |" in md, md
    assert "0.400 ms, 3.00%, worst judged 6.00%" in md
