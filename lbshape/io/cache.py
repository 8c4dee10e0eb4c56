"""A content-addressed, validated cache of precomputed arrays.

An artifact is a set of named numpy arrays plus JSON metadata, stored as one
``.npz`` (arrays + an embedded ``__meta__`` JSON string) under
``<root>/<name>-<key[:16]>.npz``. The key is a SHA-256 over everything that
determines the artifact (see :func:`cache_key`). Writes are atomic (temporary file
in the same folder, then rename). Loading validates the file: unreadable, wrong
key, missing arrays or non-finite values -> the artifact is reported stale
(``None``) with a logged reason, and the caller recomputes.

Concurrent jobs (processes) share the cache: :func:`artifact_lock` is an exclusive
``fcntl`` lock on ``<name>-<key[:16]>.lock`` beside the artifact, held while one job
checks for the artifact and computes it, so a second job on the same artifact waits
and then loads it instead of computing it again. A lock file exists only while its lock
is held: the holder deletes it before unlocking, whether the block succeeded or raised,
and a job that acquired the lock of a file meanwhile deleted (or replaced) re-opens the
path and locks again, so the lock stays exclusive. The kernel releases a lock when its
process ends; a lock file left by a killed process (stale: nobody holds it) is deleted
by the next :func:`artifact_lock` in the same cache (:func:`remove_stale_locks`).

Stage entries (:func:`save_stage`, :func:`load_stage`): one stage's result under its own
key in ``<root>/stages/<name>-<key[:16]>.pkl`` — a header line, then a pickle of (key,
result) read back by an unpickler that admits only the classes of lbshape, numpy and
scipy.sparse and plain containers; a foreign, truncated or differently keyed file is
reported stale and recomputed, never run.

Artifacts are read by :func:`read_npz` (one file read, no per-member CRC pass). Many
arrays read together can be packed into three (:func:`pack_arrays`, the floats, the
integers and their layout): an ``.npz`` member costs a fixed time to read, which dominates
for many small arrays.

The root is ``$LBSHAPE_CACHE`` if set, else ``~/.cache/lbshape``.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import io
import json
import logging
import os
import pickle
import struct
import zipfile
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path

import numpy as np

from lbshape.errors import LbshapeError
from lbshape.io.atomic import write_bytes_atomic, write_npz_atomic

log = logging.getLogger(__name__)

FORMAT_VERSION = 1


def cache_root() -> Path:
    """The cache folder (created on demand)."""
    root = os.environ.get("LBSHAPE_CACHE")
    return Path(root) if root else Path.home() / ".cache" / "lbshape"


def _canonical(value):
    if isinstance(value, Mapping):
        return {str(k): _canonical(v) for k, v in sorted(value.items(), key=lambda kv: str(kv[0]))}
    if isinstance(value, list | tuple):
        return [_canonical(v) for v in value]
    if isinstance(value, np.ndarray):
        return {"__array__": hashlib.sha256(np.ascontiguousarray(value).tobytes()).hexdigest(),
                "shape": list(value.shape), "dtype": str(value.dtype)}
    if isinstance(value, bytes):
        return {"__bytes__": hashlib.sha256(value).hexdigest()}
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, float | int | str | bool) or value is None:
        return value
    raise TypeError(f"cannot hash value of type {type(value).__name__} for the cache key")


def cache_key(*parts) -> str:
    """SHA-256 hex digest of JSON-canonical ``parts`` (dicts, lists, numbers, strings,
    bytes and numpy arrays; arrays and bytes enter through their own digests)."""
    text = json.dumps([FORMAT_VERSION, _canonical(list(parts))], sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def file_digest(path: str | Path) -> str:
    """SHA-256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def artifact_path(name: str, key: str, root: Path | None = None) -> Path:
    return (root or cache_root()) / f"{name}-{key[:16]}.npz"


