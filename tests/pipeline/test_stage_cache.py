"""The precompute's cache per stage: each stage's entry is keyed on what it reads.

A renamed scene of identical content reuses everything; a new load re-runs only the
stages that read the loads (and those after them), never the modes, the LB spectrum or
the examples' coefficients; dt, steps and a load's profile re-run nothing; a new mesh
re-runs everything; and what the cache gives equals a fresh precompute bit for bit.
"""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest

import lbshape
from lbshape.geometry.primitives import structured_box
from lbshape.io.cache import STAGE_MAGIC, load_stage, save_stage, stage_path
from lbshape.pipeline import precompute as stages
from lbshape.pipeline.precompute import precompute, stage_names
from lbshape.pipeline.precompute_key import ARTIFACT_NAME, stage_keys

BEND = {"pose": "arc", "parameters": {"angle": 0.8, "axis": "x", "direction": "z",
                                      "anchor": "min"}}
#: the stages that never read the loads, dt or steps
LOAD_FREE = {"mesh", "modes", "lb", "examples", "target-table", "lb-cubature"}


def _bar(cells=(8, 2, 2), *, load=(0.0, 0.0, -2.0), stiffness="auto", **options):
    """A small clamped bar with one example, a tip load, auto example stiffness."""
    box = structured_box((0.4, 0.05, 0.05), cells)
    settings = dict(name="bar", fixed="x < 1e-6", material={"young": 1e5, "density": 1000.0},
                    reduced={"m": 6, "r": 10, "s": 20},
                    examples=[BEND], example_stiffness=stiffness,
                    loads=[{"type": "region_force", "vector": list(load),
                            "region": "x > 0.399", "profile": "ramp", "duration": 0.1}],
                    dt=0.002, steps=20)
    return lbshape.Scene.from_mesh(box, **{**settings, **options})


def _keys(scene, names) -> dict[str, str]:
    return stage_keys(scene, names, [
        stages.CLAMPED_TARGETS, stages.MAX_APPENDED_BASIS, stages.MAX_APPENDED_FREE_BODY,
        stages.MIN_APPENDED_FREE_BODY, stages.STATIC_EQUILIBRIA_MAX_VERTICES])


def _recomputed(pre) -> set[str]:
    return set(pre.stages.seconds) - set(pre.stages.cached)


def _artifact(folder) -> dict:
    [path] = folder.glob(f"{ARTIFACT_NAME}-*.npz")
    with np.load(path) as data:
        return {name: data[name] for name in data.files if name != "__meta__"}


def _assert_same_artifact(folder, fresh_folder):
    cached, fresh = _artifact(folder), _artifact(fresh_folder)
    assert sorted(cached) == sorted(fresh)
    for name in [name for name in fresh if name.endswith("table_check")]:
        cached[name], fresh[name] = cached[name][:-1], fresh[name][:-1]  # last: wall time
    for name in fresh:
        assert np.array_equal(cached[name], fresh[name]), name  # bit for bit


def test_stage_keys_follow_what_each_stage_reads():
    scene = _bar()
    names = stage_names(scene)
    assert {"derivatives", "static-equilibria", "example-stiffness"} <= set(names)
    keys = _keys(scene, names)
    assert set(keys) == set(names)
    renamed = dataclasses.replace(scene, name="another-name")
    assert _keys(renamed, names) == keys
    runtime = _bar(dt=0.01, steps=500, damping={"alpha": 2.0, "beta": 0.0})
    assert _keys(runtime, names) == keys
    loaded = _keys(_bar(load=(0.0, 0.0, -5.0)), names)
    changed = {name for name in names if loaded[name] != keys[name]}
    assert changed == set(names) - LOAD_FREE
    remeshed = _keys(_bar(cells=(10, 2, 2)), names)
    assert not {name for name in names if remeshed[name] == keys[name]}
    more_modes = _bar(reduced={"m": 7, "r": 10, "s": 20})  # m: the LB stages and after
    assert _keys(more_modes, names)["modes"] == keys["modes"]
    assert _keys(more_modes, names)["lb"] != keys["lb"]


def test_a_stage_entry_that_is_foreign_or_stale_is_recomputed(tmp_path):
    key = "ab" * 32
    assert load_stage("modes", key, root=tmp_path) == (False, None)  # absent
    path = save_stage("modes", key, {"omega2": np.arange(3.0)}, root=tmp_path)
    hit, value = load_stage("modes", key, root=tmp_path)
    assert hit and np.array_equal(value["omega2"], np.arange(3.0))
    assert load_stage("modes", "ab" * 31 + "cd", root=tmp_path)[0] is False  # same file name
    path.write_bytes(path.read_bytes()[:40])  # truncated
    assert load_stage("modes", key, root=tmp_path) == (False, None)
    path.write_bytes(b"PK\x03\x04 a zip, not an entry")
    assert load_stage("modes", key, root=tmp_path) == (False, None)

    class Evil:
        def __reduce__(self):
            import os
            return os.system, ("touch " + str(tmp_path / "pwned"),)

    path.write_bytes(STAGE_MAGIC + pickle.dumps((key, Evil())))
    assert load_stage("modes", key, root=tmp_path) == (False, None)
    assert not (tmp_path / "pwned").exists()
    assert stage_path("modes", key, tmp_path) == path
    assert not [p for p in path.parent.iterdir() if p.name.startswith(".")]  # no temporaries


