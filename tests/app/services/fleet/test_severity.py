"""Severity from the engine type's limits and the active events: ranking, reasons, counts after
an event is acknowledged or closed, and the limits' validation through the engine-types API."""

from __future__ import annotations

from datetime import timedelta

import numpy as np
from fastapi.testclient import TestClient
from sqlalchemy.orm import Session

from app.models import EngineType
from app.models.designs import LIMIT_SPECS
from app.models.estimates import Event
from app.schemas.estimates import FleetStatus
from app.services.fleet import severity
from tests.app.services.trends.test_trends import (
    LAYOUT,
    T0,
    add_aircraft,
    add_engine,
    add_estimates,
    make_fleet,
)


def _engine_with(session: Session, fleet, aircraft, esn: str, thrust_deficit: float,  # type: ignore[no-untyped-def]
                 health: float = 0.5):
    engine = add_engine(session, fleet, esn)
    v = np.zeros((5, LAYOUT.width))
    s = LAYOUT.slices()
    v[:, s["h"]] = health
    v[:, s["h_sigma"]] = 0.1
    v[:, s["z"].start] = -thrust_deficit  # LAYOUT.aux[0] is Fn
    add_estimates(session, fleet, engine, aircraft, v, [T0 + timedelta(days=i) for i in range(5)])
    return engine


def test_a_large_thrust_deficit_ranks_above_a_small_one(
    client: TestClient, session: Session
) -> None:
    fleet = make_fleet(session, "Rank Air")
    aircraft = add_aircraft(session, fleet, "F-RANK")
    _engine_with(session, fleet, aircraft, "A-small", 3.0)
    _engine_with(session, fleet, aircraft, "B-large", 17.6)
    _engine_with(session, fleet, aircraft, "C-amber", 6.0)
    session.commit()
    body = client.get("/api/v1/fleet/status", headers={"X-API-Key": fleet.key}).json()
    FleetStatus.model_validate(body)  # the documented response shape
    order = [e["esn"] for e in body["engines"]]
    assert order == ["B-large", "C-amber", "A-small"]
    by = {e["esn"]: e for e in body["engines"]}
    assert [by[k]["rank"] for k in order] == [1, 2, 3]
    assert (by["B-large"]["severity"], by["B-large"]["state"]) == ("red", "alert")
    assert by["B-large"]["reason"] == "thrust deficit 17.6 % > red 10 %"
    assert (by["C-amber"]["severity"], by["C-amber"]["state"]) == ("amber", "watch")
    assert (by["A-small"]["severity"], by["A-small"]["state"], by["A-small"]["reason"]) == (
        "normal", "normal", None)
    # Score: (17.6 - 5) / (10 - 5), the exceedance past amber in units of the amber-red span.
    assert abs(by["B-large"]["severity_score"] - 2.52) < 1e-3
    check = next(c for c in by["A-small"]["checks"] if c["limit"] == "thrust_deficit")
    assert (check["level"], check["amber"], check["red"]) == ("normal", 5.0, 10.0)


def test_within_a_level_the_score_orders_and_margins_count_downwards() -> None:
    limits = EngineType().effective_limits
    low = severity.severity(limits, {"egt_margin": severity.LimitValue(8.0)})
    assert low.level == "amber" and low.reason == "EGT margin 8.0 °C < amber 25 °C"
    assert abs(low.score - (25.0 - 8.0) / 25.0) < 1e-12
    gone = severity.severity(limits, {"egt_margin": severity.LimitValue(-3.0)})
    assert gone.level == "red" and gone.score > low.score
    ok = severity.severity(limits, {"egt_margin": severity.LimitValue(80.0)})
    assert ok.level == "normal" and ok.reason is None


