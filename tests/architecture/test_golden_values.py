"""The golden values file ``tests/golden.toml``: every entry complete, each measured value
on the right side of its test's limit, and each entry named after the test file that
reads it (``<file>.<name>`` for ``tests/<subpackage>/test_<file>.py``)."""

from __future__ import annotations

import numbers
from pathlib import Path

import pytest
from conftest import BOUNDS, GOLDEN, golden, golden_keys, golden_table

REPOSITORY = GOLDEN.parents[1]
FIELDS = {"measured", "limit", "bound", "what", "test"}


def test_the_file_has_entries_and_unknown_keys_are_refused():
    assert len(golden_keys()) > 40
    with pytest.raises(KeyError, match="no golden value 'drag.nothing'"):
        golden("drag.nothing")


@pytest.mark.parametrize("key", golden_keys())
def test_entry_is_complete_and_its_measured_value_keeps_its_bound(key):
    entry = golden_table()
    for part in key.split("."):
        entry = entry[part]
    assert set(entry) == FIELDS, sorted(set(entry) ^ FIELDS)
    value = golden(key)
    assert value.bound in BOUNDS
    assert isinstance(value.limit, numbers.Real) and value.what.strip()
    measured = value.measured if isinstance(value.measured, tuple) else (value.measured,)
    assert len(measured) in (1, 2) and all(isinstance(m, numbers.Real) for m in measured)
    assert min(measured) == measured[0] and max(measured) == measured[-1]
    low, high = measured[0], measured[-1]
    keeps = {"below": high < value.limit, "at_most": high <= value.limit,
             "above": low > value.limit, "at_least": low >= value.limit}[value.bound]
    assert keeps, f"{key}: measured {value.measured} not {value.bound} {value.limit}"


@pytest.mark.parametrize("key", golden_keys())
def test_entry_names_the_test_that_reads_it(key):
    path, _, name = golden(key).test.partition("::")
    source = REPOSITORY / path
    assert source.is_file(), path
    assert Path(path).stem == f"test_{key.split('.')[0]}", (key, path)
    text = source.read_text(encoding="utf-8")
    assert f"def {name}(" in text and "golden(" in text, (key, name)
