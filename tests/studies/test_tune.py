"""``lbshape tune``: the cheapest (m, r, s, forces) within an error of ``full`` and a
per-step time budget, on the demo scene."""

from __future__ import annotations

import dataclasses
import tomllib

import numpy as np
import pytest

from lbshape.cli import main
from lbshape.errors import LbshapeError
from lbshape.io.toml_writer import dumps

STEPS = 15  # > the 10 warm-up steps
GRID = {"m_values": (6,), "r_values": (8, 12), "s_values": (10, 20)}


def test_toml_writer_round_trips_scene_documents():
    data = {"name": "x", "a b": {"c": [1, 2.5, "q\"\n"], "d": {"e": True}},
            "examples": {"stiffness": 2.0, "pose": [{"shape": "s", "parameters": {"k": 1}}]},
            "inf": float("inf")}
    assert tomllib.loads(dumps(data)) == data
    with pytest.raises(TypeError, match="x.when"):
        dumps({"x": {"when": object()}})


# ------------------------------------------------------------- the grid (no runs)
def test_polynomial_candidates_are_not_multiplied_by_s():
    from lbshape.scene import load_scene
    from lbshape.studies.tune import candidate_grid

    scene = load_scene("demo")  # StVK, r = 20, s = 40
    grid = candidate_grid(scene, m_values=(6,), r_values=(8, 12), s_values=(10, 20, 40))
    polynomial = sorted(c for c in grid if c.forces == "polynomial")
    cubature = sorted(c for c in grid if c.forces == "cubature")
    assert polynomial == [(6, 8, 40, "polynomial"), (6, 12, 40, "polynomial")]  # scene's s
    assert len(cubature) == 6 and {c.s for c in cubature} == {10, 20, 40}
    assert len(grid) == len(set(grid)) == 8
    # only the cubature for another material; the polynomials refused for it
    rubber = dataclasses.replace(scene, material=dataclasses.replace(
        scene.material, model="neohookean"))
    assert {c.forces for c in candidate_grid(rubber, **GRID)} == {"cubature"}
    with pytest.raises(LbshapeError, match="stvk"):
        candidate_grid(rubber, forces=("polynomial",), **GRID)
    with pytest.raises(LbshapeError, match="force models"):
        candidate_grid(scene, forces=("auto",), **GRID)


def test_default_r_candidates_reach_above_the_scene_r_within_the_mesh():
    from lbshape.scene import load_scene
    from lbshape.studies.tune import candidate_grid

    scene = load_scene("demo")  # r = 20
    rs = sorted({c.r for c in candidate_grid(scene, m_values=(6,), s_values=(10,))})
    assert rs == [7, 10, 13, 20, 27, 33]
    capped = sorted({c.r for c in candidate_grid(scene, m_values=(6,), s_values=(10,),
                                                 max_r=25)})
    assert capped == [7, 10, 13, 20, 25]


def test_polynomial_candidates_clearly_over_the_budget_are_screened_out():
    from lbshape.studies.tune import Candidate, screen

    small, large = Candidate(10, 20, 40, "polynomial"), Candidate(10, 90, 40, "polynomial")
    assert screen(small, budget_ms=1.0, n_tets=1000) == ""
    assert "force product alone" in screen(large, budget_ms=1.0, n_tets=1000)
    assert screen(large, budget_ms=100.0, n_tets=100) == ""
    assert "what forces = 'auto' builds" in screen(small, budget_ms=1.0, n_tets=10**8)
    assert screen(Candidate(10, 90, 400, "cubature"), budget_ms=1e-9, n_tets=10**8) == ""


# ------------------------------------------------------ the selection (fake timings)
def _fake(table):
    """A measurement from a table ``{candidate: (ms, error)}``, recording its calls."""
    from lbshape.studies.tune import Trial

    calls = []

    def measure(c):
        calls.append(c)
        ms, error = table[c]
        return Trial(c.m, c.r, c.s, s=c.s, t_interp_ms=0.1 * ms, t_total_ms=ms,
                     error_vs_full=error, forces=c.forces)

    return measure, calls


def _c(m, r, s, forces="cubature"):
    from lbshape.studies.tune import Candidate

    return Candidate(m, r, s, forces)


