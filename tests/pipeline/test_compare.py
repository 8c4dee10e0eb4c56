"""``lbshape simulate --compare full``: the full reference run once, its speed-up and error
in one line and in stats.json, the same error Table 2 uses; a stopped reference never
costs the run its result. Also what every run's stats say about its timing and forces."""

from __future__ import annotations

import dataclasses
import json
import re

import numpy as np
import pytest

import lbshape
import lbshape.pipeline.simulate as simulate_module
from lbshape.analysis.norms import trajectory_error
from lbshape.cli import main
from lbshape.elastic.element_kernels import mass_matrix

STEPS = 20
COMPARE_KEYS = ["error_vs_full", "final_error_vs_full", "full_t_total_ms", "speed_up",
                "compare_message"]


@pytest.fixture(scope="module")
def demo():
    scene = lbshape.load_scene("demo")
    return scene, lbshape.precompute(scene)


def _run(args, capsys) -> tuple[int, str, str]:
    code = main(args)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_compare_full_adds_the_keys_and_one_line(tmp_path, capsys, demo):
    out, full_out = tmp_path / "reduced", tmp_path / "full"
    code, stdout, _ = _run(["simulate", "demo", "--steps", str(STEPS), "--out", str(out),
                            "--no-influence", "--compare", "full"], capsys)
    assert code == 0
    lines = [line for line in stdout.splitlines() if "vs full" in line]
    assert len(lines) == 1, stdout
    assert re.search(r"x faster .* error \d+\.\d+% over the trajectory, \d+\.\d+% at the "
                     "final frame", lines[0]), lines[0]
    stats = json.loads((out / "stats.json").read_text())
    assert list(stats)[-len(COMPARE_KEYS):] == COMPARE_KEYS
    assert stats["compare_message"] is None and stats["stable"]
    assert stats["speed_up"] == pytest.approx(stats["full_t_total_ms"] / stats["t_total_ms"])
    # the same trajectory error as Table 2's, from the two runs' states.npz
    assert _run(["simulate", "demo", "--method", "full", "--steps", str(STEPS), "--out",
                 str(full_out), "--no-influence", "--json"], capsys)[0] == 0
    run, ref = (np.load(folder / "states.npz") for folder in (out, full_out))
    scene, pre = demo
    mass = mass_matrix(pre.mesh, pre.material.density)
    expected = trajectory_error(run["displacements"], ref["displacements"], mass,
                                times=run["times"], times_full=ref["times"])
    assert stats["error_vs_full"] == pytest.approx(expected, rel=1e-12)
    final = (np.sqrt(_m2(run["displacements"][-1] - ref["displacements"][-1], mass))
             / np.sqrt(_m2(ref["displacements"][-1], mass)))
    assert stats["final_error_vs_full"] == pytest.approx(final, rel=1e-12)
    # the API: the same keys from lbshape.compare and lbshape.simulate(compare="full")
    output = lbshape.simulate(scene, pre, steps=STEPS, compare="full")
    assert output.stats["error_vs_full"] == pytest.approx(expected, rel=1e-12)
    again = lbshape.compare(scene, pre, output)
    assert list(again) == COMPARE_KEYS
    assert again["error_vs_full"] == pytest.approx(expected, rel=1e-12)


def _m2(u, mass) -> float:
    flat = np.asarray(u).reshape(-1)
    return float(flat @ (mass @ flat))


def test_a_stopped_reference_leaves_the_result_intact(tmp_path, capsys, monkeypatch):
    real = simulate_module.full_simulation

    def stopped(scene, pre):
        engine = real(scene, pre)
        run = engine.run

        def run_and_stop(steps, **kwargs):
            record = run(3, **kwargs)
            return dataclasses.replace(record, stable=False,
                                       message="step 4: Newton did not converge")

        engine.run = run_and_stop
        return engine

    monkeypatch.setattr(simulate_module, "full_simulation", stopped)
    out = tmp_path / "run"
    code, stdout, _ = _run(["simulate", "demo", "--steps", str(STEPS), "--out", str(out),
                            "--no-influence", "--compare", "full"], capsys)
    assert code == 0
    assert "vs full: full reference unavailable: step 4: Newton did not converge" in stdout
    stats = json.loads((out / "stats.json").read_text())
    assert stats["stable"] and stats["steps"] == STEPS
    assert "Newton did not converge" in stats["compare_message"]
    assert stats["error_vs_full"] is None and stats["speed_up"] is None
    assert (out / "states.npz").exists() and (out / "trajectory.pvd").exists()


