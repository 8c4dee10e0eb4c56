"""The README: its Python example runs, its results table matches results/table2.json, its size."""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"


def _load_readme_table():
    path = ROOT / "scripts" / "readme_table.py"
    spec = importlib.util.spec_from_file_location("readme_table", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def python_example(text: str) -> str:
    """The first ```python block under the README's "Python" heading."""
    heading = re.search(r"^#+ Python\s*$", text, flags=re.MULTILINE)
    assert heading is not None, "README.md has no 'Python' heading"
    block = re.search(r"```python\n(.*?)```", text[heading.end():], flags=re.DOTALL)
    assert block is not None, "README.md has no ```python block under 'Python'"
    return block.group(1)


def _has_simulation_api() -> bool:
    """Whether the package offers ``lbshape.simulation`` (named in ``__all__``; not imported
    here, so a broken API fails the test instead of skipping it)."""
    try:
        import lbshape
    except ImportError:
        return False
    return "simulation" in getattr(lbshape, "__all__", ())


def test_readme_size():
    size = README.stat().st_size
    assert size <= 8192, f"README.md is {size} bytes, above 8 KB"


def test_readme_starts_with_make_demo_and_make_test():
    head = "\n".join(README.read_text(encoding="utf-8").splitlines()[:6])
    assert "make demo" in head and "make test" in head


def test_readme_table_matches_table2_json():
    module = _load_readme_table()
    current = module.current_block(README.read_text(encoding="utf-8"))
    expected = module.render_block(ROOT)
    assert current == expected, (
        "README.md's results table differs from results/table2.json; "
        "run `python scripts/readme_table.py`"
    )


@pytest.mark.skipif(not _has_simulation_api(),
                    reason="lbshape.simulation (the public API) does not exist yet")
def test_readme_python_example_runs(tmp_path):
    code = python_example(README.read_text(encoding="utf-8"))
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    env.setdefault("LBSHAPE_CACHE", str(tmp_path / "cache"))
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, f"README example failed:\n{done.stdout}\n{done.stderr}"
    assert "largest displacement" in done.stdout