def test_state_follows_events_when_acknowledged_and_closed(
    client: TestClient, session: Session
) -> None:
    fleet = make_fleet(session, "Ack Air")
    aircraft = add_aircraft(session, fleet, "F-ACK")
    engine = _engine_with(session, fleet, aircraft, "E1", 1.0)
    event = Event(operator_id=fleet.operator_id, engine_id=engine.id, design_id=fleet.design.id,
                  seq=3, detected_at=T0 + timedelta(days=3), kind="isolated_fault", fault="HPC",
                  magnitude=1.0, statistic=40.0, wssr={}, shift={})
    session.add(event)
    session.commit()
    headers = {"X-API-Key": fleet.key}

    def status() -> tuple[str, int, str | None]:
        body = client.get("/api/v1/fleet/status", headers=headers).json()
        item = body["engines"][0]
        active = client.get("/api/v1/events", params={"status": "active"},
                            headers=headers).json()["total"]
        assert active == body["n_open_events"] == item["open_events"]
        return item["state"], active, item["reason"]

    assert status() == ("alert", 1, f"open event #{event.id}: isolated fault HPC")
    assert client.post(f"/api/v1/events/{event.id}/ack", json={"reason": "seen"},
                       headers=headers).status_code == 200
    assert status() == ("alert", 1, f"acknowledged event #{event.id}: isolated fault HPC")
    assert client.post(f"/api/v1/events/{event.id}/close", json={"reason": "washed"},
                       headers=headers).status_code == 200
    assert status() == ("normal", 0, None)


def test_limits_are_validated_and_stored_per_engine_type(
    client: TestClient, session: Session
) -> None:
    fleet = make_fleet(session, "Limits Air")
    session.commit()
    headers = {"X-API-Key": fleet.key}
    url = f"/api/v1/engine-types/{fleet.engine_type.id}"
    got = client.get(url, headers=headers).json()["limits"]
    assert got["egt_margin"] == {"unit": "degC", "worse": "below", "amber": 25.0, "red": 0.0}
    assert set(got) == {*LIMIT_SPECS, "egt_redline_c"}

    bad = [
        ({"thrust_deficit": {"amber": 12, "red": 10}}, "limits.thrust_deficit.amber"),
        ({"egt_margin": {"amber": 5, "red": 10}}, "limits.egt_margin.amber"),
        ({"egt_margin": {"amber": 20, "red": 5, "unit": "degF"}}, "limits.egt_margin.unit"),
        ({"oil_pressure": {"amber": 1, "red": 2}}, "oil_pressure"),
        ({"health_change": {"amber": 1}}, "red"),
        ({"egt_redline_c": -5}, "egt_redline_c"),
    ]
    for limits, field in bad:
        r = client.patch(url, json={"limits": limits}, headers=headers)
        assert r.status_code == 422, (limits, r.text)
        assert field in r.text, (field, r.text)
    session.expire_all()
    assert session.get(EngineType, fleet.engine_type.id).limits is None  # type: ignore[union-attr]

    r = client.patch(url, json={"limits": {"thrust_deficit": {"amber": 2, "red": 3, "unit": "%"},
                                           "egt_redline_c": 1000}}, headers=headers)
    assert r.status_code == 200, r.text
    assert r.json()["limits"]["thrust_deficit"]["amber"] == 2.0
    # A second change keeps the first.
    r = client.patch(url, json={"limits": {"egt_margin": {"amber": 30, "red": 10}}},
                     headers=headers)
    limits = r.json()["limits"]
    assert limits["thrust_deficit"]["red"] == 3.0 and limits["egt_margin"]["amber"] == 30.0
    assert limits["egt_redline_c"] == 1000.0

    # The fleet status judges with the stored levels: 4 % is red now.
    aircraft = add_aircraft(session, fleet, "F-LIM")
    _engine_with(session, fleet, aircraft, "L1", 4.0)
    session.commit()
    body = client.get("/api/v1/fleet/status", headers=headers).json()
    assert body["engines"][0]["reason"] == "thrust deficit 4.0 % > red 3 %"