def test_compare_refuses_the_full_method_itself(capsys):
    code, _, err = _run(["simulate", "demo", "--method", "full", "--steps", "3",
                         "--compare", "full"], capsys)
    assert code == 2 and err.startswith("error: --compare full")


def test_short_runs_time_after_their_warm_up_and_say_which_forces_ran(demo):
    scene, pre = demo
    output = lbshape.simulate(scene, pre, steps=5)
    stats = output.stats
    assert stats["timed_steps"] == 3  # the first two steps (the warm-up) left out
    assert lbshape.simulate(scene, pre, steps=30).stats["timed_steps"] == 30 - 10
    if pre.elastic.force_model == "polynomial":
        assert stats["force_model"] == "polynomial"
        assert stats["force_elements"] == pre.mesh.n_tets
    else:
        assert stats["force_model"] == "cubature"
        assert stats["force_elements"] == pre.elastic.cubature_elements.size
    full = lbshape.simulate(scene, pre, method="full", steps=2).stats
    assert (full["force_model"], full["force_elements"]) == ("full", pre.mesh.n_tets)
    assert full["timed_steps"] == 1


def test_the_slow_steps_are_counted_against_dt():
    from lbshape.pipeline.simulate import step_time_spread

    # 1..100 ms: the 95th percentile interpolates between the 95th and 96th value
    spread = step_time_spread(np.arange(1.0, 101.0), dt=0.05)
    assert spread == {"t_p95_ms": pytest.approx(95.05), "t_max_ms": 100.0,
                      "steps_over_dt": 50}  # 51..100 ms are slower than 50 ms
    assert step_time_spread(np.array([1.0, 1.0]), dt=1e-3)["steps_over_dt"] == 0  # not above
    assert step_time_spread(np.zeros(0), dt=1e-3) == {"t_p95_ms": None, "t_max_ms": None,
                                                     "steps_over_dt": 0}


def test_a_run_reports_its_slowest_steps(demo):
    scene, pre = demo
    output = lbshape.simulate(scene, pre, steps=40, influence=False)
    stats = output.stats
    assert stats["t_max_ms"] >= stats["t_p95_ms"] >= output.step_median_ms > 0.0
    assert stats["t_max_ms"] >= stats["t_total_ms"]  # the largest is at least the mean
    assert 0 <= stats["steps_over_dt"] <= stats["timed_steps"] == 30


@pytest.mark.parametrize("method", ["reduced", "full"])
def test_the_progress_bar_counts_steps_not_states(demo, capsys, method):
    scene, pre = demo
    lbshape.simulate(scene, pre, method=method, steps=12, progress=True)
    bars = capsys.readouterr().err.replace("\r", "\n")
    counts = re.findall(r"(\d+)/12 ", bars)
    assert counts and counts[-1] == "12" and max(map(int, counts)) == 12, bars


@pytest.mark.slow
def test_a_free_body_compare_splits_the_error():
    """A free bar: the comparison adds the centre path / rotation / deformation split of
    lbshape.analysis.free_body, and the summary line names it."""
    from lbshape.analysis.free_body import KEYS, free_body_error
    from lbshape.cli.simulate import compare_line

    scene = lbshape.load_scene("bar-s-cuboid")
    pre = lbshape.precompute(scene)
    output = lbshape.simulate(scene, pre, steps=STEPS, compare="full")
    stats = output.stats
    assert list(stats)[-len(COMPARE_KEYS) - len(KEYS):] == COMPARE_KEYS + list(KEYS)
    full = lbshape.simulate(scene, pre, method="full", steps=STEPS)
    mass = mass_matrix(pre.mesh, pre.material.density)
    expected = free_body_error(output.displacements, full.displacements, pre.mesh.points,
                               mass).stats()
    for key, value in expected.items():
        assert stats[key] == pytest.approx(value, rel=1e-9), key
    assert "centre path" in compare_line(stats) and "rotation" in compare_line(stats)
