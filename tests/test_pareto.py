"""The Pareto front of the speed-versus-error sweep and its report."""

from __future__ import annotations

import json

from lbshape.report import pareto
from lbshape.report.bench import SweepPoint


def _point(m, r, s, ms, error):
    return SweepPoint(m=m, r=r, s_max=s, s=s, t_interp_ms=0.5 * ms, t_total_ms=ms,
                      t_total_min_ms=0.9 * ms, t_total_max_ms=1.1 * ms, error_vs_full=error,
                      cubature_holdout_error=0.03)


POINTS = (
    _point(10, 10, 30, 1.0, 0.20),   # fastest: on the front
    _point(10, 20, 30, 2.0, 0.05),   # front
    _point(10, 20, 60, 2.5, 0.08),   # dominated by (20, 30)
    _point(10, 30, 60, 4.0, 0.015),  # front, meets 2 % and 5 ms
    _point(10, 40, 120, 9.0, 0.005),  # front, too slow
    _point(6, 30, 60, 3.0, None),    # failed run: never on the front
    _point(14, 30, 60, 9.0, 0.006),  # dominated by (40, 120)
)


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
    assert "**met**" in pareto.verdict(sweep) and "r=30 s=60" in pareto.verdict(sweep)
    assert sweep.paper_point() is POINTS[3]

    slow = tuple(p for p in POINTS if p.r != 30)
    near = pareto.closest_miss(slow)
    # (20, 30): error 2.5x the target; (40, 120): time 1.8x the target -> the latter is closer
    assert (near.r, near.s) == (40, 120)
    text = pareto.verdict(pareto.ParetoSweep("bar", (10, 30, 60), 500, 1e-3, 2, slow))
    assert "NOT met" in text and "time 1.80×" in text, text


def test_write_pareto_writes_table_json_and_plot(tmp_path):
    sweep = pareto.ParetoSweep("bar", (10, 30, 60), 500, 1e-3, 2, POINTS)
    md, js, png = pareto.write_pareto([sweep], tmp_path)
    text = md.read_text()
    assert "| bar | (10, 30, 60) | 4.00 ms, 1.50% | **met**" in text, text
    payload = json.loads(js.read_text())
    assert [p["r"] for p in payload["scenes"][0]["pareto"]] == [10, 20, 30, 40]
    assert png.stat().st_size > 10_000
