"""Table 2's settings comparison (the paper's m, r, s with cubature forces beside the scene
as written) and a free body's split error in the benchmark rows.

Nothing here is timed: the per-step times only have to exist (one per repeat). The
errors are checked against independent runs of the same (deterministic) simulations,
and the runs the benchmark makes are counted, so that each full reference (with and
without the examples) runs once and the example influence's runs are reused.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from lbshape.analysis.free_body import free_body_error
from lbshape.analysis.norms import trajectory_error
from lbshape.cli import main
from lbshape.elastic.element_kernels import mass_matrix
from lbshape.pipeline.precompute import precompute
from lbshape.pipeline.simulate import simulate
from lbshape.scene import load_scene
from lbshape.scene.variants import without_examples
from lbshape.studies.bench import (
    LBSHAPE_SOURCE,
    PAPER_SOURCE,
    ROW_EXTRA_KEYS,
    ROW_FREE_EVAL_KEYS,
    ROW_KEYS,
    SCENE_SOURCE,
    PaperSetting,
    bench_scene,
    paper_setting,
)
from lbshape.studies.realtime import PAPER_TABLE2
from lbshape.studies.tables import table2_markdown, table2_payload

STEPS = 15  # > the 10 warm-up steps
MACHINE = {"cpu": "test cpu", "cores": 1, "python": "3", "numpy": "2", "threads": {},
           "load": None}


@pytest.fixture(scope="module")
def demo():
    scene = load_scene("demo")
    return scene, precompute(scene)


@pytest.fixture
def runs(monkeypatch):
    """The simulations a benchmark makes: ``(method, m, force model, examples act)`` each."""
    import lbshape.pipeline.simulate as simulate_module
    import lbshape.studies.bench as bench_module

    original = simulate_module.simulate
    calls = []

    def counted(scene, pre, *, method="reduced", **kwargs):
        examples = scene.examples is not None and scene.examples.stiffness > 0
        calls.append((method, scene.reduced.m, pre.elastic.force_model, examples))
        return original(scene, pre, method=method, **kwargs)

    monkeypatch.setattr(simulate_module, "simulate", counted)
    monkeypatch.setattr(bench_module, "simulate", counted)
    return calls


def _error(run, full, mass):
    return trajectory_error(run.displacements, full.displacements, mass, times=run.times,
                            times_full=full.times)


def test_paper_setting_comes_from_the_papers_table_or_the_scene(demo):
    scene, _ = demo
    assert paper_setting(dataclasses.replace(scene, name="car"), PAPER_TABLE2) == \
        PaperSetting(6, 20, 23, PAPER_SOURCE, "cubature")
    own = scene.reduced
    assert paper_setting(scene, PAPER_TABLE2) == PaperSetting(own.m, own.r, own.s,
                                                              SCENE_SOURCE, "cubature")


def test_both_settings_errors_with_and_without_examples_from_one_bench(demo, runs, tmp_path):
    """The demo at its own m, r, s with cubature forces (the paper's setting of a scene
    the paper has no row for) beside its polynomial forces."""
    scene, pre = demo
    assert pre.elastic.force_model == "polynomial"
    repeats = 2
    paper = paper_setting(scene, PAPER_TABLE2)
    result = bench_scene(scene, steps=STEPS, repeats=repeats, pre=pre, paper=paper)
    # the runs: every timed job `repeats` times interleaved; each run without examples
    # once (the full one shared by both settings, the example influence's reused)
    timed = [("full", 10, "polynomial", True), ("euclidean", 10, "polynomial", True),
             ("reduced", 10, "polynomial", True), ("reduced", 10, "cubature", True)]
    assert runs[:len(timed) * repeats] == timed * repeats
    assert sorted(runs[len(timed) * repeats:]) == sorted([
        ("reduced", 10, "polynomial", False), ("full", 10, "polynomial", False),
        ("reduced", 10, "cubature", False)])

    paper_result, lbshape = result.settings
    assert (paper_result.label, paper_result.source) == ("paper", SCENE_SOURCE)
    assert (lbshape.label, lbshape.source) == ("lbshape", LBSHAPE_SOURCE)
    assert paper_result.forces == "cubature" and lbshape.forces == "polynomial"
    assert 0 < paper_result.s <= paper_result.s_max == scene.reduced.s  # cubature elements
    assert lbshape.s == pre.mesh.n_tets  # the polynomial forces sum over every element
    for setting in result.settings:
        assert setting.examples and setting.timing.stable
        assert len(setting.timing.t_total_ms) == repeats
        # r: the basis' size (the scene's r and the example responses appended)
        assert (setting.m, setting.r) == (scene.reduced.m, pre.r) and pre.r > scene.reduced.r
    # the lbshape setting is the reduced row
    reduced = result.row("reduced")
    assert lbshape.error_vs_full == reduced["error_vs_full"]
    assert lbshape.timing == next(t for t in result.timings if t.method == "reduced")

    # the errors equal independent runs'
    mass = mass_matrix(pre.mesh, pre.material.density)
    variant = dataclasses.replace(scene, reduced=dataclasses.replace(scene.reduced,
                                                                     forces="cubature"))
    variant_pre = precompute(variant)
    full = simulate(scene, pre, method="full", steps=STEPS)
    full_none = simulate(without_examples(scene), pre, method="full", steps=STEPS)
    for setting, (s, p) in ((paper_result, (variant, variant_pre)), (lbshape, (scene, pre))):
        with_ex = _error(simulate(s, p, steps=STEPS), full, mass)
        without = _error(simulate(without_examples(s), p, steps=STEPS), full_none, mass)
        np.testing.assert_allclose(setting.error_vs_full, with_ex, rtol=1e-9,
                                   err_msg=setting.label)
        np.testing.assert_allclose(setting.error_vs_full_no_examples, without, rtol=1e-9,
                                   err_msg=setting.label)
    assert paper_result.error_vs_full != lbshape.error_vs_full  # two different runs

    # Table 2: the section and the JSON entries
    payload = table2_payload([result], MACHINE)
    (entry,) = payload["paper_vs_lbshape"]
    assert entry["scene"] == "demo"
    assert [s["label"] for s in entry["settings"]] == ["paper", "lbshape"]
    for written, setting in zip(entry["settings"], result.settings, strict=True):
        assert written["error_vs_full"] == setting.error_vs_full
        assert written["error_vs_full_no_examples"] == setting.error_vs_full_no_examples
        assert written["t_total_ms"] == float(np.median(setting.timing.t_total_ms))
        assert written["t_total_ms_min"] <= written["t_total_ms"] <= written["t_total_ms_max"]
        assert written["forces"] == setting.forces and written["repeats"] == repeats
        assert written["meets_error"] == (setting.error_vs_full <= 0.05)
        assert written["rotation_error_deg"] is None  # a fixed object
    json.dumps(payload)  # serialisable
    md = table2_markdown([result], MACHINE)
    assert "## Paper settings vs lbshape settings" in md
    assert (f"| demo | paper ({SCENE_SOURCE}) | {paper_result.m} | {paper_result.r} "
            f"| {paper_result.s} | cubature |") in md
    assert (f"| {lbshape.error_vs_full:.2%} | {lbshape.error_vs_full_no_examples:.2%} |"
            in md)
    assert "## Free bodies" not in md


def test_a_paper_m_of_its_own_gets_its_own_full_reference(demo, runs):
    """The paper's m differs from the scene's: ``full`` with examples runs once more at
    that m (its example force depends on m); without examples it is still shared."""
    scene, pre = demo
    paper = PaperSetting(8, scene.reduced.r, scene.reduced.s, PAPER_SOURCE)
    result = bench_scene(scene, steps=STEPS, repeats=1, pre=pre, paper=paper,
                         methods=("full", "reduced"), influence=False)
    assert sorted(runs) == sorted([
        ("full", 10, "polynomial", True), ("reduced", 10, "polynomial", True),
        ("reduced", 8, "cubature", True),  # the timed jobs
        ("full", 10, "polynomial", False), ("reduced", 10, "polynomial", False),
        ("reduced", 8, "cubature", False),  # without examples
        ("full", 8, "cubature", True),  # the paper's m's reference
    ])
    paper_result = result.settings[0]
    assert paper_result.m == 8
    variant = dataclasses.replace(scene, reduced=dataclasses.replace(
        scene.reduced, m=8, forces="cubature"))
    variant_pre = precompute(variant)
    mass = mass_matrix(pre.mesh, pre.material.density)
    full = simulate(variant, variant_pre, method="full", steps=STEPS)
    np.testing.assert_allclose(
        paper_result.error_vs_full,
        _error(simulate(variant, variant_pre, steps=STEPS), full, mass), rtol=1e-9)


def test_a_scene_already_at_the_setting_and_without_examples_runs_nothing_twice(demo, runs):
    """k_ex = 0: the runs without examples are the runs; a paper setting equal to the
    scene's shares its runs."""
    scene, pre = demo
    plain = without_examples(scene)
    own = PaperSetting(plain.reduced.m, plain.reduced.r, plain.reduced.s, PAPER_SOURCE,
                       forces=pre.elastic.force_model)
    result = bench_scene(plain, steps=STEPS, repeats=2, pre=pre, paper=own,
                         methods=("full", "reduced"))
    assert sorted(runs) == sorted([("full", 10, "polynomial", False),
                                   ("reduced", 10, "polynomial", False)] * 2)
    paper_result, lbshape = result.settings
    assert paper_result.source == f"{PAPER_SOURCE} ({LBSHAPE_SOURCE})"
    assert dataclasses.replace(paper_result, label="lbshape", source=LBSHAPE_SOURCE) == lbshape
    assert not lbshape.examples
    assert lbshape.error_vs_full_no_examples == lbshape.error_vs_full > 0.0
    md = table2_markdown([result], MACHINE)
    assert "| same run (no examples) |" in md


