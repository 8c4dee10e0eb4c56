"""A secondary run never fails the primary result, and the exit codes are one rule:
0 done, 2 bad input, 3 a solver failure — for every command.

The objects are the demo's coarse bar (90 vertices) made of a Neo-Hookean material: the
runs that must stop are crushed by 1e6 N on the free end (elements invert within a few
steps), those that must not carry a few newtons.
"""

from __future__ import annotations

import dataclasses
import json
import textwrap
from types import SimpleNamespace

import numpy as np
import pytest

import lbshape.pipeline.simulate as simulate_module
from lbshape.cli import main
from lbshape.errors import SolverError
from lbshape.pipeline.influence import STATS_KEYS
from lbshape.pipeline.precompute import precompute
from lbshape.scene import load_scene
from lbshape.scene.variants import without_examples
from lbshape.studies import bench, tables

BAR = """
[object]
shape = "demo-bar"

[material]
model = "neohookean"
young = 1.0e6

[reduced]
m = 6
r = 12
s = 20

[fixed]
region = "z > 0.999"

[[loads]]
type = "region_force"
vector = [{side}, 0.0, {push}]
region = "z < 0.001"
profile = "ramp"
start = 0.0
duration = 0.5

[simulation]
dt = 0.001
steps = 60
"""

EXAMPLES = """
[examples]
stiffness = 2000.0

[[examples.pose]]
shape = "demo-bar"
pose = "twist"
parameters = { angle = 0.8, axis = "z", anchor = "max" }
"""


def _scene_file(folder, name: str, *, push: float, examples: bool = False):
    path = folder / f"{name}.toml"
    text = textwrap.dedent(BAR).format(side=0.02 * push, push=push)
    path.write_text(text + (textwrap.dedent(EXAMPLES) if examples else ""))
    return path


def _crushed(scene):
    """The scene without examples, crushed: its run stops (an inverted element)."""
    plain = without_examples(scene)
    loads = tuple(dataclasses.replace(load, vector=(2e4, 0.0, 1e6)) for load in plain.loads)
    return dataclasses.replace(plain, loads=loads)


@pytest.mark.slow
def test_a_stopped_influence_run_leaves_the_result_and_the_reason(tmp_path, monkeypatch,
                                                                  capsys):
    """``simulate`` with examples: the run without them stops; the run with them is
    written, the influence keys are null with the reason, and the command exits 0."""
    path = _scene_file(tmp_path, "held", push=10.0, examples=True)
    monkeypatch.setattr(simulate_module, "without_examples", _crushed)
    out = tmp_path / "run"
    assert main(["simulate", str(path), "--out", str(out), "--json"]) == 0
    stats = json.loads((out / "stats.json").read_text())
    assert stats["stable"] and stats["steps"] == 60
    assert (out / "states.npz").exists() and not (out / "FAILED.txt").exists()
    assert all(stats[key] is None for key in STATS_KEYS)
    assert stats["influence_message"].startswith(
        "the reduced run without examples stopped: an element inverted at step ")
    printed = json.loads(capsys.readouterr().out)
    assert printed["influence_message"] == stats["influence_message"]

    # the benchmark's influence: unavailable with the reason, the runs themselves kept
    scene = load_scene(path)
    monkeypatch.setattr(bench, "example_influence", _failing_influence)
    run = simulate_module.SimulationOutput({"stable": True}, np.zeros(1), np.zeros((1, 1, 3)))
    effects, references = bench._influence(scene, precompute(scene), {"reduced": run},
                                           steps=60)
    assert references == {}
    (method, row), = effects
    assert method == "reduced" and all(row[key] is None for key in STATS_KEYS)
    assert row["influence_message"] == "the reduced run without examples stopped: at step 7"
    table = tables._influence_rows(SimpleNamespace(scene="held", influence=effects))
    assert table == ["| held | reduced | unavailable: the reduced run without examples stopped: "
                     "at step 7 | — | — | — | — | — |"]


def _failing_influence(*args, **kwargs):
    raise SolverError("the reduced run without examples stopped: at step 7")


def test_exit_codes_bad_input_2_solver_failure_3(tmp_path, capsys, monkeypatch):
    assert main(["simulate", str(tmp_path / "no-such-scene.toml")]) == 2
    assert capsys.readouterr().err.startswith("error: ")

    crushed = _scene_file(tmp_path, "crushed", push=1e6)
    out = tmp_path / "run"
    assert main(["simulate", str(crushed), "--out", str(out), "--no-influence"]) == 3
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("error: simulation stopped: an element inverted at step ")
    assert "is far beyond what the object carries" in err and "lower dt" not in err
    assert (out / "FAILED.txt").exists()

    # tune: its full reference stops -> a solver failure, not bad input
    assert main(["tune", str(crushed), "--error", "0.1", "--m", "6", "--r", "12",
                 "--s", "20", "--out", str(tmp_path / "tune")]) == 3
    assert "the full reference run of crushed stopped" in capsys.readouterr().err

    # a numerical failure below lbshape's own checks: exit 3, one line, no traceback
    def singular(_):
        raise np.linalg.LinAlgError("Singular matrix")

    monkeypatch.setattr("lbshape.cli.simulate.load_scene", singular)
    assert main(["simulate", str(crushed)]) == 3
    assert capsys.readouterr().err == "error: solver failed: LinAlgError: Singular matrix\n"
