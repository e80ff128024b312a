"""Fleet status and deterioration: every engine with its current installation, the latest
estimate decoded, open events; fleet averages equal a direct per-engine-then-fleet mean."""

from __future__ import annotations

from dataclasses import replace
from datetime import UTC, datetime, timedelta

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy.orm import Session

from app.models import EngineType, Installation, MaintenanceAction
from app.models.estimates import Event
from app.services.fleet import slopes, status
from app.services.fleet.severity import LimitValue, severity
from estimation.uncertainty import YEAR_S, Calibration, correct_level, spread
from tests.app.services.trends.test_trends import (
    LAYOUT,
    T0,
    add_aircraft,
    add_engine,
    add_estimates,
    as_stored,
    make_fleet,
)


def test_status_lists_every_engine_with_its_latest_state(
    client: TestClient, session: Session
) -> None:
    fleet = make_fleet(session, "Status Air")
    aircraft = add_aircraft(session, fleet, "F-STAT")
    rng = np.random.default_rng(5)
    engines = [add_engine(session, fleet, f"S{i}") for i in range(3)]
    session.add(Installation(operator_id=fleet.operator_id, engine_id=engines[0].id,
                             aircraft_id=aircraft.id, position=2, installed_at=T0))
    values = {}
    for engine in engines[:2]:
        v = rng.normal(size=(30, LAYOUT.width))
        v[:, LAYOUT.slices()["h_sigma"]] = 0.1
        values[engine.id] = v
        add_estimates(session, fleet, engine, aircraft, v,
                      [T0 + timedelta(days=i) for i in range(30)])
    session.add(Event(operator_id=fleet.operator_id, engine_id=engines[1].id,
                      design_id=fleet.design.id, seq=20, detected_at=T0 + timedelta(days=20),
                      kind="isolated_fault", fault="HPC", magnitude=1.0, statistic=40.0,
                      wssr={}, shift={}))
    session.commit()

    body = client.get("/api/v1/fleet/status", headers={"X-API-Key": fleet.key}).json()
    by_esn = {e["esn"]: e for e in body["engines"]}
    assert set(by_esn) == {"S0", "S1", "S2"} and body["n_open_events"] == 1
    assert (by_esn["S0"]["tail"], by_esn["S0"]["position"]) == ("F-STAT", 2)
    assert by_esn["S1"]["tail"] is None and by_esn["S2"]["state"] == "no_data"
    assert by_esn["S1"]["state"] == "alert" and by_esn["S1"]["latest_event"]["fault"] == "HPC"
    h = LAYOUT.slices()["h"]
    last = as_stored(values[engines[0].id])[-1]
    worst = int(np.argmax(np.abs(last[h])))
    health = by_esn["S0"]["health"]
    assert health["worst_health"] == LAYOUT.health[worst]
    assert abs(health["worst_health_value"] - last[h][worst]) < 1e-3
    assert abs(health["thrust_deficit"] + last[LAYOUT.slices()["z"]][0]) < 1e-3  # Fn first

    # A page at a time, worst first, with the whole fleet's counts per state.
    states = body["states"]
    assert sum(states.values()) == body["n_engines"] == body["total"] == 3
    assert states["alert"] == 1 and states["no_data"] == 1
    ranked = [e["esn"] for e in body["engines"]]
    pages = [client.get("/api/v1/fleet/status", params={"limit": 2, "offset": o},
                        headers={"X-API-Key": fleet.key}).json() for o in (0, 2)]
    assert [e["esn"] for p in pages for e in p["engines"]] == ranked
    assert [len(p["engines"]) for p in pages] == [2, 1]
    assert all(p["total"] == 3 and p["states"] == states for p in pages)
    only = client.get("/api/v1/fleet/status", params={"state": "no_data"},
                      headers={"X-API-Key": fleet.key}).json()
    assert [e["esn"] for e in only["engines"]] == ["S2"] and only["total"] == 1
    for bad in ({"limit": 0}, {"limit": 100_000}, {"offset": -1}, {"state": "red"}):
        response = client.get("/api/v1/fleet/status", params=bad, headers={"X-API-Key": fleet.key})
        assert response.status_code == 422, bad
    # The default limits: health change amber 5 % red 8 %, thrust deficit amber 5 % red 10 %.
    worst_h, deficit = np.abs(last[h]).max(), -last[LAYOUT.slices()["z"]][0]
    expected = ("alert" if worst_h >= 8 or deficit >= 10
                else "watch" if worst_h >= 5 or deficit >= 5 else "normal")
    assert by_esn["S0"]["state"] == expected
    assert by_esn["S0"]["last_data"].startswith("2026-01-30")


