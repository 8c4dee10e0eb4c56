"""The literate scripts of ``docs/examples/`` run as a user runs them (a fresh interpreter,
this checkout's package), with few steps, and print what they claim."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "docs" / "examples"


def _run(script: str, *args: str, cwd: Path) -> str:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1", "MPLBACKEND": "Agg"}
    done = subprocess.run([sys.executable, str(EXAMPLES / script), *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout


def test_every_example_is_tested():
    assert sorted(p.name for p in EXAMPLES.glob("*.py")) == [
        "builtin_scene.py", "own_mesh_with_examples.py", "reduced_vs_full.py"]


def test_builtin_scene(tmp_path):
    out = _run("builtin_scene.py", "--steps", "10", cwd=tmp_path)
    assert "t = 0.010 s after 10 steps" in out
    assert float(re.search(r"largest displacement: ([0-9.]+) mm", out)[1]) > 0.0
    assert list(tmp_path.iterdir()) == []


def test_own_mesh_with_examples(tmp_path):
    out = _run("own_mesh_with_examples.py", "--steps", "10", cwd=tmp_path)
    moved = float(re.search(r"examples move the bar by up to ([0-9.]+) mm", out)[1])
    assert moved > 0.0, out
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("where", ["given", "default"])
def test_reduced_vs_full_plots_to_the_given_folder(tmp_path, where):
    work = tmp_path / "work"
    work.mkdir()
    args = ("--steps", "10") + ((str(tmp_path / "plots"),) if where == "given" else ())
    out = _run("reduced_vs_full.py", *args, cwd=work)
    png = Path(out.strip().splitlines()[-1])
    assert png.name == "reduced_vs_full.png" and png.stat().st_size > 1000
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert list(work.iterdir()) == []  # nothing in the working folder
    if where == "given":
        assert png.parent == tmp_path / "plots"
    else:
        assert png.parent.name.startswith("lbshape-example-")  # a new temporary folder
        png.unlink()
        png.parent.rmdir()