def _lock_file(path: Path, *, wait: bool):
    """An open handle on ``path`` holding its exclusive ``fcntl`` lock, or ``None`` if
    ``wait`` is False and another process holds it (or ``path`` is gone).

    Locks the file, then checks that ``path`` still names the locked file (its holder
    may have deleted it meanwhile); otherwise opens ``path`` again (creating it when
    ``wait``) and retries.
    """
    while True:
        try:
            handle = open(path, "a+b" if wait else "r+b")  # noqa: SIM115 -- returned or closed
        except FileNotFoundError:
            if not wait:
                return None
            raise
        try:
            fcntl.flock(handle.fileno(), fcntl.LOCK_EX if wait else fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.close()
            return None
        except BaseException:
            handle.close()
            raise
        try:
            same = os.path.samestat(os.fstat(handle.fileno()), os.stat(path))
        except FileNotFoundError:
            same = False
        if same:
            return handle
        handle.close()  # locked a deleted file: its holder is done with it
        if not wait:
            return None


def _unlink_and_unlock(path: Path, handle) -> None:
    """Delete the lock file ``path`` (still locked through ``handle``), then unlock it."""
    with handle:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


def remove_stale_locks(root: Path | None = None) -> list[Path]:
    """Delete the lock files of ``root`` (default: the cache root) that nobody holds.

    Such a file was left by a process that ended without deleting it (killed). Each
    is locked first (without waiting; held ones are skipped), so no running job's lock
    file is deleted. Returns the deleted paths.
    """
    removed = []
    root = root or cache_root()
    for path in sorted(root.glob("*.lock")) if root.is_dir() else ():
        with contextlib.suppress(OSError):
            handle = _lock_file(path, wait=False)
            if handle is not None:
                _unlink_and_unlock(path, handle)
                removed.append(path)
    if removed:
        log.info("cache: removed %d stale lock file(s) in %s", len(removed), root)
    return removed


@contextlib.contextmanager
def artifact_lock(name: str, key: str, *, root: Path | None = None) -> Iterator[Path]:
    """Hold the exclusive inter-process lock of one artifact for the block.

    Blocks until no other process holds it. Yields the lock file's path
    (``<root>/<name>-<key[:16]>.lock``, created with its folder if needed); the file
    is deleted when the block ends, normally or by an exception. Stale lock files of
    the cache are deleted first (:func:`remove_stale_locks`).

    Raises:
        LbshapeError: the cache folder cannot be created or written.
    """
    path = artifact_path(name, key, root).with_suffix(".lock")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        remove_stale_locks(path.parent)
        handle = _lock_file(path, wait=True)
    except OSError as exc:
        raise LbshapeError(f"cannot use the cache folder {path.parent}: "
                           f"{exc.strerror or exc}") from None
    try:
        yield path
    finally:
        _unlink_and_unlock(path, handle)


def save_artifact(
    name: str, key: str, arrays: Mapping[str, np.ndarray], meta: Mapping | None = None,
    *, root: Path | None = None,
) -> Path:
    """Write arrays + metadata atomically; return the path."""
    payload = {"key": key, "format": FORMAT_VERSION, "arrays": sorted(arrays), **(meta or {})}
    return write_npz_atomic(artifact_path(name, key, root),
                            __meta__=np.array(json.dumps(payload)), **arrays)


#: a zip member's local header: signature and fixed part (the name and extra field follow)
_LOCAL_HEADER = struct.Struct("<IHHHHHIIIHH")
_LOCAL_SIGNATURE = 0x04034B50
#: the ``.npy`` header readers by format version
_HEADER_READERS = {(1, 0): np.lib.format.read_array_header_1_0,
                   (2, 0): np.lib.format.read_array_header_2_0}


def read_npz(path: str | Path) -> dict[str, np.ndarray]:
    """Every array of an uncompressed ``.npz`` (as :func:`numpy.savez` writes it), read
    with one file read: each member's ``.npy`` header is parsed in place and its data
    copied out (aligned, writable). :func:`numpy.load` pays a fixed time per member and a
    CRC pass over every byte; a precompute artifact holds 30-80 members.

    Raises:
        zipfile.BadZipFile: not a zip file; ValueError: a compressed member, an object
        array, or a member that runs past the end of the file (truncated).
    """
    data = Path(path).read_bytes()
    out: dict[str, np.ndarray] = {}
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        for info in archive.infolist():
            if info.compress_type != zipfile.ZIP_STORED:
                raise ValueError(f"member {info.filename} is compressed")
            fields = _LOCAL_HEADER.unpack_from(data, info.header_offset)
            if fields[0] != _LOCAL_SIGNATURE:
                raise ValueError(f"member {info.filename} has no local header")
            start = info.header_offset + _LOCAL_HEADER.size + fields[9] + fields[10]
            end = start + info.file_size
            if end > len(data):
                raise ValueError(f"member {info.filename} runs past the end of the file")
            member = io.BytesIO(data[start:min(end, start + 65536)])
            version = np.lib.format.read_magic(member)
            if version not in _HEADER_READERS:
                raise ValueError(f"member {info.filename}: .npy format {version} not read")
            shape, fortran, dtype = _HEADER_READERS[version](member)
            if dtype.hasobject:
                raise ValueError(f"member {info.filename} holds objects")
            count = int(np.prod(shape, dtype=np.int64))
            if start + member.tell() + count * dtype.itemsize > end:
                raise ValueError(f"member {info.filename} is shorter than its header says")
            values = np.frombuffer(data, dtype=dtype, count=count, offset=start + member.tell())
            name = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
            out[name] = values.reshape(shape, order="F" if fortran else "C").copy(
                order="F" if fortran else "C")
    return out


def load_artifact(
    name: str, key: str, *, required: Iterable[str] = (), root: Path | None = None
) -> tuple[dict[str, np.ndarray], dict] | None:
    """Load and validate an artifact; ``None`` (with a logged reason) if absent or stale."""
    path = artifact_path(name, key, root)
    if not path.exists():
        return None
    try:
        arrays = read_npz(path)
        meta = json.loads(str(arrays.pop("__meta__")))
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, json.JSONDecodeError) as exc:
        log.warning("cache: %s is unreadable (%s); recomputing", path.name, exc)
        return None
    reason = None
    if meta.get("key") != key or meta.get("format") != FORMAT_VERSION:
        reason = "its key does not match"
    elif missing := [k for k in required if k not in arrays]:
        reason = f"it lacks {missing}"
    else:
        bad = [k for k, v in arrays.items() if v.dtype.kind == "f" and not np.isfinite(v).all()]
        if bad:
            reason = f"{bad} hold non-finite values"
    if reason:
        log.warning("cache: %s is stale or corrupt (%s); recomputing", path.name, reason)
        return None
    return arrays, meta