def test_deterioration_is_the_mean_over_engines_of_engine_means(session: Session) -> None:
    fleet = make_fleet(session, "Fleet Avg Air")
    aircraft = add_aircraft(session, fleet, "F-AVG")
    rng = np.random.default_rng(6)
    start = datetime(2026, 3, 1, tzinfo=UTC)
    per_engine, per_engine_aux = [], []
    for i, n in enumerate((40, 10)):  # a busy engine must not outweigh a quiet one
        engine = add_engine(session, fleet, f"A{i}")
        v = rng.normal(size=(n, LAYOUT.width))
        times = [start + timedelta(hours=12 * k) for k in range(n)]  # March only
        add_estimates(session, fleet, engine, aircraft, v, times)
        per_engine.append(as_stored(v)[:, LAYOUT.slices()["h"]].mean(0))
        per_engine_aux.append(as_stored(v)[:, LAYOUT.slices()["z"]].mean(0))
    out = status.fleet_deterioration(session, fleet.operator_id, "month")
    group = out["groups"][0]
    assert group["time"] == ["2026-03-01T00:00:00Z"] and group["n_engines"] == [2]
    expected = np.mean(per_engine, axis=0)
    spread = np.std(per_engine, axis=0)
    got = [s["mean"][0] for s in group["health"]]
    np.testing.assert_allclose(got, expected, atol=1e-4)
    np.testing.assert_allclose([s["sigma"][0] for s in group["health"]], spread, atol=1e-4)
    assert group["unobservable"] == []
    # With a calibration that finds fan_eff unobservable: nulls, named; the rest as before.
    # The calibrated aux outputs too: SmHPC less 0.2 + 0.3 h_hpc_flow, the mean and spread
    # over engines of each engine's calibrated output at its own means.
    aux_correction = np.zeros((1, 10))
    aux_correction[0, 0] = 0.2
    aux_correction[0, 3] = 0.3  # hpc_flow's column in the calibration's order
    calib = Calibration(
        names=("fan_eff", "hpc_eff", "hpc_flow"), level_std=np.zeros(3), change_std=np.zeros(3),
        slope_error=np.zeros(3), bias2=np.zeros(3), drift=np.zeros(3),
        observable=np.array([False, True, True]), aux_names=("SmHPC",), aux_std=np.zeros(1),
        aux_correction=aux_correction,
    )
    fleet.design.result = {"uncertainty": calib.to_dict()}
    session.flush()
    group = status.fleet_deterioration(session, fleet.operator_id, "month")["groups"][0]
    h_engines = np.array(per_engine)  # layout order: hpc_eff, hpc_flow, fan_eff
    sm = np.array(per_engine_aux)[:, 1] - (0.2 + 0.3 * h_engines[:, 1])
    aux = {s["name"]: (s["mean"][0], s["sigma"][0]) for s in group["aux"]}
    assert aux["SmHPC"] == pytest.approx((sm.mean(), sm.std()), abs=1e-4)
    fn = np.array(per_engine_aux)[:, 0]  # not corrected
    assert aux["Fn"] == pytest.approx((fn.mean(), fn.std()), abs=1e-4)
    assert group["unobservable"] == ["fan_eff"]
    fan = next(s for s in group["health"] if s["name"] == "fan_eff")
    assert fan["mean"] == [None] and fan["sigma"] == [None]
    shown = [i for i, s in enumerate(group["health"]) if s["name"] != "fan_eff"]
    np.testing.assert_allclose([group["health"][i]["mean"][0] for i in shown], expected[shown],
                               atol=1e-4)


