"""The health group of a trend: honest sigma from the design's stored calibration, unobservable
parameters as nulls, and the change since the engine's baseline (``?health=change``), each
compared with the same arithmetic done by hand on the stored numbers."""

from __future__ import annotations

from dataclasses import replace
from datetime import datetime, timedelta

import numpy as np
from fastapi.testclient import TestClient
from sqlalchemy.orm import Session

from app.models import Installation
from app.services.designs import calibration
from app.services.fleet import maintenance
from app.services.trends import health as health_view
from app.services.trends import service as trends
from estimation.uncertainty import Calibration
from tests.app.services.trends.test_trends import (
    LAYOUT,
    T0,
    add_aircraft,
    add_engine,
    add_estimates,
    as_stored,
    make_fleet,
)

N = 200
SHOP_AT = 120  # the record a shop visit comes before
CALIB = Calibration(
    names=("hpc_eff", "hpc_flow", "fan_eff"),
    level_std=np.array([0.5, 0.3, 2.0]), change_std=np.array([0.2, 0.1, 1.0]),
    slope_error=np.array([0.1, -0.2, 2.5]), bias2=np.array([0.04, 0.09, 1.0]),
    drift=np.array([0.05, -0.1, 0.3]), observable=np.array([True, True, False]),
    bias_scale=np.array([1.0, 0.5, 1.0]), source={"design": "test"},
)


def _setup(session: Session, calibrated: bool = True):  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(7)
    fleet = make_fleet(session, "Health Air")
    engine, aircraft = add_engine(session, fleet, "H1"), add_aircraft(session, fleet, "F-HHHH")
    values = rng.normal(size=(N, LAYOUT.width))
    s = LAYOUT.slices()
    values[:, s["h_sigma"]] = np.abs(values[:, s["h_sigma"]]) + 0.1
    times = [T0 + timedelta(hours=6 * i) for i in range(N)]
    add_estimates(session, fleet, engine, aircraft, values, times)
    session.add(Installation(operator_id=fleet.operator_id, engine_id=engine.id,
                             aircraft_id=aircraft.id, position=1, installed_at=T0))
    session.flush()
    maintenance.record_action(
        session, operator_id=fleet.operator_id, engine_id=engine.id, kind="shop_visit",
        performed_at=times[SHOP_AT] - timedelta(hours=1),
    )
    # A water wash does not move the baseline.
    maintenance.record_action(
        session, operator_id=fleet.operator_id, engine_id=engine.id, kind="water_wash",
        performed_at=times[90] - timedelta(hours=1),
    )
    fleet.design.result = {"format": "fleethealth.design/1"}
    session.flush()
    if calibrated:
        calibration.store_calibration(session, fleet.design, CALIB)
    stored = as_stored(values)
    return fleet, engine, stored, times


def _group(trend: dict) -> dict:
    return next(g for g in trend["groups"] if g["key"] == "health")


def _column(group: dict, name: str, key: str) -> np.ndarray:
    series = next(s for s in group["series"] if s["name"] == name)
    return np.array([np.nan if v is None else v for v in series[key]], float)


def test_calibrated_design_gives_the_honest_sigma_and_hides_unobservable(
    client: TestClient, session: Session
) -> None:
    fleet, engine, stored, _times = _setup(session)
    r = client.get(f"/api/v1/engines/{engine.id}/trend", params={"max_points": 0},
                   headers={"X-API-Key": fleet.key})
    assert r.status_code == 200, r.text
    group = _group(r.json())
    assert group["view"] == "level" and group["uncertainty"] == "calibrated"
    assert group["unobservable"] == ["fan_eff"]
    s = LAYOUT.slices()
    for j, name in enumerate(LAYOUT.health[:2]):
        f = stored[:, s["h_sigma"]][:, j]
        scale = np.asarray(CALIB.bias_scale)[j]
        honest = np.sqrt(scale**2 * CALIB.bias2[j] + f**2 + CALIB.level_std[j] ** 2)
        np.testing.assert_allclose(_column(group, name, "sigma"), honest, atol=2e-4)
        np.testing.assert_allclose(_column(group, name, "value"), stored[:, s["h"]][:, j],
                                   atol=2e-4)
        assert np.all(_column(group, name, "sigma") > f)
    assert np.all(np.isnan(_column(group, "fan_eff", "value")))
    assert np.all(np.isnan(_column(group, "fan_eff", "sigma")))


