"""Nothing half-written: a run that stops leaves no folder that looks like a result, and
a precompute (failed or not) leaves no lock file in the cache."""

from __future__ import annotations

import fcntl
import re
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from lbshape.cli import main
from lbshape.errors import LbshapeError
from lbshape.io.cache import artifact_lock
from lbshape.pipeline.precompute import precompute
from lbshape.scene import load_scene

DEMO = Path(__file__).resolve().parents[2] / "lbshape" / "scene" / "builtin" / "demo.toml"


def _scene_file(folder: Path, name: str, **replace: str) -> Path:
    """The demo scene under another name with some of its lines replaced."""
    text = DEMO.read_text().replace('name = "demo"', f'name = "{name}"')
    for old, new in replace.items():
        assert old in text, old
        text = text.replace(old, new)
    path = folder / f"{name}.toml"
    path.write_text(text)
    return path


@pytest.fixture
def diverging(tmp_path) -> Path:
    """The demo, Neo-Hookean, with an absurd torque: the reduced run stops within 30 steps
    (measured: an element inverts at step 18, the load named as the likely cause). Runs
    stop only on a wrong state: a StVK bar under 1e9 N m runs on (6 m in 30 steps)."""
    return _scene_file(tmp_path, "demo-diverging", **{
        "vector = [0.0, 0.0, 100.0]": "vector = [0.0, 0.0, 1.0e5]", "steps = 300": "steps = 30",
        'model = "stvk"': 'model = "neohookean"'})


def _siblings(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.parent.iterdir() if p.name.startswith(f".{folder.name}"))


def test_a_run_that_stops_leaves_only_the_failed_marker(diverging, tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    # an earlier successful run's files (trajectory with more frames than the new run)
    for name in ("stats.json", "states.npz", "trajectory.pvd",
                 *(f"trajectory_{i:05d}.vtu" for i in range(20))):
        (out / name).write_text("earlier run")
    assert main(["simulate", str(diverging), "--out", str(out), "--json"]) == 3
    assert "simulation stopped" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["FAILED.txt"]
    text = (out / "FAILED.txt").read_text()
    assert text.startswith("simulation stopped: ") and "no result" in text
    assert '"stable": false' in text and '"message"' in text
    assert _siblings(out) == []  # no temporary folder left beside it


def test_a_stable_run_replaces_a_failed_or_longer_one_as_a_whole(diverging, tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["simulate", str(diverging), "--out", str(out)]) == 3
    assert main(["simulate", str(diverging), "--steps", "3", "--out", str(out)]) == 0
    names = sorted(p.name for p in out.iterdir())
    frames = re.findall(r'file="([^"]+)"', (out / "trajectory.pvd").read_text())
    assert names == sorted(["stats.json", "states.npz", "trajectory.pvd", *frames])
    with np.load(out / "states.npz") as states:
        assert len(states["times"]) == len(frames) == 4
    assert _siblings(out) == []


def test_a_render_of_a_stopped_run_is_labelled_stopped(diverging, tmp_path, capsys):
    """``render`` draws a stopped run only as ``simulation-STOPPED.png`` and removes an
    earlier run's ``simulation.png``."""
    out = tmp_path / "figures"
    out.mkdir()
    (out / "simulation.png").write_bytes(b"earlier run")
    assert main(["render", str(diverging), "--steps", "30", "--out", str(out)]) == 3
    names = {p.name for p in out.iterdir()}
    assert "simulation-STOPPED.png" in names and "simulation.png" not in names
    assert "simulation stopped" in capsys.readouterr().err


def test_a_folder_of_other_files_is_refused_before_the_run(tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    assert main(["simulate", "demo", "--steps", "2", "--out", str(out)]) == 2
    assert "holds other files (notes.txt)" in capsys.readouterr().err
    assert [p.name for p in out.iterdir()] == ["notes.txt"]


def test_a_failed_precompute_leaves_no_lock_file(tmp_path, monkeypatch):
    cache = tmp_path / "cache"
    monkeypatch.setenv("LBSHAPE_CACHE", str(cache))
    scene = load_scene(_scene_file(tmp_path, "demo-too-large", **{"r = 20": "r = 100000"}))
    with pytest.raises(LbshapeError, match="free DOFs"):
        precompute(scene, progress=False)
    assert cache.is_dir() and list(cache.glob("*.lock")) == []


def test_stale_lock_files_are_removed_and_held_ones_kept(tmp_path):
    stale = tmp_path / "gone-0123456789abcdef.lock"  # its process was killed
    stale.write_bytes(b"")
    held = tmp_path / "busy-0123456789abcdef.lock"  # a running job's
    with open(held, "a+b") as job:
        fcntl.flock(job.fileno(), fcntl.LOCK_EX)
        with artifact_lock("demo", "ab" * 32, root=tmp_path) as path:
            assert path.exists() and not stale.exists()
        assert not path.exists() and held.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == [held.name]


def test_a_waiting_job_locks_again_after_the_holder_deletes_the_file(tmp_path):
    """The holder deletes the lock file on exit; a job that waited on that file must
    not believe it holds the lock, but lock the path's new file, exclusively."""
    key = "cd" * 32
    events = []
    first_in = threading.Event()

    def waiter():
        first_in.wait()
        with artifact_lock("demo", key, root=tmp_path) as path:
            events.append("second in")
            with open(path, "a+b") as other, pytest.raises(BlockingIOError):
                fcntl.flock(other.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            events.append("second exclusive")

    thread = threading.Thread(target=waiter)
    thread.start()
    with artifact_lock("demo", key, root=tmp_path):
        first_in.set()
        time.sleep(0.3)  # the waiter opens the same file and blocks on it
        events.append("first out")
    thread.join(10)
    assert events == ["first out", "second in", "second exclusive"]
    assert list(tmp_path.glob("*.lock")) == []