def test_deterioration_shows_the_calibrated_level_of_each_engines_mean(
    session: Session,
) -> None:
    """With a calibrated design, the fleet's health means are the calibrated level the engine
    pages show, taken on each engine's period mean (straight and curved rows alike), and the
    spread over engines is that of those levels."""
    fleet = make_fleet(session, "Fleet Level Air")
    aircraft = add_aircraft(session, fleet, "F-LVL")
    rng = np.random.default_rng(16)
    start = datetime(2026, 5, 1, tzinfo=UTC)
    means = []
    for i in range(5):
        engine = add_engine(session, fleet, f"C{i}")
        v = rng.normal(size=(20, LAYOUT.width))
        v[:, LAYOUT.slices()["h"]] += rng.normal(scale=3.0, size=3)  # engines apart
        add_estimates(session, fleet, engine, aircraft, v,
                      [start + timedelta(hours=12 * k) for k in range(20)])
        means.append(as_stored(v)[:, LAYOUT.slices()["h"]].mean(0))
    means = np.array(means)
    # Row 0 straight, row 1 curved (the estimates' products), row 2 left as estimated.
    correction = np.zeros((3, 10))
    correction[0, :4] = [0.3, 0.1, -0.05, 0.02]
    correction[1, :4] = [-0.2, 0.0, 0.08, 0.0]
    correction[1, 4:] = [0.01, -0.004, 0.002, 0.006, 0.0, -0.003]
    calib = Calibration(
        names=LAYOUT.health, level_std=np.zeros(3), change_std=np.zeros(3),
        slope_error=np.zeros(3), bias2=np.zeros(3), drift=np.zeros(3),
        observable=np.ones(3, bool), level_correction=correction,
    )
    fleet.design.result = {"uncertainty": calib.to_dict()}
    session.flush()
    group = status.fleet_deterioration(session, fleet.operator_id, "month")["groups"][0]
    assert group["level"] == "calibrated" and group["n_engines"] == [5]
    levels = correct_level(means, correction)
    got = np.array([s["mean"][0] for s in group["health"]])
    np.testing.assert_allclose(got, levels.mean(0), atol=1e-4)
    assert np.abs(got - means.mean(0)).max() > 0.1  # not the estimates' mean
    spread = np.array([s["sigma"][0] for s in group["health"]])
    # Straight rows: exact; the curved row carried through its Jacobian at the fleet mean.
    np.testing.assert_allclose(spread[[0, 2]], levels.std(0)[[0, 2]], atol=1e-4)
    np.testing.assert_allclose(spread[1], levels.std(0)[1], rtol=0.1)
    # Without a calibration: the estimates as stored.
    fleet.design.result = {}
    session.flush()
    group = status.fleet_deterioration(session, fleet.operator_id, "month")["groups"][0]
    assert group["level"] == "estimated"
    np.testing.assert_allclose([s["mean"][0] for s in group["health"]], means.mean(0), atol=1e-4)


