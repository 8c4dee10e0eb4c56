"""Atomic file output: write to a temporary file in the same folder, then rename.

Every file lbshape writes goes through :func:`atomic_path`, so a reader never sees
a half-written file and a failure leaves the previous file (if any) untouched and
no temporary behind. The temporary sits next to the target (same file system, so
``os.replace`` is atomic), is hidden (``.<name>.<random>.tmp<suffix>``) and keeps
the target's suffix, for libraries that choose the format from the file name
(gmsh, VTK, matplotlib). Parent folders are created. Written files get the usual
mode ``0o666 & ~umask``, not the private ``0o600`` of :func:`tempfile.mkstemp`.

* :func:`write_bytes_atomic`, :func:`write_text_atomic`, :func:`write_json_atomic`,
  :func:`write_npz_atomic` — content held in memory;
* :func:`write_atomic` — a callback that writes a path (another library's writer,
  e.g. ``lambda tmp: plotter.screenshot(tmp)``);
* :func:`atomic_path` — the same as a context manager.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np


def _umask() -> int:
    """The process umask, read without changing it where Linux allows (no race with threads)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    umask = os.umask(0o022)
    os.umask(umask)
    return umask


def default_file_mode() -> int:
    """``0o666 & ~umask``: the mode ``open()`` gives a new file in this process."""
    return 0o666 & ~_umask()


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path`` that replaces ``path`` when the block succeeds.

    The block writes the temporary (it exists, empty, on entry). On normal exit it
    is renamed onto ``path``; if the block or the rename raises, it is removed and
    the exception propagates.

    Args:
        path: the file to (re)write; its folder is created if needed.

    Yields:
        The temporary file's path.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=f".tmp{path.suffix}",
                                dir=path.parent)
    os.close(fd)
    tmp = Path(name)
    try:
        os.chmod(tmp, default_file_mode())
        yield tmp
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def write_atomic(path: str | Path, write: Callable[[Path], object]) -> Path:
    """Call ``write(tmp)`` to produce the file at a temporary path, then rename it to ``path``.

    For files made by other libraries (meshio, gmsh, VTK, matplotlib); see
    :func:`atomic_path`. Returns ``path``.
    """
    with atomic_path(path) as tmp:
        write(tmp)
    return Path(path)


def write_bytes_atomic(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; create parent folders. Returns ``path``."""
    return write_atomic(path, lambda tmp: tmp.write_bytes(data))


def write_text_atomic(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; create parent folders."""
    return write_bytes_atomic(path, text.encode())


def write_json_atomic(path: str | Path, payload: dict) -> Path:
    """Write ``payload`` as indented JSON to ``path`` atomically."""
    return write_text_atomic(path, json.dumps(payload, indent=2) + "\n")


def write_npz_atomic(path: str | Path, **arrays: np.ndarray) -> Path:
    """Write named arrays as an uncompressed ``.npz`` (:func:`numpy.savez`) atomically.

    The file name is kept as given (numpy appends ``.npz`` only to names it opens itself).
    """

    def save(tmp: Path) -> None:
        with open(tmp, "wb") as handle:
            np.savez(handle, **arrays)

    return write_atomic(path, save)
