"""A small TOML writer for the documents lbshape reads (scene files).

:func:`dumps` turns nested dicts of strings, booleans, integers, floats, lists and
dicts into TOML text that :mod:`tomllib` reads back to the same data: top-level
dicts become ``[tables]`` (nested ones ``[a.b]``), lists of dicts become arrays of
tables ``[[a]]`` and dicts inside those become inline tables. Dates and other types
are not supported (a :class:`TypeError` names the key).
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping

_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")


def _key(key: str) -> str:
    return key if _BARE_KEY.match(key) else json.dumps(key)


def _is_table_array(value) -> bool:
    return isinstance(value, list) and bool(value) and all(isinstance(v, Mapping) for v in value)


def _value(value, where: str) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)  # JSON string escapes are TOML basic-string escapes
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_value(v, where) for v in value) + "]"
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{_key(str(k))} = {_value(v, f'{where}.{k}')}"
                               for k, v in value.items()) + "}"
    raise TypeError(f"cannot write {where} of type {type(value).__name__} as TOML")


def _table(data: Mapping, path: list[str], lines: list[str], *, inline_dicts: bool) -> None:
    """Append ``data``'s plain keys, then its sub-tables, then its arrays of tables."""
    where = ".".join(path) or "the document"
    for key, value in data.items():
        if inline_dicts or not (isinstance(value, Mapping) or _is_table_array(value)):
            lines.append(f"{_key(str(key))} = {_value(value, f'{where}.{key}')}")
    for key, value in data.items():
        if isinstance(value, Mapping) and not inline_dicts:
            sub = [*path, str(key)]
            lines.extend(["", "[" + ".".join(_key(k) for k in sub) + "]"])
            _table(value, sub, lines, inline_dicts=False)
    for key, value in data.items():
        if _is_table_array(value) and not inline_dicts:
            sub = [*path, str(key)]
            for item in value:
                lines.extend(["", "[[" + ".".join(_key(k) for k in sub) + "]]"])
                _table(item, sub, lines, inline_dicts=True)


def dumps(data: Mapping) -> str:
    """TOML text of ``data`` (see the module docstring); ends with a newline."""
    lines: list[str] = []
    _table(data, [], lines, inline_dicts=False)
    while lines and not lines[0]:
        lines.pop(0)
    return "\n".join(lines) + "\n"
