"""``lbshape tune``: the cheapest (m, r, s) within an error of ``full``, on the demo scene."""

from __future__ import annotations

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


def test_tune_picks_the_cheapest_candidate_within_the_error():
    from lbshape.elastic.element_kernels import mass_matrix
    from lbshape.pipeline.precompute import precompute
    from lbshape.pipeline.simulate import simulate
    from lbshape.report.bench import trajectory_error
    from lbshape.report.tune import _variant, tune_scene
    from lbshape.scene import load_scene

    scene = load_scene("demo")
    result = tune_scene(scene, error=10.0, steps=STEPS, repeats=1, **GRID)
    tried = [(t.m, t.r, t.s_max) for t in result.trials]
    assert sorted(tried) == [(6, 8, 10), (6, 8, 20), (6, 12, 10), (6, 12, 20)]
    ran = [t for t in result.trials if not t.note]
    assert ran and all(t.meets(10.0) for t in ran)
    assert result.best.t_total_ms == min(t.t_total_ms for t in ran)
    # a candidate larger in m, r and s than one that met E is skipped, never run
    assert [t.note.startswith("skipped") for t in result.trials] == [False, True, True, True]
    # the reported error is the trajectory error of independent runs (deterministic)
    best = result.best
    variant = _variant(scene, best.m, best.r, best.s_max)
    pre, base = precompute(variant), precompute(scene)
    full = simulate(scene, base, method="full", steps=STEPS)
    run = simulate(variant, pre, method="reduced", steps=STEPS)
    expected = trajectory_error(run.displacements, full.displacements,
                                mass_matrix(pre.mesh, pre.material.density),
                                times=run.times, times_full=full.times)
    np.testing.assert_allclose(best.error_vs_full, expected, rtol=1e-9)
    with pytest.raises(LbshapeError, match="error target"):
        tune_scene(scene, error=0.0, steps=STEPS, **GRID)


def test_tune_command_writes_a_loadable_scene_beside_its_table(tmp_path, capsys):
    from lbshape.pipeline.precompute import scene_cache_key
    from lbshape.report.tune import _variant
    from lbshape.scene import load_scene

    code = main(["tune", "demo", "--error", "0.9", "--m", "6", "--r", "8,12", "--s", "10,20",
                 "--steps", str(STEPS), "--repeats", "1", "--out", str(tmp_path)])
    assert code == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo-tune.md", "demo-tuned.toml"]
    table = (tmp_path / "demo-tune.md").read_text()
    assert table.count("\n| 6 |") == 4 and "**chosen**" in table
    tuned = load_scene(tmp_path / "demo-tuned.toml")
    chosen = (tuned.reduced.m, tuned.reduced.r, tuned.reduced.s)
    assert f"m={chosen[0]}, r={chosen[1]}, s={chosen[2]}" in capsys.readouterr().out
    # everything but m, r, s is the original scene: same cache entry as the variant
    original = load_scene("demo")
    assert tuned.name == original.name and tuned.loads == original.loads
    assert scene_cache_key(tuned) == scene_cache_key(_variant(original, *chosen))


def test_tune_command_fails_in_one_line_when_nothing_meets_the_error(tmp_path, capsys):
    code = main(["tune", "demo", "--error", "1e-9", "--m", "6", "--r", "8", "--s", "10",
                 "--steps", str(STEPS), "--repeats", "1", "--out", str(tmp_path)])
    assert code != 0
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("error: no (m, r, s) tried") and "the best error was" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["demo-tune.md"]  # no scene file
    assert main(["tune", "demo", "--error", "0.1", "--r", "8,x"]) != 0
    assert "comma-separated integers" in capsys.readouterr().err