# ------------------------------------------------------------------ stage entries
#: a stage entry's first bytes: what a foreign or older file lacks
STAGE_MAGIC = b"lbshape-stage-1\n"
#: the modules whose classes a stage entry may hold (plus :data:`_SAFE_GLOBALS`)
_STAGE_MODULES = ("lbshape.", "numpy", "scipy.sparse")
_SAFE_GLOBALS = {("copyreg", "_reconstructor"), ("collections", "OrderedDict"),
                 *(("builtins", name) for name in ("tuple", "list", "dict", "set", "frozenset",
                                                   "complex", "float", "int", "str", "bytes",
                                                   "bytearray", "slice", "range", "object",
                                                   "bool"))}
_NUMPY_FUNCTIONS = {"_reconstruct", "scalar", "_frombuffer"}


def stage_path(name: str, key: str, root: Path | None = None) -> Path:
    """The file of one stage's entry: ``<root>/stages/<name>-<key[:16]>.pkl``."""
    return (root or cache_root()) / "stages" / f"{name}-{key[:16]}.pkl"


class _StageUnpickler(pickle.Unpickler):
    """Unpickles only the classes of lbshape, numpy and scipy.sparse and plain
    containers: a foreign file cannot call anything else."""

    def find_class(self, module: str, name: str):
        value = super().find_class(module, name)
        if (module, name) in _SAFE_GLOBALS:
            return value
        if module.split(".")[0] in ("numpy",) and name in _NUMPY_FUNCTIONS:
            return value
        if isinstance(value, type) and (module + ".").startswith(_STAGE_MODULES):
            return value
        raise pickle.UnpicklingError(f"{module}.{name} is not allowed in a stage entry")