def test_uncalibrated_design_keeps_the_filter_sigma(session: Session) -> None:
    fleet, engine, stored, _times = _setup(session, calibrated=False)
    trend = trends.engine_trend(session, fleet.operator_id, engine.id, max_points=0)
    group = _group(trend)
    assert group["uncertainty"] == "uncalibrated" and group["unobservable"] == []
    s = LAYOUT.slices()
    for j, name in enumerate(LAYOUT.health):
        np.testing.assert_allclose(_column(group, name, "sigma"), stored[:, s["h_sigma"]][:, j],
                                   atol=6e-5)


def test_change_view_is_level_minus_the_baseline_level(
    client: TestClient, session: Session
) -> None:
    fleet, engine, stored, times = _setup(session)
    r = client.get(f"/api/v1/engines/{engine.id}/trend",
                   params={"max_points": 0, "health": "change"},
                   headers={"X-API-Key": fleet.key})
    assert r.status_code == 200, r.text
    group = _group(r.json())
    settle = health_view.BASELINE_SETTLE_RECORDS
    bases = (settle, SHOP_AT + settle)  # the installation's piece, then the shop visit's
    assert group["view"] == "change"
    assert [datetime.fromisoformat(t.replace("Z", "+00:00")) for t in group["baselines"]] == [
        times[b] for b in bases]
    s = LAYOUT.slices()
    h, f = stored[:, s["h"]], stored[:, s["h_sigma"]]
    takeoffs = np.cumsum(np.arange(N) % 2 == 0)  # the stored phases alternate from take-off
    for j, name in enumerate(LAYOUT.health[:2]):
        value = _column(group, name, "value")
        sigma = _column(group, name, "sigma")
        for lo, hi, b in ((0, SHOP_AT, bases[0]), (SHOP_AT, N, bases[1])):
            assert np.all(np.isnan(value[lo:b]))
            np.testing.assert_allclose(value[b:hi], h[b:hi, j] - h[b, j], atol=2e-4)
            c = (takeoffs[b:hi] - takeoffs[b]) / 1000.0
            expected = np.sqrt(f[b:hi, j] ** 2 + f[b, j] ** 2 + (CALIB.drift[j] * c) ** 2
                               + CALIB.change_std[j] ** 2)
            np.testing.assert_allclose(sigma[b:hi], expected, atol=2e-4)
    assert np.all(np.isnan(_column(group, "fan_eff", "value")))


def test_change_view_keeps_its_baseline_before_the_time_range(session: Session) -> None:
    fleet, engine, stored, times = _setup(session)
    full = trends.engine_trend(session, fleet.operator_id, engine.id, max_points=0,
                               health="change")
    part = trends.engine_trend(session, fleet.operator_id, engine.id, max_points=0,
                               health="change", start=times[100])
    assert part["n_records"] == N - 100
    np.testing.assert_allclose(_column(_group(part), "hpc_eff", "value"),
                               _column(_group(full), "hpc_eff", "value")[100:], atol=1e-9)


def test_a_bad_health_view_is_422(client: TestClient, session: Session) -> None:
    fleet, engine, _stored, _times = _setup(session)
    r = client.get(f"/api/v1/engines/{engine.id}/trend", params={"health": "delta"},
                   headers={"X-API-Key": fleet.key})
    assert r.status_code == 422, r.text
    assert "health" in r.text


