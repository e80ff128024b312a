"""The stored form of snapshot estimates (``EstimateLayout.encode``) against the float32 numbers
the pipeline computes, on the built-in engine's demo design over a simulated fleet with faults,
washes and swaps: every value within 1/15 of its 1-sigma, every sigma within 3.2 %, residuals
within 0.02 % + 3.9 %, WSSRs within 3.3 %, missing numbers missing, phases kept."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from app.models.estimates import EstimateLayout
from app.services.demo import fleet
from app.services.snapshots import run as snapshots_run
from app.services.snapshots.estimator import SnapshotEstimator
from app.signals import PHASES
from estimation.engine.fleet import fleet_snapshots, plan_fleet
from estimation.engine.schedule import build_schedule
from tests.support import detection_replay


@pytest.fixture(scope="module")
def estimator() -> SnapshotEstimator:
    # Two nodes per axis keep the test fast; the service uses the full default grid.
    schedule = build_schedule({"alt": (0.0, 40000.0), "mach": (0.0, 0.85),
                               "power": (40.0, 100.0)})
    return fleet.design_estimator(schedule, *fleet.ACTIVE_DESIGN)


@pytest.fixture(scope="module")
def computed(estimator: SnapshotEstimator) -> tuple[np.ndarray, np.ndarray]:
    """(values [n, width] float32 as computed, phase indices [n]) of a small fleet."""
    size = fleet.DemoSize(aircraft=2, flights=300, fault_rate=1.0 / 60.0)
    plan_rng, snap_rng = np.random.default_rng(23).spawn(2)
    plan = plan_fleet(fleet.fleet_config(size), plan_rng)
    engines = detection_replay.engine_runs(plan, fleet_snapshots(plan, snap_rng), estimator)
    outputs = snapshots_run.run_filters(estimator, [e.run for e in engines])
    values = np.concatenate([o.packed for o in outputs]).astype(np.float64)
    phase = np.concatenate([[PHASES.index(p) for p in e.run.phase] for e in engines])
    return values, phase


def _check(layout: EstimateLayout, values: np.ndarray, phase: np.ndarray) -> None:
    stored = layout.encode(values, phase)
    assert stored.shape == (len(values), layout.stored_bytes)
    decoded = layout.decode(stored.tobytes(), len(values))
    np.testing.assert_array_equal(decoded.phase, phase)
    got, s = decoded.values, layout.slices()
    for block in ("q", "h", "z"):
        sigma = values[:, s[block + "_sigma"]]
        if block == "h" and layout.health_from_tuners is not None:
            # h = V*^+ q: each tuner's error (1/16 of its sigma) through V*^+.
            sigma = values[:, s["q_sigma"]] @ np.abs(np.array(layout.health_from_tuners)).T
        error = np.abs(got[:, s[block]] - values[:, s[block]]) / sigma
        assert np.nanmax(error) < 1 / 15, block
    for block in ("q_sigma", "h_sigma", "z_sigma"):
        assert np.nanmax(np.abs(got[:, s[block]] / values[:, s[block]] - 1)) < 0.032, block
    residual = values[:, s["residual"]]
    assert np.all(np.abs(got[:, s["residual"]] - residual) <= 0.02 + 0.039 * np.abs(residual))
    wssr, back = values[:, s["wssr"]], got[:, s["wssr"]]
    np.testing.assert_array_equal(np.isnan(back), np.isnan(wssr))
    assert np.isnan(wssr).any() and np.isfinite(wssr).any()
    assert np.nanmax(np.abs(back / wssr - 1)) < 0.033


def test_the_demo_design_stores_59_bytes_within_a_fraction_of_each_sigma(
    estimator: SnapshotEstimator, computed: tuple[np.ndarray, np.ndarray]
) -> None:
    layout = estimator.layout
    assert layout.width == 71 and layout.stored_bytes == 59  # float32: 284 bytes
    values, phase = computed
    assert len(values) > 2000
    # The errors are much smaller than the bands: the health change of a record moves by
    # less than 1/15 of its 1-sigma.
    _check(layout, values, phase)


def test_health_not_derivable_from_the_tuners_is_stored(
    estimator: SnapshotEstimator, computed: tuple[np.ndarray, np.ndarray]
) -> None:
    """A design whose V*^+ mixes tuners derives h but stores its sigma; a layout without V*^+
    stores both, and each keeps the same precision."""
    values, phase = computed
    mixed = np.eye(10) + 0.1 * np.ones((10, 10))
    derived = replace(estimator.layout, health_from_tuners=tuple(map(tuple, mixed)))
    s = derived.slices()
    mixing = values.copy()
    mixing[:, s["h"]] = values[:, s["q"]] @ mixed.T
    assert derived.stored_bytes == 59 + 10
    _check(derived, mixing, phase)
    plain = replace(estimator.layout, health_from_tuners=None)
    assert plain.stored_bytes == 59 + 10 + 15
    _check(plain, values, phase)


def test_values_far_beyond_their_sigma_widen_the_band_instead_of_clipping() -> None:
    layout = EstimateLayout(tuners=("q1",), health=("h1",), aux=("Fn",), sensors=("T30",),
                            faults=("HPC",), health_from_tuners=((1.0,),))
    values = np.array([[30.0, 0.01, 30.0, 0.01, -17.6, 0.0, np.nan, 0.0]])
    got = layout.decode(layout.encode(values, np.array([2]))).values[0]
    assert got[0] == pytest.approx(30.0, rel=1e-3) and got[4] == pytest.approx(-17.6, rel=1e-3)
    assert 0.01 < got[1] < 30.0 / 200 and np.isnan(got[6])
    assert got[7] == pytest.approx(0.01)  # WSSR below its range: its lower end