def test_deterioration_slopes_split_at_shop_visits_calibrated_and_unobservable(
    client: TestClient, session: Session,
) -> None:
    """Each engine's weekly means between baseline resets give its trends: a shop visit's
    step does not enter the slope, the fleet's is their T^2-weighted mean; with a stored
    calibration it is divided by the gain, carries its 1-sigma (the gain's standard error
    included) in %/year over HTTP, and an unobservable parameter has no number; a calibration
    stored before the gain's standard error was gives the slope without a sigma, "recalibrate";
    a stored slope correction reads each parameter's slope from every parameter's and scales
    the sigma."""
    fleet = make_fleet(session, "Fleet Slope Air")
    aircraft = add_aircraft(session, fleet, "F-SLP")
    rng = np.random.default_rng(8)
    h = LAYOUT.slices()["h"]
    rates = np.array([[-1.0, 0.5, -0.2], [-2.0, 1.0, -0.4]])  # percent per year
    for i, rate in enumerate(rates):
        engine = add_engine(session, fleet, f"L{i}")
        days = np.arange(400 if i == 0 else 200)
        years = days * 86400.0 / YEAR_S
        v = rng.normal(size=(len(days), LAYOUT.width)) * 0.01
        v[:, h] = np.outer(years, rate) + 0.01 * rng.normal(size=(len(days), 3))
        if i == 0:  # a shop visit on day 200 restores 5 %
            v[200:, h] += 5.0
            session.add(MaintenanceAction(operator_id=fleet.operator_id, engine_id=engine.id,
                                          kind="shop_visit",
                                          performed_at=T0 + timedelta(days=199, hours=12)))
        add_estimates(session, fleet, engine, aircraft, v,
                      [T0 + timedelta(days=int(d)) for d in days])
    layout = LAYOUT
    plain = slopes.fleet_slopes(session, fleet.operator_id, fleet.design.id, layout)
    assert plain.uncertainty == "uncalibrated" and plain.engines == 2 and plain.pieces == 3
    assert not plain.unobservable and np.isnan(plain.sigma).all()
    # Spans 18 and 19 weeks (a 60-record settle, the shop visit's week left out) and 19 weeks.
    w = (np.array([18.0, 19.0, 19.0]) * 7 * 86400.0 / YEAR_S) ** 2
    expected = (w[:2].sum() * rates[0] + w[2] * rates[1]) / w.sum()
    np.testing.assert_allclose(plain.slope, expected, rtol=0.02)
    calib = Calibration(
        names=("fan_eff", "hpc_eff", "hpc_flow"), level_std=np.zeros(3), change_std=np.zeros(3),
        slope_error=np.zeros(3), bias2=np.zeros(3), drift=np.zeros(3),
        observable=np.array([False, True, True]), slope_gain=np.array([1.0, 1.25, np.nan]),
        slope_noise=np.array([0.01, 0.02, 0.02]), slope_common=np.array([0.0, 0.01, 0.0]),
        slope_gain_std=np.array([0.1, 0.15, np.nan]),
    )
    fleet.design.result = {"uncertainty": calib.to_dict()}
    session.flush()
    out = slopes.fleet_slopes(session, fleet.operator_id, fleet.design.id, layout).to_dict()
    assert out["uncertainty"] == "calibrated" and out["unit"] == "%/year"
    # fan_eff: level unobservable; hpc_flow: no gain (its trend cannot be calibrated).
    assert sorted(out["unobservable"]) == ["fan_eff", "hpc_flow"]
    got = {s["name"]: s for s in out["health"]}
    assert got["fan_eff"]["slope"] is None and got["hpc_flow"]["sigma"] is None
    np.testing.assert_allclose(got["hpc_eff"]["slope"], plain.slope[0] / 1.25, atol=1e-4)
    corrected = plain.slope[0] / 1.25
    np.testing.assert_allclose(
        got["hpc_eff"]["sigma"],
        np.sqrt((0.02 / w.sum() + 0.01) / 1.25**2 + (corrected * 0.15 / 1.25) ** 2), rtol=1e-3)
    # The fleet's slopes per active design are the same, and so is the API's answer.
    group = status.fleet_deterioration_slopes(session, fleet.operator_id)["groups"][0]
    assert group == {"engine_type": "generic", "design_id": fleet.design.id, **out}
    response = client.get("/api/v1/fleet/deterioration/slopes",
                          headers={"X-API-Key": fleet.key})
    assert response.status_code == 200
    assert response.json()["groups"] == [group]
    # Stored before the gain's standard error was calibrated: the corrected slope, no sigma.
    stale = {k: v for k, v in calib.to_dict().items() if k != "slope_gain_std"}
    fleet.design.result = {"uncertainty": stale}
    session.flush()
    before = client.get("/api/v1/fleet/deterioration/slopes",
                        headers={"X-API-Key": fleet.key}).json()["groups"][0]
    assert before["uncertainty"] == "recalibrate" and before["unit"] == "%/year"
    assert sorted(before["unobservable"]) == ["fan_eff", "hpc_flow"]
    assert all(item["sigma"] is None for item in before["health"])
    assert before["health"] == [{**item, "sigma": None} for item in out["health"]]
    # Stored before the slope correction (no A, no scale): the slopes and sigmas as above.
    older = {k: v for k, v in calib.to_dict().items()
             if k not in ("slope_correction", "slope_scale")}
    fleet.design.result = {"uncertainty": older}
    session.flush()
    assert slopes.fleet_slopes(session, fleet.operator_id, fleet.design.id,
                               layout).to_dict() == out
    # With a slope correction A (in the calibration's order): each piece's slopes read as
    # b - b A^T before the gain, so the fleet's as (I - A) of the plain fleet slope in the
    # layout's order, hpc_eff from all three; its sigma scaled by lambda. Without A (above)
    # the slopes are as before.
    A = np.array([[0.0, 0.0, 0.0], [0.3, 0.2, -0.4], [0.0, 0.1, 0.0]])
    fleet.design.result = {"uncertainty": replace(
        calib, slope_correction=A, slope_scale=np.full(3, 0.8)).to_dict()}
    session.flush()
    with_k = slopes.fleet_slopes(session, fleet.operator_id, fleet.design.id, layout)
    order = [1, 2, 0]  # the layout's hpc_eff, hpc_flow, fan_eff in the calibration
    read = plain.slope - A[np.ix_(order, order)] @ plain.slope
    assert abs(read[0] - plain.slope[0]) > 0.05  # the correction moves it
    np.testing.assert_allclose(with_k.slope[0], read[0] / 1.25, rtol=1e-9)
    np.testing.assert_allclose(
        with_k.sigma[0],
        0.8 * np.sqrt((0.02 / w.sum() + 0.01) / 1.25**2 + (read[0] / 1.25 * 0.15 / 1.25) ** 2),
        rtol=1e-9)
    assert with_k.unobservable == ("hpc_flow", "fan_eff")


