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
* :func:`atomic_path` — the same as a context manager;
* :func:`atomic_folder` — a whole output folder (a run's files) written beside its
  place and renamed into it when complete, replacing the previous one;
  :func:`write_failed_folder` replaces it by a folder holding only
  :data:`FAILED_MARKER`, so a failed run never looks like a result.
  :func:`check_replaceable` refuses, before any work, a folder holding files the
  writer does not own (it is never deleted).
"""

from __future__ import annotations

import contextlib
import fnmatch
import json
import os
import secrets
import shutil
import tempfile
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

import numpy as np

from lbshape.errors import LbshapeError

#: the only file of a failed run's output folder (see :func:`write_failed_folder`)
FAILED_MARKER = "FAILED.txt"


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


def check_replaceable(folder: str | Path, owned: Iterable[str],
                      owned_folders: Iterable[str] = ()) -> Path:
    """Check that ``folder`` may be replaced as a whole by :func:`atomic_folder`.

    It may when it does not exist, or is a folder holding only files whose names match
    one of the glob patterns ``owned`` (the files its writer makes), :data:`FAILED_MARKER`
    or hidden temporaries of this module (``.*.tmp*``), and sub-folders named in
    ``owned_folders``.

    Args:
        folder: the output folder.
        owned: glob patterns of the writer's file names, e.g. ``("stats.json", "*.vtu")``.
        owned_folders: names of the sub-folders the writer makes (e.g. ``("runs",)``).

    Returns:
        ``folder`` as an absolute path.

    Raises:
        LbshapeError: ``folder`` is a file, or holds something else (left untouched).
    """
    folder = Path(os.path.abspath(folder))
    if not folder.name:
        raise LbshapeError(f"cannot use {folder} as an output folder")
    if not os.path.lexists(folder):
        return folder
    if not folder.is_dir():
        raise LbshapeError(f"output folder {folder} exists and is not a folder")
    patterns = (*owned, FAILED_MARKER, ".*.tmp*")
    folders = set(owned_folders)
    foreign = sorted(entry.name for entry in folder.iterdir()
                     if (entry.name not in folders if entry.is_dir()
                         else not any(fnmatch.fnmatchcase(entry.name, p) for p in patterns)))
    if foreign:
        raise LbshapeError(f"output folder {folder} holds other files ({', '.join(foreign[:3])}"
                           f"{', ...' if len(foreign) > 3 else ''}); choose a new or empty "
                           f"folder")
    return folder


@contextlib.contextmanager
def atomic_folder(folder: str | Path, owned: Iterable[str],
                  owned_folders: Iterable[str] = ()) -> Iterator[Path]:
    """A temporary folder beside ``folder`` that replaces ``folder`` when the block succeeds.

    The block writes its files into the temporary (hidden: ``.<name>.<random>.tmp``,
    same file system). On normal exit the previous ``folder`` (checked by
    :func:`check_replaceable` first) is moved aside, the temporary renamed into its
    place and the previous one deleted, so ``folder`` never mixes two runs' files. If
    the block raises, the temporary is removed, ``folder`` is left as it was, and the
    exception propagates.

    Args:
        folder: the output folder (its parent is created).
        owned: glob patterns of the files the writer makes (see :func:`check_replaceable`).
        owned_folders: names of the sub-folders the writer makes.

    Yields:
        The temporary folder's path.
    """
    owned, owned_folders = tuple(owned), tuple(owned_folders)
    folder = check_replaceable(folder, owned, owned_folders)
    folder.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", suffix=".tmp", dir=folder.parent))
    try:
        os.chmod(tmp, 0o777 & ~_umask())
        yield tmp
        check_replaceable(folder, owned, owned_folders)  # nothing foreign arrived meanwhile
        old = folder.with_name(f".{folder.name}.{secrets.token_hex(4)}.old")
        if os.path.lexists(folder):
            os.rename(folder, old)
        try:
            os.rename(tmp, folder)
        except OSError:
            if os.path.lexists(old):
                os.rename(old, folder)
            raise
        if old.is_symlink():
            old.unlink()
        else:
            shutil.rmtree(old, ignore_errors=True)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def write_failed_folder(folder: str | Path, text: str, owned: Iterable[str]) -> Path:
    """Replace ``folder`` by a folder holding only :data:`FAILED_MARKER` with ``text``.

    For a run that stopped: whatever the folder held before (an earlier result) is
    gone, and nothing in it can be mistaken for a result. See :func:`atomic_folder`.
    Returns the marker's path.
    """
    with atomic_folder(folder, owned) as tmp:
        (tmp / FAILED_MARKER).write_text(text if text.endswith("\n") else text + "\n")
    return Path(os.path.abspath(folder)) / FAILED_MARKER