def test_winner_is_the_fastest_candidate_meeting_the_error_within_the_budget():
    from lbshape.studies.tune import search

    table = {
        _c(6, 8, 10): (0.05, 0.30),                  # fastest, too inaccurate
        _c(6, 8, 40, "polynomial"): (0.08, 0.04),    # meets both: the winner
        _c(6, 12, 10): (0.20, 0.045),                # meets both, slower
        _c(6, 12, 40, "polynomial"): (0.30, 0.01),   # dominated by (6, 8) polynomial
        _c(6, 16, 10): (2.50, 0.001),                # dominated by (6, 12, 10)
        _c(6, 16, 40, "polynomial"): (1.50, 0.002),  # dominated as well
    }
    measure, calls = _fake(table)
    trials, best = search(list(table), measure, error=0.05, budget_ms=1.0)
    assert (best.m, best.r, best.forces) == (6, 8, "polynomial")
    assert best.t_total_ms <= 1.0 and best.error_vs_full <= 0.05
    skipped = [t.candidate for t in trials if t.note.startswith("skipped")]
    assert skipped == [_c(6, 12, 40, "polynomial"), _c(6, 16, 10), _c(6, 16, 40, "polynomial")]
    assert calls == [_c(6, 8, 10), _c(6, 8, 40, "polynomial"), _c(6, 12, 10)]
    # the fastest accurate candidate over the budget loses to a slower one under it
    table = {_c(6, 8, 10): (1.4, 0.01), _c(6, 12, 40, "polynomial"): (0.9, 0.04)}
    measure, _ = _fake(table)
    _, best = search(list(table), measure, error=0.05, budget_ms=1.0)
    assert best.candidate == _c(6, 12, 40, "polynomial")
    # a skip reason given a priori is kept in the table and the candidate never runs
    measure, calls = _fake(table)
    trials, best = search(list(table), measure, error=0.05, budget_ms=1.0,
                          skip=lambda c: "skipped: test" if c.forces == "polynomial" else "")
    assert best is None and calls == [_c(6, 8, 10)] and trials[1].note == "skipped: test"


def test_no_candidate_within_the_budget_is_said_plainly():
    from lbshape.studies.tune import TuneResult, search, tune_markdown, verdict_line

    table = {_c(6, 8, 10): (0.5, 0.30), _c(6, 12, 10): (1.2, 0.04),
             _c(6, 12, 40, "polynomial"): (3.0, 0.01)}
    measure, _ = _fake(table)
    trials, best = search(list(table), measure, error=0.05, budget_ms=1.0)
    assert best is None
    result = TuneResult("demo", 0.05, STEPS, 1, 3.0, trials, best, budget_ms=1.0)
    line = verdict_line(result)
    assert line.startswith("no candidate meets error ≤ 5% within 1 ms per step; closest: "
                           "m=6, r=12, s=10, cubature: 1.200 ms per step"), line
    assert "time 1.20× the budget" in line and "\n" not in line
    text = tune_markdown(result)
    assert line[1:] in text and text.count("\n| cubature |") == 2
    assert text.count("\n| polynomial |") == 1