def test_baseline_index_by_hand() -> None:
    epoch = np.arange(10.0)
    # Resets at 3.0 and 8.5: pieces [0..2], [3..8], [9]; settle 2.
    b = health_view.baseline_index(epoch, np.array([3.0, 8.5]), 2)
    assert b.tolist() == [-1, -1, 2, -1, -1, 5, 5, 5, 5, -1]
    assert health_view.baseline_index(epoch, np.array([]), 0).tolist() == [0] * 10


# A calibrated level (``uncertainty.Calibration.level``), in another order than the layout's:
# the correction's rows and columns follow the calibration's names.
CORRECTED = Calibration(
    names=("fan_eff", "hpc_eff", "hpc_flow"),
    level_std=np.array([2.0, 0.1, 0.2]), change_std=np.array([1.0, 0.05, 0.0]),
    slope_error=np.zeros(3), bias2=np.array([1.0, 0.04, 0.09]), drift=np.array([0.3, 0.02, 0.0]),
    observable=np.array([False, True, True]), bias_scale=np.array([1.0, 1.0, 0.0]),
    # Columns: 1, the three estimates, their products (fan_eff^2, fan_eff hpc_eff, fan_eff
    # hpc_flow, hpc_eff^2, hpc_eff hpc_flow, hpc_flow^2); hpc_eff's correction is curved.
    level_correction=np.array([[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
                               [0.3, 0.1, -0.2, 0.05, 0.0, 0.0, 0.0, 0.0, 0.01, 0.02],
                               [-0.1, 0.0, 0.4, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]]),
    level_spread=np.array([0.0, 0.05, 0.02]), filter_scale=np.array([1.0, 1.0, 0.5]),
    change_scale=np.array([1.0, 0.7, 0.6]), source={"design": "test"},
)


def test_calibrated_level_and_change_are_the_corrected_estimates(
    client: TestClient, session: Session
) -> None:
    fleet, engine, stored, _times = _setup(session, calibrated=False)
    calibration.store_calibration(session, fleet.design, CORRECTED)
    s = LAYOUT.slices()
    h, f = stored[:, s["h"]], stored[:, s["h_sigma"]]  # layout: hpc_eff, hpc_flow, fan_eff
    by_name = {n: h[:, j] for j, n in enumerate(LAYOUT.health)}
    d = np.sqrt(np.mean(h**2, axis=1))
    level = client.get(f"/api/v1/engines/{engine.id}/trend", params={"max_points": 0},
                       headers={"X-API-Key": fleet.key})
    change = client.get(f"/api/v1/engines/{engine.id}/trend",
                        params={"max_points": 0, "health": "change"},
                        headers={"X-API-Key": fleet.key})
    assert level.status_code == 200 and change.status_code == 200, level.text + change.text
    base = health_view.BASELINE_SETTLE_RECORDS  # the installation's piece
    takeoffs = np.cumsum(np.arange(N) % 2 == 0)
    c = (takeoffs[base:SHOP_AT] - takeoffs[base]) / 1000.0
    for j, name in enumerate(LAYOUT.health[:2]):
        k = CORRECTED.names.index(name)
        row = CORRECTED.level_correction[k]

        def fitted_of(v: dict[str, np.ndarray], row: np.ndarray = row) -> np.ndarray:
            names = CORRECTED.names
            pairs = zip(*np.triu_indices(3), strict=True)
            return (row[0] + sum(row[1 + i] * v[n] for i, n in enumerate(names))
                    + sum(row[4 + m] * v[names[a]] * v[names[b]]
                          for m, (a, b) in enumerate(pairs)))

        fitted = fitted_of(by_name)
        np.testing.assert_allclose(_column(_group(level.json()), name, "value"),
                                   h[:, j] - fitted, atol=5e-4)
        sigma = np.sqrt(CORRECTED.bias_scale[k] ** 2 * CORRECTED.bias2[k]
                        + (CORRECTED.filter_scale[k] * f[:, j]) ** 2
                        + CORRECTED.level_std[k] ** 2 + (CORRECTED.level_spread[k] * d) ** 2)
        np.testing.assert_allclose(_column(_group(level.json()), name, "sigma"), sigma,
                                   atol=5e-4)
        # The change: the calibrated level's change (the correction's constant cancels).
        now = {n: v[base:SHOP_AT] for n, v in by_name.items()}
        then = {n: np.full(SHOP_AT - base, v[base]) for n, v in by_name.items()}
        expected = (now[name] - fitted_of(now)) - (then[name] - fitted_of(then))
        np.testing.assert_allclose(_column(_group(change.json()), name, "value")[base:SHOP_AT],
                                   expected, atol=5e-4)
        g = CORRECTED.change_scale[k]
        d_sigma = np.sqrt((g * f[base:SHOP_AT, j]) ** 2 + (g * f[base, j]) ** 2
                          + (CORRECTED.drift[k] * c) ** 2 + CORRECTED.change_std[k] ** 2)
        np.testing.assert_allclose(_column(_group(change.json()), name, "sigma")[base:SHOP_AT],
                                   d_sigma, atol=5e-4)
    assert np.all(np.isnan(_column(_group(level.json()), "fan_eff", "value")))


def test_tuners_are_the_calibrated_level_along_their_directions(
    client: TestClient, session: Session
) -> None:
    """With a calibration holding the tuners' correction V* C (in its own order of tuners and
    of health names), the tuners group serves q - X (V* C)^T with the honest sigma, names the
    tuners it shows calibrated, and serves the one it finds unobservable as nulls, named."""
    V = np.array([[0.0, 1.0, 0.0], [0.6, 0.0, 0.8]])  # rows q2, q1 over fan_eff, hpc_eff, hpc_flow
    C = np.asarray(CORRECTED.level_correction)
    calib = replace(CORRECTED, tuner_names=("q2", "q1"), tuner_std=np.array([0.3, 0.1]),
                    tuner_scale=np.array([0.5, 1.0]), tuner_spread=np.array([0.1, 0.0]),
                    tuner_correction=V @ C, tuner_observable=np.array([True, False]))
    fleet, engine, stored, _times = _setup(session, calibrated=False)
    calibration.store_calibration(session, fleet.design, calib)
    s = LAYOUT.slices()
    h, q, qs = stored[:, s["h"]], stored[:, s["q"]], stored[:, s["q_sigma"]]
    v = {n: h[:, j] for j, n in enumerate(LAYOUT.health)}
    names = CORRECTED.names
    row = (V @ C)[0]
    fitted = (row[0] + sum(row[1 + i] * v[n] for i, n in enumerate(names))
              + sum(row[4 + m] * v[names[a]] * v[names[b]]
                    for m, (a, b) in enumerate(zip(*np.triu_indices(3), strict=True))))
    r = client.get(f"/api/v1/engines/{engine.id}/trend", params={"max_points": 0},
                   headers={"X-API-Key": fleet.key})
    assert r.status_code == 200, r.text
    group = next(g for g in r.json()["groups"] if g["key"] == "tuners")
    assert group["uncertainty"] == "calibrated"
    assert group["unobservable"] == ["q1"] and group["calibrated_series"] == ["q2"]
    q2 = LAYOUT.tuners.index("q2")
    np.testing.assert_allclose(_column(group, "q2", "value"), q[:, q2] - fitted, atol=5e-4)
    d = np.sqrt(np.mean(h**2, axis=1))
    np.testing.assert_allclose(_column(group, "q2", "sigma"),
                               np.sqrt((0.5 * qs[:, q2]) ** 2 + 0.3**2 + (0.1 * d) ** 2),
                               atol=5e-4)
    assert np.all(np.isnan(_column(group, "q1", "value")))
    assert np.all(np.isnan(_column(group, "q1", "sigma")))