def save_stage(name: str, key: str, value, *, root: Path | None = None) -> Path | None:
    """Write one stage's result atomically under its key; ``None`` (logged) if it
    cannot be stored (the stage is then simply not cached)."""
    try:
        payload = pickle.dumps((key, value), protocol=pickle.HIGHEST_PROTOCOL)
        return write_bytes_atomic(stage_path(name, key, root), STAGE_MAGIC + payload)
    except (OSError, pickle.PicklingError, TypeError, AttributeError, LbshapeError) as exc:
        log.info("cache: stage %s not stored (%s)", name, exc)
        return None


def load_stage(name: str, key: str, *, root: Path | None = None):
    """(True, value) of a stored stage entry, or (False, None) if absent, foreign,
    unreadable or keyed otherwise (logged; the caller recomputes — never raises)."""
    path = stage_path(name, key, root)
    if not path.exists():
        return False, None
    try:
        data = path.read_bytes()
        if not data.startswith(STAGE_MAGIC):
            raise ValueError("not a stage entry")
        stored, value = _StageUnpickler(io.BytesIO(data[len(STAGE_MAGIC):])).load()
        if stored != key:
            raise ValueError("its key does not match")
    except Exception as exc:  # noqa: BLE001 -- any unreadable entry means: recompute
        log.warning("cache: %s is stale or unreadable (%s); recomputing", path.name, exc)
        return False, None
    return True, value


#: the names of :func:`pack_arrays`'s three arrays
PACKED = ("floats", "integers", "layout")


def pack_arrays(arrays: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Named float, integer and bool arrays as three: ``floats`` (every float array,
    float64, raveled and concatenated), ``integers`` (every integer and bool array, int32
    where every value fits, else int64) and ``layout`` (a JSON string: each name's kind,
    dtype, shape and offset). :func:`unpack_arrays` is the inverse.

    Raises:
        LbshapeError: an array of another kind (strings, objects, complex).
    """
    layout, floats, integers = [], [], []
    offsets = {"f": 0, "i": 0}
    for name, value in arrays.items():
        value = np.asarray(value)
        kind = "f" if value.dtype.kind == "f" else "i" if value.dtype.kind in "iub" else None
        if kind is None:
            raise LbshapeError(f"cannot pack array {name!r} of dtype {value.dtype}")
        layout.append([name, kind, value.dtype.str, list(value.shape), offsets[kind]])
        offsets[kind] += value.size
        (floats if kind == "f" else integers).append(value.ravel())
    ints = np.concatenate(integers).astype(np.int64) if integers else np.zeros(0, np.int64)
    if ints.size == 0 or (ints.min() >= np.iinfo(np.int32).min
                          and ints.max() <= np.iinfo(np.int32).max):
        ints = ints.astype(np.int32)
    return {"floats": np.concatenate(floats).astype(float) if floats else np.zeros(0),
            "integers": ints, "layout": np.array(json.dumps(layout))}


def unpack_arrays(packed: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Inverse of :func:`pack_arrays`: the named arrays with their shapes and dtypes,
    except that integer arrays keep the packed width (int32 or int64); float and integer
    arrays are views of the packed ones."""
    sources = {"f": np.asarray(packed["floats"]), "i": np.asarray(packed["integers"])}
    out = {}
    for name, kind, dtype, shape, offset in json.loads(str(packed["layout"])):
        size = int(np.prod(shape, dtype=np.int64))
        values = sources[kind][offset:offset + size].reshape(shape)
        if kind == "f" or np.dtype(dtype).kind == "b":  # integers keep the packed width
            values = values.astype(dtype, copy=False)
        out[name] = values
    return out
