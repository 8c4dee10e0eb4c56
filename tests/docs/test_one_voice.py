"""One voice: the README and the docs describe the code as it is. No sentence compares it
with an earlier state of the code ("was", "no longer", "now", "formerly", …); that history
belongs in docs/decisions.md, dated, which this check leaves out."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
#: the pages that speak in the present: the README and every page of docs/ but the
#: decisions log
PAGES = [ROOT / "README.md"] + sorted(
    path for path in (ROOT / "docs").glob("*.md") if path.name != "decisions.md")
#: words and phrases that compare with an earlier state (whole words, any case)
HISTORY = re.compile(
    r"\b(?:was|were|before|earlier|former|formerly|previously|no longer|not anymore|"
    r"anymore|now|used to|has been|have been|had been|until recently|so far|"
    r"the old|the previous (?:code|version|release|default|scheme)|nowadays)\b",
    flags=re.IGNORECASE)
#: technical uses of those words, allowed (an order of operations, not of versions)
ALLOWED = re.compile(
    r"\bbefore (?:a merge|writing\b|posing\b|the first\b|each\b|every\b|the step\b|"
    r"it is\b|they are\b)",
    flags=re.IGNORECASE)


def history_phrases(text: str) -> list[tuple[int, str]]:
    """(line number, line) of every line that compares with an earlier state."""
    found = []
    for number, line in enumerate(text.splitlines(), start=1):
        if HISTORY.search(ALLOWED.sub("", line)):
            found.append((number, line.strip()))
    return found


@pytest.mark.parametrize("page", PAGES, ids=lambda path: str(path.relative_to(ROOT)))
def test_the_page_speaks_of_the_code_as_it_is(page):
    found = history_phrases(page.read_text(encoding="utf-8"))
    assert not found, (
        f"{page.relative_to(ROOT)} compares with an earlier state of the code (rewrite in "
        f"the present; history goes to docs/decisions.md): {found}")


@pytest.mark.parametrize("line", [
    "The step was 0.21 ms before the split.",
    "Free bodies are no longer damped.",
    "The cache now keys on the material.",
    "Formerly the basis held 30 columns.",
    "At the former drag the leg moved 2 cm.",
])
def test_history_is_caught(line):
    assert history_phrases(line)


@pytest.mark.parametrize("line", [
    "`make test` before a merge.",
    "Try a file before writing a scene.",
    "The rest mesh before posing.",
    "Free flight agrees until the first bounce; before the first contact the paths match.",
    "The known limitations are stated plainly.",
])
def test_technical_uses_are_allowed(line):
    assert not history_phrases(line)
