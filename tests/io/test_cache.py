"""The artifact cache: keys, atomic writes, validation of corrupt or stale files."""

from __future__ import annotations

import numpy as np

from lbshape.io.cache import artifact_path, cache_key, load_artifact, save_artifact


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
