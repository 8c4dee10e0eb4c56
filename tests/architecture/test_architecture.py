"""The package's dependency graph, read from the source: top-level imports of lbshape's own
modules, no arrow back up the layers, no import cycle, heavy optional packages lazy."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[2] / "lbshape"
#: optional heavy packages that may only be imported inside functions
HEAVY = ("dolfinx", "petsc4py", "slepc4py", "pyvista", "matplotlib", "gmsh")
#: the layers from the top down (imports only point down):
#: cli → studies → report → pipeline → scene → analysis → numerics; live (the interactive
#: session and window) → report, pipeline; api → pipeline, scene, spectral, geometry;
#: io is used by any layer
NUMERICS = ("geometry", "fem", "spectral", "elastic", "shapespace", "dynamics")
#: subpackage -> subpackages it must never import
FORBIDDEN = {
    **{low: ("analysis", "scene", "pipeline", "report", "studies", "live", "api", "cli")
       for low in NUMERICS},
    "analysis": ("scene", "pipeline", "report", "studies", "live", "api", "cli"),
    "scene": ("pipeline", "report", "studies", "live", "api", "cli"),
    "pipeline": ("report", "studies", "live", "api", "cli"),
    "report": ("studies", "live", "api", "cli"),
    "studies": ("live", "api", "cli"),
    "live": ("studies", "api", "cli"),
    "api": ("report", "studies", "live", "cli"),
}
#: what runs work (a precompute or a simulation): report draws runs it is given, so it
#: imports none of these modules or names
RUNNING_MODULES = ("lbshape.pipeline.precompute", "lbshape.pipeline.simulate",
                   "lbshape.pipeline.batch", "lbshape.pipeline.stages")
RUNNING_NAMES = ("precompute", "simulate", "example_influence", "reduced_simulation",
                 "run_full_space", "simulation")

def _modules() -> dict[str, ast.Module]:
    trees = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        trees[name] = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    return trees


MODULES = _modules()


def _imported(node: ast.AST) -> list[str]:
    """Module names an import statement names (``from a import b``: ``a`` and ``a.b``)."""
    if isinstance(node, ast.Import):
        return [alias.name for alias in node.names]
    if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
        return [node.module] + [f"{node.module}.{alias.name}" for alias in node.names]
    return []


def _top_level_imports(tree: ast.Module) -> list[ast.AST]:
    return [node for node in tree.body if isinstance(node, ast.Import | ast.ImportFrom)]


def _type_checking_imports(tree: ast.Module) -> list[ast.AST]:
    """Imports under a top-level ``if TYPE_CHECKING:`` (annotations only, never run)."""
    return [node for block in tree.body
            if isinstance(block, ast.If) and getattr(block.test, "id", None) == "TYPE_CHECKING"
            for node in block.body if isinstance(node, ast.Import | ast.ImportFrom)]


def _nested_imports(tree: ast.Module) -> list[ast.AST]:
    top = set(map(id, _top_level_imports(tree) + _type_checking_imports(tree)))
    return [node for node in ast.walk(tree)
            if isinstance(node, ast.Import | ast.ImportFrom) and id(node) not in top]


def _edges(name: str) -> set[str]:
    """lbshape modules that module ``name`` imports at its top level."""
    return {target for node in _top_level_imports(MODULES[name]) for target in _imported(node)
            if target in MODULES and target != name}


def test_lbshape_imports_its_own_modules_at_the_top_only():
    nested = [f"{name}:{node.lineno}" for name, tree in MODULES.items()
              for node in _nested_imports(tree)
              if any(t.split(".")[0] == "lbshape" for t in _imported(node))]
    assert not nested, f"lbshape imports inside functions: {nested}"


def test_heavy_optional_packages_are_imported_lazily():
    eager = [f"{name}:{node.lineno}" for name, tree in MODULES.items()
             for node in _top_level_imports(tree)
             if any(t.split(".")[0] in HEAVY for t in _imported(node))]
    assert not eager, f"heavy optional packages imported at module top: {eager}"


@pytest.mark.parametrize("layer", sorted(FORBIDDEN))
def test_no_arrow_back_up_the_layers(layer):
    wrong = []
    for name, tree in MODULES.items():
        if name.split(".")[1:2] != [layer]:
            continue
        for node in ast.walk(tree):
            for target in _imported(node):
                parts = target.split(".")
                if parts[0] == "lbshape" and len(parts) > 1 and parts[1] in FORBIDDEN[layer]:
                    wrong.append(f"{name}:{node.lineno} -> {target}")
    assert not wrong, f"{layer} imports a layer above it: {sorted(set(wrong))}"


def test_report_never_runs_a_precompute_or_a_simulation():
    wrong = []
    for name, tree in MODULES.items():
        if name.split(".")[1:2] != ["report"]:
            continue
        for node in ast.walk(tree):
            targets = _imported(node)
            names = [alias.name for alias in getattr(node, "names", ())]
            if any(t.startswith(RUNNING_MODULES) for t in targets) or any(
                    n.split(".")[-1] in RUNNING_NAMES for n in names if targets):
                wrong.append(f"{name}:{node.lineno} -> {', '.join(targets)}")
    assert not wrong, f"report runs work instead of drawing runs it is given: {wrong}"


def test_the_module_import_graph_has_no_cycle():
    graph = {name: _edges(name) for name in MODULES}
    state: dict[str, int] = {}
    path: list[str] = []

    def visit(name: str) -> list[str] | None:
        state[name] = 1
        path.append(name)
        for target in sorted(graph[name]):
            if state.get(target) == 1:
                return path[path.index(target):] + [target]
            if target not in state:
                cycle = visit(target)
                if cycle:
                    return cycle
        path.pop()
        state[name] = 2
        return None

    for name in sorted(graph):
        if name not in state:
            cycle = visit(name)
            assert cycle is None, f"import cycle: {' -> '.join(cycle)}"
