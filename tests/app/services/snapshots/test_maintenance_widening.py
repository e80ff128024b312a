"""What a maintenance action does to the filter: it widens the covariance by what the action
can move the health by (``estimator.RESET_STD``): a shop visit up to the fleet's spread, a
water wash well under a percent, so that a wash does not make the filter forget the engine."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from app.services.snapshots import estimator, run
from tests.app.services.snapshots.test_wear_events import _steady_fleet


def test_a_wash_widens_less_than_a_shop_visit_and_moves_the_estimates_less() -> None:
    est, runs = _steady_fleet(1, 240, seed=7)
    base = runs[0]
    at = float(base.epoch[120]) - 60.0  # just before record 120
    s = est.layout.slices()

    def filtered(std: list[float] | None) -> np.ndarray:
        engine = replace(base, maintenance=np.array([at]),
                         maintenance_std=None if std is None else np.array(std))
        return run.run_filters(est, [engine])[0].packed.astype(np.float64)

    wash = filtered([estimator.RESET_STD["water_wash"]])
    shop = filtered([estimator.RESET_STD["shop_visit"]])
    default = filtered(None)
    # No kind given: the fleet's spread, as before kinds were told apart.
    np.testing.assert_array_equal(default, shop)
    # Before the action the same filter; at it, the 1-sigma widened by the action's size.
    np.testing.assert_array_equal(wash[:120], shop[:120])
    sigma_wash, sigma_shop = wash[120, s["h_sigma"]], shop[120, s["h_sigma"]]
    before = wash[119, s["h_sigma"]]
    assert np.all(sigma_wash > before) and np.all(sigma_shop > 1.3 * sigma_wash)
    # On a healthy engine (noise only) the estimates wander less after a wash.
    h = s["h"]

    def wander(values: np.ndarray) -> float:
        return float(np.sqrt(np.mean(np.square(values[120:140, h] - values[119, h]))))

    assert wander(wash) < 0.6 * wander(shop)