@pytest.mark.slow
def test_free_body_rows_and_settings_split_the_error(runs):
    """A free bar (Figure 4): its rows and both settings carry the centre-of-mass path,
    rotation and body-frame deformation errors of independent runs."""
    scene = load_scene("bar-s-cuboid")
    pre = precompute(scene)
    steps = 20
    result = bench_scene(scene, steps=steps, repeats=1, pre=pre, methods=("full", "reduced"),
                         paper=paper_setting(scene, PAPER_TABLE2))
    mass = mass_matrix(pre.mesh, pre.material.density)
    full = simulate(scene, pre, method="full", steps=steps)
    reduced = simulate(scene, pre, steps=steps)
    expected = free_body_error(reduced.displacements, full.displacements, pre.mesh.points,
                               mass).stats()
    row = result.row("reduced")
    assert tuple(row) == ROW_KEYS + ROW_EXTRA_KEYS + ROW_FREE_EVAL_KEYS
    for key, value in expected.items():
        np.testing.assert_allclose(row[key], value, rtol=1e-9, err_msg=key)
    assert row["rotation_error_deg"] > 0.0 and row["body_deformation_error"] > 0.0
    assert result.row("full")["body_deformation_error"] == 0.0
    paper_result, lbshape = result.settings
    assert lbshape.free_body == {key: row[key] for key in ROW_EXTRA_KEYS}
    full_none = simulate(without_examples(scene), pre, method="full", steps=steps)
    none = simulate(without_examples(scene), pre, steps=steps)
    expected_none = free_body_error(none.displacements, full_none.displacements,
                                    pre.mesh.points, mass).stats()
    for key, value in expected_none.items():
        np.testing.assert_allclose(lbshape.free_body_no_examples[key], value, rtol=1e-9,
                                   atol=1e-12, err_msg=key)
    assert paper_result.forces == "cubature" and paper_result.free_body is not None
    assert ("full", 10, "polynomial", False) in runs
    assert sum(run[0] == "full" for run in runs) == 2  # with and without examples, once each

    md = table2_markdown([result], MACHINE)
    assert "## Free bodies: rigid motion and deformation apart" in md
    assert (f"| bar-s-cuboid | reduced | {row['error_vs_full']:.2%} "
            f"| {row['com_path_error']:.2%} | {row['rotation_error_deg']:.2f} "
            f"| {row['body_deformation_error']:.2%} |") in md
    entry = table2_payload([result], MACHINE)["paper_vs_lbshape"][0]["settings"][1]
    assert entry["body_deformation_error_no_examples"] == \
        lbshape.free_body_no_examples["body_deformation_error"]


def test_bench_command_runs_the_paper_setting_unless_told_not_to(tmp_path, capsys):
    code = main(["bench", "demo", "--json", "--steps", str(STEPS), "--repeats", "1",
                 "--out-dir", str(tmp_path / "on")])
    assert code == 0
    printed = json.loads(capsys.readouterr().out)
    assert [s["label"] for s in printed["paper_vs_lbshape"][0]["settings"]] == \
        ["paper", "lbshape"]
    written = json.loads((tmp_path / "on" / "table2.json").read_text())
    assert written["paper_vs_lbshape"] == printed["paper_vs_lbshape"]
    code = main(["bench", "demo", "--json", "--no-paper-settings", "--steps", str(STEPS),
                 "--repeats", "1", "--out-dir", str(tmp_path / "off")])
    assert code == 0
    assert "paper_vs_lbshape" not in json.loads(capsys.readouterr().out)
    written = json.loads((tmp_path / "off" / "table2.json").read_text())
    assert written["paper_vs_lbshape"] == []
    assert "## Paper settings" not in (tmp_path / "off" / "table2.md").read_text()
    assert main(["bench", "demo", "--sweep", "--no-paper-settings"]) != 0
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and "--no-paper-settings" in err, err