def test_status_summaries_equal_the_one_engine_reference(
    client: TestClient, session: Session
) -> None:
    """The array summaries of many engines equal ``health_summary`` and the severity of each
    engine's latest estimate alone, also when a design's engines carry different layout
    documents."""
    from app.models.estimates import EstimateLayout, FilterState

    fleet = make_fleet(session, "Status Ref Air")
    aircraft = add_aircraft(session, fleet, "F-REF")
    rng = np.random.default_rng(9)
    lasts = {}
    for i in range(12):
        engine = add_engine(session, fleet, f"R{i:02d}")
        v = rng.normal(size=(4, LAYOUT.width)) * 2.0
        v[:, LAYOUT.slices()["h_sigma"]] = rng.uniform(0.05, 1.0, size=(4, len(LAYOUT.health)))
        add_estimates(session, fleet, engine, aircraft, v,
                      [T0 + timedelta(days=k, hours=i) for k in range(4)])
        lasts[engine.id] = as_stored(v)[-1]
    # One engine's layout document differs (its own health names): read for that engine.
    renamed = EstimateLayout.from_dict(
        dict(LAYOUT.to_dict(), health=[f"x_{n}" for n in LAYOUT.health])
    )
    state = session.query(FilterState).filter_by(engine_id=min(lasts)).one()
    state.layout = renamed.to_dict()
    session.commit()

    body = client.get("/api/v1/fleet/status", headers={"X-API-Key": fleet.key}).json()
    assert body["n_engines"] == 12
    for item in body["engines"]:
        layout = renamed if item["engine_id"] == min(lasts) else LAYOUT
        last = lasts[item["engine_id"]]
        expected = status.health_summary(
            layout, last, datetime.fromisoformat(item["last_data"]), 3
        )
        expected["recorded_at"] = item["last_data"]
        assert item["health"] == expected
        judged = severity(EngineType().effective_limits, {
            "health_change": LimitValue(abs(expected["worst_health_value"])),
            "thrust_deficit": LimitValue(expected["thrust_deficit"]),
        })
        assert item["severity"] == judged.level
        assert item["severity_score"] == round(judged.score, 3)