@pytest.mark.slow
def test_a_renamed_scene_reuses_every_stage(tmp_path, monkeypatch):
    monkeypatch.setenv("LBSHAPE_CACHE", str(tmp_path / "cache"))
    scene = _bar()
    first = precompute(scene)
    assert first.stages.cached == () and not first.stages.from_cache
    renamed = dataclasses.replace(scene, name="my-copy")
    again = precompute(renamed)
    assert again.stages.from_cache and set(again.stages.cached) == set(stage_names(scene))
    for path in (tmp_path / "cache").glob(f"{ARTIFACT_NAME}-*.npz"):
        path.unlink()  # only the stage entries left: every one is loaded, none computed
    rebuilt = precompute(dataclasses.replace(scene, name="third"))
    assert not rebuilt.stages.from_cache and _recomputed(rebuilt) == set()
    monkeypatch.setenv("LBSHAPE_CACHE", str(tmp_path / "fresh"))
    precompute(scene, force=True)
    _assert_same_artifact(tmp_path / "cache", tmp_path / "fresh")


@pytest.mark.slow
def test_a_new_load_reruns_only_the_stages_that_read_it(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("LBSHAPE_CACHE", str(tmp_path / "cache"))
    precompute(_bar())
    runtime = precompute(_bar(name="slower", dt=0.01, steps=400,
                              loads=[{"type": "region_force", "vector": [0.0, 0.0, -2.0],
                                      "region": "x > 0.399", "profile": "constant"}]))
    assert _recomputed(runtime) == set()  # dt, steps and a load's profile: nothing
    for path in (tmp_path / "cache").glob(f"{ARTIFACT_NAME}-*.npz"):
        path.unlink()
    loaded = _bar(load=(0.0, 0.0, -5.0))
    capsys.readouterr()
    pre = precompute(loaded, progress=True)
    assert set(pre.stages.cached) == LOAD_FREE  # modes, LB spectrum, examples: reused
    bars = capsys.readouterr().err  # the progress bars say which stages came from the cache
    assert "modes        (cache)" in bars and "derivatives  (cache)" not in bars, bars
    assert _recomputed(pre) == set(stage_names(loaded)) - LOAD_FREE
    assert {"derivatives", "static-equilibria", "example-stiffness"} <= _recomputed(pre)
    monkeypatch.setenv("LBSHAPE_CACHE", str(tmp_path / "fresh"))
    precompute(loaded, force=True)
    _assert_same_artifact(tmp_path / "cache", tmp_path / "fresh")


def test_a_new_mesh_reruns_every_stage(tmp_path, monkeypatch):
    monkeypatch.setenv("LBSHAPE_CACHE", str(tmp_path / "cache"))
    precompute(_bar())
    pre = precompute(_bar(cells=(10, 2, 2)))
    assert pre.stages.cached == () and _recomputed(pre) == set(stage_names(_bar()))
    for name in stage_names(_bar()):  # each mesh keeps its own entry of every stage
        assert len(list((tmp_path / "cache" / "stages").glob(f"{name}-{16 * '?'}.pkl"))) == 2, name


def _twist(angle: float, anchor: str) -> dict:
    return {"pose": "twist", "parameters": {"angle": angle, "axis": "z", "anchor": anchor}}


def _local_bar() -> lbshape.Scene:
    """A clamped bar with local examples (regions) under gravity."""
    return lbshape.Scene.from_mesh(
        structured_box((0.05, 0.05, 0.4), (2, 2, 8)), name="local", fixed="z < 0.001",
        reduced={"m": 4, "r": 12, "s": 20}, material={"young": 1e5, "density": 1000.0},
        examples=[_twist(1.0, "min"), _twist(-0.6, "max")], example_stiffness=200.0,
        regions=[{"name": "low", "region": "z < 0.2", "examples": [0]},
                 {"name": "high", "region": "z > 0.2", "examples": [1]}],
        loads=[{"type": "gravity", "vector": [0.0, 0.0, -9.81]}], dt=0.002, steps=5)


def _free_bar() -> lbshape.Scene:
    """A free bar with one example (auto stiffness) under gravity."""
    return lbshape.Scene.from_mesh(
        structured_box((0.05, 0.05, 0.4), (2, 2, 8)), name="free",
        reduced={"m": 4, "r": 12, "s": 20}, material={"young": 1e5, "density": 1000.0},
        examples=[_twist(1.0, "min")], example_stiffness="auto",
        loads=[{"type": "gravity", "vector": [0.0, 0.0, -9.81]}], dt=0.002, steps=5)


@pytest.mark.slow
@pytest.mark.parametrize("build, reused", [
    (_local_bar, {"mesh", "modes", "lb", "regions"}),
    (_free_bar, {"mesh", "modes", "derivatives", "basis", "lb", "examples", "target-table",
                 "lb-cubature"}),  # a free body's basis holds no static responses
], ids=["local", "free"])
def test_local_and_free_scenes_reuse_what_a_new_load_leaves(tmp_path, monkeypatch, build,
                                                            reused):
    monkeypatch.setenv("LBSHAPE_CACHE", str(tmp_path / "cache"))
    scene = build()
    precompute(scene)
    loaded = dataclasses.replace(scene, loads=tuple(
        dataclasses.replace(load, vector=tuple(2.0 * np.asarray(load.vector)))
        for load in scene.loads))
    pre = precompute(loaded)
    assert set(pre.stages.cached) == reused
    monkeypatch.setenv("LBSHAPE_CACHE", str(tmp_path / "fresh"))
    precompute(loaded, force=True)
    for folder in ("cache", "fresh"):  # keep the changed scene's artifact only
        for path in (tmp_path / folder).glob(f"{ARTIFACT_NAME}-*.npz"):
            if pre.key[:16] not in path.name:
                path.unlink()
    _assert_same_artifact(tmp_path / "cache", tmp_path / "fresh")
