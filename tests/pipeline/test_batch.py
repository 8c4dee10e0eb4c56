"""Batch jobs: several scenes in worker processes, a shared cache, a failed scene kept apart."""

from __future__ import annotations

import fcntl
import json
import shutil
from importlib import resources

import numpy as np
import pytest

from lbshape.cli import main
from lbshape.errors import LbshapeError
from lbshape.io.cache import artifact_lock, load_artifact
from lbshape.pipeline.batch import expand_scenes, run_jobs, summary_table

STEPS = 15  # > the 10 warm-up steps


def _bad_scene(folder):
    path = folder / "bad.toml"
    path.write_text('[object]\nshape = "demo-bar"\nbogus = 1\n')
    return path


def _fails_on_odd(value: str) -> int:
    if int(value) % 2:
        raise LbshapeError(f"odd {value}")
    return int(value) * 10


def test_run_jobs_keeps_order_and_failures_in_process():
    results = run_jobs(_fails_on_odd, ["2", "3", "4"], jobs=1)
    assert [r.scene for r in results] == ["2", "3", "4"]
    assert [r.ok for r in results] == [True, False, True]
    assert [r.value for r in results] == [20, None, 40]
    assert results[1].error == "odd 3" and results[1].exit_code == 2
    table = summary_table(results, ("value",), lambda v: (str(v),)).splitlines()
    assert len(table) == 2 + 3 and "FAILED" in table[3] and "odd 3" in table[3]
    with pytest.raises(LbshapeError, match="jobs"):
        run_jobs(_fails_on_odd, ["2", "4"], jobs=0)


def test_expand_scenes_globs_and_duplicates(tmp_path):
    for name in ("b.toml", "a.toml"):
        (tmp_path / name).write_text("")
    scenes, unmatched = expand_scenes(["demo", str(tmp_path / "*.toml"), "demo",
                                       str(tmp_path / "none*.toml")])
    assert scenes == ["demo", str(tmp_path / "a.toml"), str(tmp_path / "b.toml")]
    assert len(unmatched) == 1 and "no scene file matches" in unmatched[0].error


def test_artifact_lock_is_exclusive_between_open_files(tmp_path):
    with artifact_lock("demo", "ab" * 32, root=tmp_path) as path:
        with open(path, "a+b") as other, pytest.raises(BlockingIOError):
            fcntl.flock(other.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    with open(path, "a+b") as other:  # released on exit
        fcntl.flock(other.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)


@pytest.mark.slow
def test_precompute_batch_with_a_bad_scene(tmp_path, capsys):
    code = main(["precompute", "demo", str(_bad_scene(tmp_path)), "-j", "1"])
    assert code != 0
    out, err = capsys.readouterr()
    rows = [line for line in out.splitlines() if line.startswith("| ")]
    assert len(rows) == 3, out  # header + one row per scene
    assert "| demo " in rows[1] and "| ok " in rows[1]
    assert "FAILED" in rows[2] and "bogus" in rows[2]
    assert err.strip().splitlines()[-1].startswith("error: 1 of 2 scenes failed")


@pytest.mark.slow
def test_concurrent_precomputes_of_one_scene_leave_one_valid_entry(tmp_path, monkeypatch,
                                                                   capsys):
    cache = tmp_path / "cache"
    monkeypatch.setenv("LBSHAPE_CACHE", str(cache))
    resource = resources.files("lbshape.scene").joinpath("builtin", "demo.toml")
    with resources.as_file(resource) as file:
        copy = shutil.copy(file, tmp_path / "demo.toml")  # same scene, another argument
    assert main(["precompute", "demo", str(copy), "-j", "2"]) == 0
    out = capsys.readouterr().out
    rows = [line for line in out.splitlines() if line.startswith("| ")][1:]
    origins = sorted(row.split("|")[4].strip() for row in rows)
    assert origins == ["cache", "computed"], out  # computed once, loaded once
    entries = sorted(cache.glob("*.npz"))
    assert len(entries) == 1, entries
    assert not [p for p in cache.iterdir() if p.name.startswith(".")]  # no temporaries
    from lbshape.pipeline.precompute_key import ARTIFACT_NAME, scene_cache_key
    from lbshape.scene import load_scene

    arrays, meta = load_artifact(ARTIFACT_NAME, scene_cache_key(load_scene("demo")),
                                 required=["U"])
    assert np.isfinite(arrays["U"]).all() and meta["scene"] == "demo"


@pytest.mark.slow
def test_bench_batch_with_a_bad_scene(tmp_path, capsys):
    code = main(["bench", "demo", str(_bad_scene(tmp_path)), "--json", "--steps", str(STEPS),
                 "--repeats", "1", "--out-dir", str(tmp_path / "out")])
    assert code != 0
    out, err = capsys.readouterr()
    rows = json.loads(out)["rows"]  # stdout stays one JSON document
    assert {row["scene"] for row in rows} == {"demo"} and len(rows) == 3
    table = [line for line in err.splitlines() if line.startswith("| ")]
    assert len(table) == 3 and "FAILED" in table[2] and "bad.toml" in table[2]
    assert "| ok " in table[1]
    assert err.strip().splitlines()[-1].startswith("error: 1 of 2 scenes failed")
    assert json.loads((tmp_path / "out" / "table2.json").read_text())["rows"] == rows


def test_an_unusable_cache_folder_is_a_one_line_error(tmp_path, monkeypatch, capsys):
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("")
    monkeypatch.setenv("LBSHAPE_CACHE", str(blocker / "cache"))
    assert main(["precompute", "demo"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: cannot use the cache folder") and "\n" not in err, err
