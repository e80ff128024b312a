"""Shared helpers of the benchmark scripts: import path, timing, the test model."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


def best_time(fn: Callable[[], object], repeat: int = 3) -> float:
    """Best wall time of ``repeat`` calls, seconds (the least disturbed run)."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def reference_design(extra_sensors: int = 0, m: int = 6):
    """The seed-002-like reference model of the tests and an SVD-tuner filter on it."""
    from estimation import tuners
    from tests.estimation.models import reference_model, reference_noise

    model = reference_model(extra_sensors=extra_sensors)
    noise = reference_noise(model)
    return model, noise, tuners.svd_tuners(model, m, noise["Q"], noise["Qh"], noise["Ph"])
