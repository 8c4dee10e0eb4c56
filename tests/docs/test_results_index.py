"""results/README.md indexes every tracked results file and names the command that writes it."""

from __future__ import annotations

import importlib.util
import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
INDEX = ROOT / "results" / "README.md"


def _load_script():
    spec = importlib.util.spec_from_file_location("results_index",
                                                  ROOT / "scripts" / "results_index.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _tracked() -> list[str]:
    try:
        return _load_script().tracked_files(ROOT)
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")


def _sections(text: str) -> list[tuple[str, str]]:
    """(section text, command) per '## ' section of the index."""
    out = []
    for part in re.split(r"^## ", text, flags=re.MULTILINE)[1:]:
        command = re.search(r"^- command: `([^`]+)`", part, flags=re.MULTILINE)
        out.append((part, command.group(1) if command else ""))
    return out


def test_every_tracked_results_file_is_indexed_with_its_command():
    sections = _sections(INDEX.read_text(encoding="utf-8"))
    missing, commandless = [], []
    for name in _tracked():
        holders = [cmd for part, cmd in sections if f"| `{name}` |" in part]
        if not holders:
            missing.append(name)
        elif not holders[0].strip():
            commandless.append(name)
    assert not missing, f"results files missing from results/README.md: {missing}"
    assert not commandless, f"results files whose index section names no command: {commandless}"


def test_every_tracked_results_file_has_a_source_entry():
    module = _load_script()
    sources = module.load_sources(ROOT)
    for name in _tracked():
        entry = module.source_of(name, sources)
        for key in ("shows", "command", "machine", "threads"):
            assert entry.get(key), f"results/{name}: its SOURCES.toml entry has no {key!r}"


def test_stale_files_are_marked():
    """A file whose source entry says ``status = "stale"`` heads a STALE section of the
    index, and no other file does."""
    module = _load_script()
    sources = module.load_sources(ROOT)
    text = INDEX.read_text(encoding="utf-8")
    for name in _tracked():
        section = next(p for p, _ in _sections(text) if f"| `{name}` |" in p)
        stale = module.source_of(name, sources).get("status") == "stale"
        assert section.startswith("STALE") == stale, f"results/{name}: stale is {stale}"


def _masked(text: str) -> str:
    """The index without its commit and date columns (they follow git, not the sources)."""
    return re.sub(r"^(\| `[^`]+` \|).*$", r"\1", text, flags=re.MULTILINE)


def test_index_is_generated_from_sources():
    _tracked()
    expected = _load_script().render_index(ROOT)
    assert _masked(INDEX.read_text(encoding="utf-8")) == _masked(expected), (
        "results/README.md differs from results/SOURCES.toml; run "
        "`python scripts/results_index.py`"
    )
