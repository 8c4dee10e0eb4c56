"""The artifact cache: keys, atomic writes, validation of corrupt or stale files."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest

from lbshape.errors import LbshapeError
from lbshape.io.cache import (
    artifact_path,
    cache_key,
    load_artifact,
    pack_arrays,
    read_npz,
    save_artifact,
    unpack_arrays,
)


def test_key_depends_on_every_part():
    a = np.arange(6.0)
    base = cache_key({"m": 10, "material": {"young": 1e5}}, a, b"mesh-bytes")
    assert base == cache_key({"material": {"young": 1e5}, "m": 10}, a.copy(), b"mesh-bytes")
    assert base != cache_key({"m": 11, "material": {"young": 1e5}}, a, b"mesh-bytes")
    assert base != cache_key({"m": 10, "material": {"young": 1e5}}, a + 1e-12, b"mesh-bytes")
    assert base != cache_key({"m": 10, "material": {"young": 1e5}}, a, b"mesh-byteS")


def test_round_trip_and_validation(tmp_path, caplog):
    key = cache_key("scene", 1)
    arrays = {"U": np.eye(3), "weights": np.array([1.0, 2.0])}
    path = save_artifact("demo", key, arrays, {"stage_seconds": {"modes": 0.5}}, root=tmp_path)
    loaded, meta = load_artifact("demo", key, required=["U"], root=tmp_path)
    np.testing.assert_array_equal(loaded["U"], np.eye(3))
    assert meta["stage_seconds"] == {"modes": 0.5}
    assert not list(tmp_path.glob("*.tmp"))  # nothing half-written is left behind

    # a different key is a different file: absent
    assert load_artifact("demo", cache_key("scene", 2), root=tmp_path) is None
    # missing required arrays -> stale
    assert load_artifact("demo", key, required=["T"], root=tmp_path) is None
    assert "lacks" in caplog.text
    # a corrupt file -> stale, with a reason
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    assert load_artifact("demo", key, root=tmp_path) is None
    assert "unreadable" in caplog.text


def test_non_finite_arrays_are_rejected(tmp_path):
    key = cache_key("nan")
    save_artifact("x", key, {"U": np.array([1.0, np.nan])}, root=tmp_path)
    assert load_artifact("x", key, root=tmp_path) is None
    assert artifact_path("x", key, tmp_path).exists()


def test_packed_arrays_round_trip_with_their_shapes_and_kinds(tmp_path):
    """pack_arrays → save → load → unpack_arrays gives every array back (values, shapes,
    float and bool dtypes); integers shrink to int32 only where every value fits."""
    rng = np.random.default_rng(0)
    arrays = {"a": rng.standard_normal((3, 4)), "idx": np.arange(7, dtype=np.int64),
              "keep": np.array([True, False, True]), "scalar": np.array(2.5),
              "empty": np.zeros((0, 3))}
    packed = pack_arrays(arrays)
    assert set(packed) == {"floats", "integers", "layout"}
    assert packed["integers"].dtype == np.int32
    save_artifact("packed", "k", arrays=packed, root=tmp_path)
    loaded, _ = load_artifact("packed", "k", root=tmp_path)
    back = unpack_arrays(loaded)
    assert set(back) == set(arrays)
    for name, value in arrays.items():
        np.testing.assert_array_equal(back[name], value)
        assert back[name].shape == value.shape
    assert back["keep"].dtype == bool and back["a"].dtype == float
    wide = pack_arrays({"big": np.array([0, 2**40])})
    assert wide["integers"].dtype == np.int64
    assert unpack_arrays(wide)["big"][1] == 2**40
    with pytest.raises(LbshapeError, match="'name'"):
        pack_arrays({"name": np.array(["text"])})


def test_read_npz_equals_numpy_load_and_refuses_what_it_cannot_read(tmp_path):
    """read_npz gives every member as numpy.load does (values, dtypes, shapes, Fortran
    order, 0-d strings, empty arrays), writable and aligned; a compressed, object-holding
    or truncated file is refused."""
    rng = np.random.default_rng(1)
    arrays = {"a": rng.standard_normal((5, 7)), "f": np.asfortranarray(rng.random((4, 3))),
              "i": np.arange(11, dtype=np.int32), "b": np.array([True, False]),
              "meta": np.array('{"key": "x"}'), "empty": np.zeros((0, 3)),
              "c": rng.random(3).astype(np.float32)}
    path = tmp_path / "a.npz"
    np.savez(path, **arrays)
    read = read_npz(path)
    with np.load(path) as reference:
        assert set(read) == set(reference.files)
        for name in reference.files:
            np.testing.assert_array_equal(read[name], reference[name])
            assert read[name].dtype == reference[name].dtype
            assert read[name].shape == reference[name].shape
            assert read[name].flags.writeable and read[name].flags.aligned
    assert read["f"].flags.f_contiguous
    read["a"][0, 0] = 1e9  # a copy: the file is unchanged
    assert np.load(path)["a"][0, 0] != 1e9

    np.savez_compressed(tmp_path / "z.npz", a=np.ones(3))
    with pytest.raises(ValueError, match="compressed"):
        read_npz(tmp_path / "z.npz")
    np.savez(tmp_path / "o.npz", o=np.array([{"x": 1}], dtype=object))
    with pytest.raises(ValueError, match="objects"):
        read_npz(tmp_path / "o.npz")
    data = path.read_bytes()
    (tmp_path / "t.npz").write_bytes(data[: len(data) - 40])
    with pytest.raises((ValueError, zipfile.BadZipFile)):
        read_npz(tmp_path / "t.npz")