def test_status_reads_the_calibrated_level_the_engine_page_shows(
    client: TestClient, session: Session
) -> None:
    """With a calibrated design, an engine's status health is the calibrated level its trend
    shows at its latest record, an unobservable parameter is null and never the worst, and
    the severity's health change is that level's largest."""
    from app.services.designs import calibration

    fleet = make_fleet(session, "Status Calibrated Air")
    aircraft = add_aircraft(session, fleet, "F-CALS")
    engine = add_engine(session, fleet, "CALS-1")
    v = np.zeros((3, LAYOUT.width))
    s = LAYOUT.slices()
    v[:, s["h"]] = [-1.0, -2.0, -9.0]  # layout: hpc_eff, hpc_flow, fan_eff
    v[:, s["h_sigma"]] = 0.2
    v[:, s["z"]] = [-2.0, 1.0]  # Fn, SmHPC: a 2 % thrust deficit
    v[:, s["z_sigma"]] = [0.3, 0.5]
    add_estimates(session, fleet, engine, aircraft, v,
                  [T0 + timedelta(days=k) for k in range(3)])
    calib = Calibration(
        names=("hpc_eff", "hpc_flow", "fan_eff"), level_std=np.full(3, 0.1),
        change_std=np.zeros(3), slope_error=np.zeros(3), bias2=np.zeros(3),
        drift=np.zeros(3), observable=np.array([True, True, False]),
        level_correction=np.array([[0.0, 0.0, 0.0, 0.0], [-0.5, 0.0, 1.0, 0.0],
                                   [0.0, 0.0, 0.0, 0.0]]),
        aux_names=("Fn",), aux_std=np.array([0.4]),
        # The calibrated thrust: 1 + 0.5 h_hpc_eff off the estimate.
        aux_correction=np.array([[1.0, 0.5] + [0.0] * 8]),
    )
    fleet.design.result = {"format": "fleethealth.design/1"}
    calibration.store_calibration(session, fleet.design, calib)
    session.commit()
    body = client.get("/api/v1/fleet/status", headers={"X-API-Key": fleet.key}).json()
    health = body["engines"][0]["health"]
    # hpc_flow's error is -0.5 + h_hpc_flow: its calibrated level is 0.5 %; fan_eff hidden;
    # hpc_eff as stored (-1 % in the estimate's stored precision).
    hpc_eff = round(float(as_stored(v)[-1, s["h"]][0]), 4)
    assert health["health"] == {"hpc_eff": hpc_eff, "hpc_flow": 0.5, "fan_eff": None}
    assert health["worst_health"] == "hpc_eff" and health["worst_health_value"] == hpc_eff
    trend = client.get(f"/api/v1/engines/{engine.id}/trend", params={"max_points": 0},
                       headers={"X-API-Key": fleet.key}).json()
    group = next(g for g in trend["groups"] if g["key"] == "health")
    last = {series["name"]: series["value"][-1] for series in group["series"]}
    assert last == health["health"]
    reference = status.health_summary(LAYOUT, as_stored(v)[-1], T0, 2, calib)
    assert reference["health"] == health["health"]
    checks = {c["limit"]: c["value"] for c in body["engines"][0]["checks"]}
    assert checks["health_change"] == round(abs(hpc_eff), 3)  # not fan_eff's 9 %: hidden
    # Each check's 1-sigma is the engine page's: the worst parameter's honest sigma, and the
    # thrust deficit's filter sigma with the calibrated model error in quadrature.
    sigmas = {c["limit"]: c["sigma"] for c in body["engines"][0]["checks"]}
    assert sigmas["health_change"] == pytest.approx(health["worst_health_sigma"], abs=1e-3)
    z_sigma = float(as_stored(v)[-1, s["z_sigma"]][0])
    assert sigmas["thrust_deficit"] == pytest.approx(np.hypot(z_sigma, 0.4), abs=1e-3)
    aux = next(g for g in trend["groups"] if g["key"] == "aux")
    fn = next(series for series in aux["series"] if series["name"] == "Fn")
    assert fn["sigma"][-1] == pytest.approx(sigmas["thrust_deficit"], abs=1e-3)
    # The thrust the status ranks by is the calibrated one the engine page shows:
    # -2 - (1 + 0.5 (-1)) = -2.5 %, a 2.5 % deficit.
    fn_stored = float(as_stored(v)[-1, s["z"]][0])
    assert fn["value"][-1] == pytest.approx(fn_stored - (1.0 + 0.5 * hpc_eff), abs=1e-3)
    assert health["thrust_deficit"] == pytest.approx(-fn["value"][-1], abs=1e-3)
    assert health["thrust_deficit"] == pytest.approx(2.5, abs=2e-3)
    assert reference["thrust_deficit"] == health["thrust_deficit"]
    # The trend says what each band is: the aux outputs calibrated; the tuners not, by a
    # calibration stored before they were.
    states = {g["key"]: g.get("uncertainty") for g in trend["groups"]}
    assert states["health"] == states["aux"] == "calibrated"
    assert states["tuners"] == "recalibrate"