# ------------------------------------------------------------------- real runs
@pytest.mark.slow
def test_tune_picks_the_cheapest_candidate_within_the_error():
    from lbshape.analysis.norms import trajectory_error
    from lbshape.elastic.element_kernels import mass_matrix
    from lbshape.pipeline.precompute import precompute
    from lbshape.pipeline.simulate import simulate
    from lbshape.scene import load_scene
    from lbshape.scene.variants import with_reduced
    from lbshape.studies.tune import tune_scene

    scene = load_scene("demo")
    result = tune_scene(scene, error=10.0, budget_ms=1e3, steps=STEPS, repeats=1, **GRID)
    tried = sorted(t.candidate for t in result.trials)
    assert tried == [(6, 8, 10, "cubature"), (6, 8, 20, "cubature"), (6, 8, 40, "polynomial"),
                     (6, 12, 10, "cubature"), (6, 12, 20, "cubature"),
                     (6, 12, 40, "polynomial")]
    ran = [t for t in result.trials if not t.note]
    assert ran and all(t.meets(10.0) for t in ran)
    assert result.best.t_total_ms == min(t.t_total_ms for t in ran)
    # a candidate larger in m, r (and s) than one of its model that met E is never run
    assert len(ran) == 2 and {t.forces for t in ran} == {"cubature", "polynomial"}
    assert all(t.s == 187 for t in ran if t.forces == "polynomial")  # every element
    # the reported error is the trajectory error of independent runs (deterministic)
    best = result.best
    variant = with_reduced(scene, *best.candidate)
    pre, base = precompute(variant), precompute(scene)
    assert pre.elastic.force_model == best.forces
    full = simulate(scene, base, method="full", steps=STEPS)
    run = simulate(variant, pre, method="reduced", steps=STEPS)
    expected = trajectory_error(run.displacements, full.displacements,
                                mass_matrix(pre.mesh, pre.material.density),
                                times=run.times, times_full=full.times)
    np.testing.assert_allclose(best.error_vs_full, expected, rtol=1e-9)
    with pytest.raises(LbshapeError, match="error target"):
        tune_scene(scene, error=0.0, steps=STEPS, **GRID)
    with pytest.raises(LbshapeError, match="budget"):
        tune_scene(scene, error=0.1, budget_ms=0.0, steps=STEPS, **GRID)


def test_tune_command_writes_a_loadable_scene_beside_its_table(tmp_path, capsys):
    from lbshape.pipeline.precompute_key import scene_cache_key
    from lbshape.scene import load_scene
    from lbshape.scene.variants import with_reduced

    code = main(["tune", "demo", "--error", "0.9", "--budget-ms", "1000", "--m", "6",
                 "--r", "8,12", "--s", "10,20", "--forces", "cubature",
                 "--steps", str(STEPS), "--repeats", "1", "--out", str(tmp_path)])
    assert code == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo-tune.md", "demo-tuned.toml"]
    table = (tmp_path / "demo-tune.md").read_text()
    assert table.count("\n| cubature | 6 |") == 4 and "**chosen**" in table
    assert "polynomial" not in table.split("| note |")[1]
    tuned = load_scene(tmp_path / "demo-tuned.toml")
    red = tuned.reduced
    chosen = (red.m, red.r, red.s, red.forces)
    assert red.forces == "cubature"
    assert f"m={red.m}, r={red.r}, s={red.s}, cubature" in capsys.readouterr().out
    # everything but m, r, s, forces is the original scene: same cache entry as the variant
    original = load_scene("demo")
    assert tuned.name == original.name and tuned.loads == original.loads
    assert scene_cache_key(tuned) == scene_cache_key(with_reduced(original, *chosen))


def test_tune_command_fails_in_one_line_when_nothing_meets_the_targets(tmp_path, capsys):
    # no step takes a nanosecond: nothing is within the budget
    code = main(["tune", "demo", "--error", "0.9", "--budget-ms", "1e-6", "--m", "6",
                 "--r", "8", "--s", "10", "--forces", "cubature", "--steps", str(STEPS),
                 "--repeats", "1", "--out", str(tmp_path)])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("error: no candidate meets error ≤ 90% within 1e-06 ms per step; "
                          "closest: m=6, r=8, s=10, cubature:"), err
    assert "× the budget" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo-tune.md"]  # no scene file
    table = (tmp_path / "demo-tune.md").read_text()
    assert "**No candidate meets error ≤ 90% within 1e-06 ms per step; closest:" in table
    assert table.count("\n| cubature | 6 | 8 | 10 |") == 1


@pytest.mark.parametrize("budget", ["0", "-1", "nan", "inf"])
def test_budget_flag_is_validated_in_one_line(budget, capsys):
    code = main(["tune", "demo", "--error", "0.1", f"--budget-ms={budget}"])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: --budget-ms must be a number of ms > 0")


def test_list_flags_are_validated(capsys):
    assert main(["tune", "demo", "--error", "0.1", "--r", "8,x"]) != 0
    assert "comma-separated integers" in capsys.readouterr().err
    assert main(["tune", "demo", "--error", "0.1", "--forces", "exact"]) != 0
    assert "force models must be among" in capsys.readouterr().err
