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