def test_rate_of_change_carries_the_calibrated_change_sigma(
    client: TestClient, session: Session
) -> None:
    """The rate of change is the largest change of the shown level over the last RATE_WINDOW
    records per 100 records; with a calibrated design it carries that change's 1-sigma (the
    calibrated change between the two records, ``Calibration.rate``), per 100 records too;
    without one, none."""
    from app.services.designs import calibration
    from estimation.uncertainty import RATE_WINDOW

    fleet = make_fleet(session, "Status Rate Air")
    aircraft = add_aircraft(session, fleet, "F-RATE")
    engine = add_engine(session, fleet, "RATE-1")
    n = RATE_WINDOW + 3
    s = LAYOUT.slices()
    v = np.zeros((n, LAYOUT.width))
    v[:, s["h"]] = np.linspace(0.0, 1.0, n)[:, None] * [-1.0, -3.0, -0.5]
    v[:, s["h_sigma"]] = np.linspace(0.4, 0.2, n)[:, None]
    add_estimates(session, fleet, engine, aircraft, v, [T0 + timedelta(days=k) for k in range(n)])
    session.commit()

    def rate_check() -> dict[str, object]:
        body = client.get("/api/v1/fleet/status", headers={"X-API-Key": fleet.key}).json()
        return next(c for c in body["engines"][0]["checks"] if c["limit"] == "rate_of_change")

    stored = as_stored(v)
    now, old = stored[-1], stored[-1 - RATE_WINDOW]
    plain = rate_check()
    assert plain["sigma"] is None  # no calibration: no honest sigma to give
    assert plain["value"] == pytest.approx(abs(now[s["h"]][1] - old[s["h"]][1]) * 100 / RATE_WINDOW,
                                           abs=2e-3)
    calib = Calibration(
        names=("hpc_eff", "hpc_flow", "fan_eff"), level_std=np.full(3, 0.1),
        change_std=np.array([0.05, 0.15, 0.1]), slope_error=np.zeros(3), bias2=np.zeros(3),
        drift=np.full(3, 0.3), observable=np.array([True, True, False]),
        change_scale=np.array([1.0, 0.5, 1.0]),
    )
    fleet.design.result = {"format": "fleethealth.design/1"}
    calibration.store_calibration(session, fleet.design, calib)
    session.commit()
    check = rate_check()
    # hpc_flow the worst change; its sigma: the change's over the window (no drift over it).
    sigma = np.sqrt(0.5**2 * (now[s["h_sigma"]][1] ** 2 + old[s["h_sigma"]][1] ** 2) + 0.15**2)
    assert check["value"] == pytest.approx(plain["value"], abs=2e-3)
    assert check["sigma"] == pytest.approx(sigma * 100 / RATE_WINDOW, abs=2e-3)
    assert "hpc_flow" in check["reason"]
    # Calibrated on the rate itself (``Calibration.rate``): the filter's sigma at both ends
    # scaled, its model error and spread with the latest record's distance from nominal.
    fitted = replace(calib, rate_std=np.array([0.01, 0.03, 0.02]),
                     rate_scale=np.array([0.8, 0.2, 1.0]), rate_spread=np.array([0.0, 0.1, 0.0]))
    calibration.store_calibration(session, fleet.design, fitted)
    session.commit()
    check = rate_check()
    both = np.hypot(now[s["h_sigma"]][1], old[s["h_sigma"]][1])
    d = float(spread(now[s["h"]][None])[0])
    sigma = np.sqrt((0.2 * both) ** 2 + 0.03**2 + (0.1 * d) ** 2)
    assert check["sigma"] == pytest.approx(sigma * 100 / RATE_WINDOW, abs=2e-3)
