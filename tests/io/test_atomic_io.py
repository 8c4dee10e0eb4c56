"""The atomic writer: content, the usual file mode, nothing left behind on failure."""

from __future__ import annotations

import json
import os
import stat

import numpy as np
import pytest

from lbshape.io.atomic import (
    write_atomic,
    write_bytes_atomic,
    write_json_atomic,
    write_npz_atomic,
    write_text_atomic,
)


@pytest.fixture
def umask_027():
    old = os.umask(0o027)
    yield 0o027
    os.umask(old)


def _mode(path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_every_writer_gives_the_umask_mode_not_the_private_one(tmp_path, umask_027):
    expected = 0o666 & ~umask_027
    paths = [
        write_bytes_atomic(tmp_path / "a" / "b.bin", b"\x00\x01"),
        write_text_atomic(tmp_path / "t.md", "é\n"),
        write_json_atomic(tmp_path / "j.json", {"k": [1, 2]}),
        write_npz_atomic(tmp_path / "s.npz", x=np.arange(3.0)),
        write_atomic(tmp_path / "c.txt", lambda tmp: tmp.write_text("by callback")),
    ]
    assert [oct(_mode(p)) for p in paths] == [oct(expected)] * len(paths)
    assert paths[0].read_bytes() == b"\x00\x01"
    assert paths[1].read_text(encoding="utf-8") == "é\n"
    assert json.loads(paths[2].read_text()) == {"k": [1, 2]}
    with np.load(paths[3]) as data:
        np.testing.assert_array_equal(data["x"], np.arange(3.0))
    assert paths[4].read_text() == "by callback"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "c.txt", "j.json", "s.npz", "t.md"]


def test_failed_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    path = write_text_atomic(tmp_path / "out.txt", "old")

    def fail(tmp):
        tmp.write_text("half")
        raise RuntimeError("writer broke")

    with pytest.raises(RuntimeError, match="writer broke"):
        write_atomic(path, fail)
    assert path.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]


def test_temporary_keeps_the_suffix_for_format_detection(tmp_path):
    seen = []
    write_atomic(tmp_path / "frame.vtu", lambda tmp: seen.append(tmp) or tmp.write_text("x"))
    assert seen[0].suffix == ".vtu" and seen[0].parent == tmp_path
