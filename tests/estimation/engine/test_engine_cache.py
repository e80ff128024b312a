"""The application's disk cache of the engine schedule."""

import json

import numpy as np
import pytest

import app.engine_cache as cache

AXES = {"alt": (0.0, 10000.0), "mach": (0.0,), "power": (80.0, 100.0)}


def test_builds_once_then_reads(tmp_path, monkeypatch):
    first = cache.engine_schedule(tmp_path, AXES)
    path = cache.cache_path(tmp_path, AXES)
    assert path.exists()

    def no_build(*a, **k):
        raise AssertionError("schedule rebuilt although cached")

    monkeypatch.setattr(cache, "build_schedule", no_build)
    second = cache.engine_schedule(tmp_path, AXES)
    for k, v in first.values.items():
        assert np.array_equal(second.values[k], v)


def test_other_grid_other_file(tmp_path):
    assert cache.cache_path(tmp_path, AXES) != cache.cache_path(
        tmp_path, {**AXES, "power": (90.0, 100.0)})


def test_damaged_or_foreign_cache_is_rebuilt(tmp_path):
    path = cache.cache_path(tmp_path, AXES)
    path.write_text("{not json", encoding="utf-8")
    assert cache.load_schedule(path) is None
    sched = cache.engine_schedule(tmp_path, AXES)
    d = json.loads(path.read_text(encoding="utf-8"))
    assert d["fingerprint"] == sched.fingerprint
    d["fingerprint"] = "another-design"
    path.write_text(json.dumps(d), encoding="utf-8")
    assert cache.load_schedule(path) is None


def test_unknown_axis_refused(tmp_path):
    with pytest.raises(ValueError):
        cache.cache_path(tmp_path, {"altitude": (0.0,)})


TRIM_AXES = {"alt": (0.0, 5000.0), "mach": (0.0, 0.1), "dtamb": (-10.0, 10.0),
             "power": (90.0, 100.0)}


def test_trim_table_builds_once_then_reads(tmp_path, monkeypatch):
    first = cache.engine_trim_table(tmp_path, TRIM_AXES)
    path = cache.trim_table_path(tmp_path, TRIM_AXES)
    assert path.exists()
    assert path != cache.trim_table_path(tmp_path, {**TRIM_AXES, "power": (80.0, 100.0)})

    def no_build(*a, **k):
        raise AssertionError("trim table rebuilt although cached")

    monkeypatch.setattr(cache, "build_trim_table", no_build)
    second = cache.engine_trim_table(tmp_path, TRIM_AXES)
    assert np.array_equal(second.corrected, first.corrected)
    assert all(np.array_equal(a, b) for a, b in zip(second.axes, first.axes, strict=True))


def test_damaged_trim_table_is_rebuilt(tmp_path):
    path = cache.trim_table_path(tmp_path, TRIM_AXES)
    path.write_bytes(b"not an npz file")
    assert cache.load_trim_table(path, TRIM_AXES) is None
    table = cache.engine_trim_table(tmp_path, TRIM_AXES)
    assert cache.load_trim_table(path, TRIM_AXES) is not None
    # A file holding another grid under this name is not used.
    other = cache.trim_table_path(tmp_path, {**TRIM_AXES, "power": (80.0, 100.0)})
    path.rename(other)
    assert cache.load_trim_table(other, {**TRIM_AXES, "power": (80.0, 100.0)}) is None
    assert table.corrected.shape == (2, 2, 2, 2, len(table.names))


def test_detector_arrays_built_once_per_key_then_read(tmp_path):
    calls = []

    def build(scale):
        def run():
            calls.append(scale)
            return {"table": scale * np.arange(4.0), "level": scale}
        return run

    first = cache.arrays(tmp_path, "bank", {"n": 3, "scale": 1.5}, build(1.5))
    again = cache.arrays(tmp_path, "bank", {"scale": 1.5, "n": 3}, build(99.0))
    other = cache.arrays(tmp_path, "bank", {"n": 3, "scale": 2.0}, build(2.0))
    assert calls == [1.5, 2.0]  # the same key (in any order) is read, not built again
    assert np.array_equal(again["table"], first["table"]) and float(again["level"]) == 1.5
    assert float(other["level"]) == 2.0


def test_damaged_detector_arrays_are_rebuilt(tmp_path):
    cache.arrays(tmp_path, "cusum", {"m": 6}, lambda: {"threshold": 14.7})
    (path,) = tmp_path.glob("cusum-*.npz")
    path.write_bytes(b"not a zip file")
    rebuilt = cache.arrays(tmp_path, "cusum", {"m": 6}, lambda: {"threshold": 14.8})
    assert float(rebuilt["threshold"]) == 14.8
    assert float(cache.arrays(tmp_path, "cusum", {"m": 6}, lambda: {})["threshold"]) == 14.8
