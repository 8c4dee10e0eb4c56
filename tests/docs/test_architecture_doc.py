"""docs/architecture.md describes the package as it is: every module, folder and file it
names exists, its module table lists exactly the modules of each subpackage, and it stays
under 10 KB."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "architecture.md"
PACKAGE = ROOT / "lbshape"
MAX_BYTES = 10 * 1024
#: names the doc may use for a package that the source holds under another name
#: (the doc's name -> the source's), for as long as the source keeps the other one
ALIASES = {"interactive": "live"}

TEXT = DOC.read_text(encoding="utf-8")
#: code spans of the doc
SPANS = re.findall(r"`([^`\n]+)`", TEXT)
#: a path: words, dots, dashes and globs joined by slashes (`scene/build.py`, `tests/`)
PATH = re.compile(r"^[\w.*-]+(/[\w.*-]*)+$")
#: a dotted module name (`lbshape.pipeline.precomputed`)
DOTTED = re.compile(r"^lbshape(\.\w+)+$")


def _aliased(parts: list[str]) -> list[str]:
    """``parts`` with a package the doc names by its alias renamed to the source's name,
    while the source has no package of the doc's name."""
    return [ALIASES[p] if p in ALIASES and not (PACKAGE / p).exists() else p for p in parts]


def _exists(relative: str) -> bool:
    """Whether a path the doc names exists from the repository root or from lbshape/."""
    parts = _aliased(relative.rstrip("/").split("/"))
    for base in (ROOT, PACKAGE):
        if any(True for _ in base.glob("/".join(parts))):
            return True
    return False


def _module_exists(dotted: str) -> bool:
    """A dotted name is a module or package of lbshape, or a module and a name it defines."""
    parts = _aliased(dotted.split(".")[1:])
    path = PACKAGE.joinpath(*parts)
    if path.with_suffix(".py").is_file() or (path / "__init__.py").is_file():
        return True
    module = path.parent.with_suffix(".py")
    if not module.is_file():
        module = path.parent / "__init__.py"
    return module.is_file() and re.search(
        rf"^(class|def) {parts[-1]}\b|^{parts[-1]}\b\s*[:=]",
        module.read_text(encoding="utf-8"), flags=re.MULTILINE) is not None


def _table_rows() -> dict[str, set[str]]:
    """The module table: subpackage -> the module names its last cell lists."""
    rows = {}
    for line in TEXT.splitlines():
        cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
        head = re.fullmatch(r"`(\w+)/`", cells[0]) if len(cells) >= 3 else None
        if head:
            rows[head.group(1)] = set(re.findall(r"`(\w+)`", cells[-1]))
    return rows


def test_the_doc_stays_under_its_size():
    size = len(TEXT.encode("utf-8"))
    assert size <= MAX_BYTES, f"docs/architecture.md is {size} bytes (at most {MAX_BYTES})"


def test_every_path_the_doc_names_exists():
    paths = sorted({span for span in SPANS if PATH.match(span)})
    assert paths, "the doc names no path"
    missing = [path for path in paths if not _exists(path)]
    assert not missing, f"docs/architecture.md names paths that do not exist: {missing}"


def test_every_dotted_module_the_doc_names_exists():
    missing = [name for name in sorted({s for s in SPANS if DOTTED.match(s)})
               if not _module_exists(name)]
    assert not missing, f"docs/architecture.md names modules that do not exist: {missing}"


def test_the_module_table_lists_every_subpackage_and_module():
    rows = _table_rows()
    packages = sorted(p.name for p in PACKAGE.iterdir() if (p / "__init__.py").is_file())
    documented = sorted(_aliased(list(rows)))
    assert documented == packages, (
        f"the module table's subpackages {documented} differ from lbshape's {packages}")
    wrong = {}
    for name, listed in rows.items():
        folder = PACKAGE / _aliased([name])[0]
        actual = {p.stem for p in folder.glob("*.py") if p.stem != "__init__"}
        if listed != actual:
            wrong[name] = {"not in the doc": sorted(actual - listed),
                           "not in the package": sorted(listed - actual)}
    assert not wrong, f"update the module table of docs/architecture.md: {wrong}"
