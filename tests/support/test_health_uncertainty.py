"""The honest health uncertainty against the fleet simulator's truth (reduced, seeded).

The model-error term is calibrated (``health_uncertainty.calibrate``) on one small simulated
fleet and scored on another seed with the product's own filter; thresholds are the issue's
acceptance figures where a small fleet can show them: every parameter's honest 1-sigma holds the
truth more often than the filter's own, the shown parameters' 1-sigma in at least 55 % and
their 2-sigma in at least 85 % of the records, and the change since the baseline has an RMS error of
at most 0.5 % over the shown parameters. The accuracy of the fleet-average slopes needs the
bench's larger fleets; here, a slope is a number only where the calibration can vouch for it
(an observable parameter with a gain) and is reported as unobservable elsewhere.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.services.demo import fleet
from estimation.engine.fleet import FleetPlan, Snapshots, fleet_snapshots, plan_fleet
from estimation.engine.schedule import EngineSchedule, build_schedule
from estimation.uncertainty import Calibration
from tests.support import health_uncertainty

SIZE = fleet.DemoSize(aircraft=3, flights=400)


@pytest.fixture(scope="module")
def schedule() -> EngineSchedule:
    return build_schedule()


def _fleet(seed: int) -> tuple[FleetPlan, Snapshots]:
    plan_rng, snap_rng = np.random.default_rng(seed).spawn(2)
    plan = plan_fleet(fleet.fleet_config(SIZE), plan_rng)
    return plan, fleet_snapshots(plan, snap_rng)


def test_calibrated_uncertainty_on_an_independent_seed(schedule: EngineSchedule) -> None:
    est = fleet.design_estimator(schedule, "svd", 6)
    plan, snaps = _fleet(11)
    calib = health_uncertainty.calibrate(est, plan, snaps, design="svd:6", seed=11)
    # Stored with the design as JSON and read back unchanged.
    calib = Calibration.from_dict(json.loads(json.dumps(calib.to_dict())))
    plan, snaps = _fleet(12)
    sc = health_uncertainty.score(est, calib, plan, snaps)
    assert sc.records > 1000
    assert np.all(sc.cover1 > sc.filter_cover1), sc.report()
    shown = sc.observable
    assert shown.any(), sc.report()
    assert np.all(sc.cover1[shown] >= 0.55), sc.report()
    assert np.all(sc.cover2[shown] >= 0.85), sc.report()
    assert np.sqrt(np.mean(sc.change_rms[shown] ** 2)) <= 0.5, sc.report()
    # Slopes: every engine trend of the fleet measured, a number only where shown.
    assert sc.pieces >= 4 and np.all(np.isfinite(sc.slope_true)), sc.report()
    assert not np.any(sc.slope_shown & ~shown), sc.report()
    assert np.all(np.isfinite(sc.slope_hat) == sc.slope_shown), sc.report()
    assert sc.report().count("unobservable") == int((~sc.slope_shown).sum())
