"""Safe region expressions in x, y, z (fixed regions, load regions, local-example regions).

An expression such as ``"z > 0.99"`` or ``"(x < 0.1) & (abs(y) <= 0.05)"`` is parsed
with :mod:`ast` and evaluated on vertex coordinates by walking a whitelist of
nodes: numbers, the names x, y, z, arithmetic, comparisons (chained too),
``and``/``or``/``not``, ``&``/``|``/``~`` and a few math functions. Nothing is ever
passed to ``eval``.
"""

from __future__ import annotations

import ast
import operator
from collections.abc import Callable

import numpy as np

from lbshape.errors import LbshapeError

_BINARY: dict[type, Callable] = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: operator.mul,
    ast.Div: operator.truediv,
    ast.Pow: operator.pow,
    ast.Mod: operator.mod,
    ast.BitAnd: np.logical_and,
    ast.BitOr: np.logical_or,
}
_COMPARE: dict[type, Callable] = {
    ast.Lt: operator.lt,
    ast.LtE: operator.le,
    ast.Gt: operator.gt,
    ast.GtE: operator.ge,
    ast.Eq: operator.eq,
    ast.NotEq: operator.ne,
}
_FUNCTIONS: dict[str, Callable] = {
    "abs": np.abs,
    "sqrt": np.sqrt,
    "sin": np.sin,
    "cos": np.cos,
    "min": np.minimum,
    "max": np.maximum,
}
_CONSTANTS = {"pi": np.pi}
_VARIABLES = ("x", "y", "z")


def parse_region(expression: str) -> ast.Expression:
    """Parse and validate a region expression; raise LbshapeError if unsafe or malformed."""
    if not isinstance(expression, str) or not expression.strip():
        raise LbshapeError(f"region expression must be a non-empty string, got {expression!r}")
    try:
        tree = ast.parse(expression.strip(), mode="eval")
    except SyntaxError:
        raise LbshapeError(f"region expression {expression!r} is not valid syntax") from None
    for node in ast.walk(tree):
        allowed = (
            ast.Expression, ast.BinOp, ast.UnaryOp, ast.BoolOp, ast.Compare, ast.Call,
            ast.Name, ast.Constant, ast.Load, ast.USub, ast.UAdd, ast.Not, ast.Invert,
            ast.And, ast.Or, *_BINARY, *_COMPARE,
        )
        if not isinstance(node, allowed):
            raise LbshapeError(
                f"region expression {expression!r}: '{type(node).__name__}' is not allowed "
                "(use numbers, x, y, z, arithmetic, comparisons, and/or/not, abs, sqrt, min, max)"
            )
        if isinstance(node, ast.Name) and node.id not in (*_VARIABLES, *_FUNCTIONS, *_CONSTANTS):
            raise LbshapeError(f"region expression {expression!r}: unknown name '{node.id}'")
        if isinstance(node, ast.Call):
            if not isinstance(node.func, ast.Name) or node.func.id not in _FUNCTIONS:
                raise LbshapeError(f"region expression {expression!r}: unknown function")
            if node.keywords:
                raise LbshapeError(f"region expression {expression!r}: keyword arguments")
        if isinstance(node, ast.Constant) and not isinstance(node.value, int | float):
            raise LbshapeError(f"region expression {expression!r}: only numeric constants")
    return tree


def evaluate_region(expression: str, points: np.ndarray) -> np.ndarray:
    """Evaluate a boolean region expression on vertices.

    Args:
        expression: e.g. ``"z > 0.99"``.
        points: (n, 3) coordinates in metres.

    Returns:
        (n,) bool mask.
    """
    tree = parse_region(expression)
    env = {"x": points[:, 0], "y": points[:, 1], "z": points[:, 2]}
    value = _eval(tree.body, env, expression)
    mask = np.broadcast_to(np.asarray(value), (points.shape[0],))
    if mask.dtype != bool:
        raise LbshapeError(f"region expression {expression!r} must be a comparison (true/false)")
    return np.array(mask)


def region_vertices(expression: str, points: np.ndarray, *, what: str = "region") -> np.ndarray:
    """Indices (k,) of the vertices selected by ``expression``; error if none."""
    idx = np.flatnonzero(evaluate_region(expression, points))
    if idx.size == 0:
        raise LbshapeError(f"{what} {expression!r} selects no vertex of the mesh")
    return idx


def _eval(node: ast.AST, env: dict, source: str):
    if isinstance(node, ast.Constant):
        return node.value
    if isinstance(node, ast.Name):
        if node.id in env:
            return env[node.id]
        if node.id in _CONSTANTS:
            return _CONSTANTS[node.id]
        raise LbshapeError(f"region expression {source!r}: '{node.id}' is not a value")
    if isinstance(node, ast.BinOp):
        return _BINARY[type(node.op)](_eval(node.left, env, source), _eval(node.right, env, source))
    if isinstance(node, ast.UnaryOp):
        operand = _eval(node.operand, env, source)
        if isinstance(node.op, ast.USub):
            return -operand
        if isinstance(node.op, ast.UAdd):
            return operand
        return np.logical_not(operand)
    if isinstance(node, ast.BoolOp):
        values = [_eval(v, env, source) for v in node.values]
        combine = np.logical_and if isinstance(node.op, ast.And) else np.logical_or
        result = values[0]
        for v in values[1:]:
            result = combine(result, v)
        return result
    if isinstance(node, ast.Compare):
        left = _eval(node.left, env, source)
        result = True
        for op, comparator in zip(node.ops, node.comparators, strict=True):
            right = _eval(comparator, env, source)
            result = np.logical_and(result, _COMPARE[type(op)](left, right))
            left = right
        return result
    if isinstance(node, ast.Call):
        args = [_eval(a, env, source) for a in node.args]
        return _FUNCTIONS[node.func.id](*args)
    raise LbshapeError(f"region expression {source!r}: unsupported construct")
