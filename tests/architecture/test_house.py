"""The house limits, read from the source: no module over 700 lines, no function over 80
lines, no function (compiled kernels included) with more than 12 positional parameters —
a kernel that needs more takes named structures (views of one buffer)."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[2] / "lbshape"
MAX_MODULE_LINES = 700
MAX_FUNCTION_LINES = 80
MAX_POSITIONAL = 12


def _sources() -> dict[Path, str]:
    return {path: path.read_text(encoding="utf-8") for path in sorted(PACKAGE.rglob("*.py"))}


SOURCES = _sources()


def _functions():
    for path, text in SOURCES.items():
        for node in ast.walk(ast.parse(text, filename=str(path))):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                yield path.relative_to(PACKAGE.parent), node


def test_no_module_is_over_the_line_limit():
    long = {str(path.relative_to(PACKAGE.parent)): text.count("\n")
            for path, text in SOURCES.items() if text.count("\n") > MAX_MODULE_LINES}
    assert not long, f"modules over {MAX_MODULE_LINES} lines: {long}"


def test_no_function_is_over_the_line_limit():
    long = {f"{path}:{node.name}": node.end_lineno - node.lineno + 1
            for path, node in _functions()
            if node.end_lineno - node.lineno + 1 > MAX_FUNCTION_LINES}
    assert not long, f"functions over {MAX_FUNCTION_LINES} lines: {long}"


def test_no_function_takes_more_than_twelve_positional_parameters():
    wide = {f"{path}:{node.name}": len(node.args.posonlyargs) + len(node.args.args)
            for path, node in _functions()
            if len(node.args.posonlyargs) + len(node.args.args) > MAX_POSITIONAL}
    assert not wide, f"functions with over {MAX_POSITIONAL} positional parameters: {wide}"
