"""Physical bounds per quantity in stored units: a value no engine reaches is refused, naming
row, column and reason, for snapshots and stream samples alike; nothing is stored."""

from __future__ import annotations

import json

import pytest
from fastapi.testclient import TestClient
from sqlalchemy.orm import Session

from app.services.uploads.parse import QUANTITY_BOUNDS, parse_json, signal_bounds
from app.signals import SIGNALS
from tests.app.services.uploads.test_parse import records, rejected
from tests.support.fleet_fixture import Fleet, counts, make_fleet


def test_every_stored_signal_has_finite_bounds_from_its_quantity() -> None:
    for signal in SIGNALS:
        low, high = signal_bounds(signal)
        assert low is not None and high is not None, signal.name
        assert low < high
        q_low, q_high = QUANTITY_BOUNDS[(signal.quantity, signal.unit)]
        assert q_low <= low and high <= q_high  # a signal's own range only narrows


@pytest.mark.parametrize(
    ("column", "value", "bound"),
    [("T30", 1e308, "10000 degR"), ("P30", 1e6, "2000 psia"), ("Nf", 1e9, "60000 rpm"),
     ("Wf", 1e4, "100 pps"), ("T30", -1.0, "0 degR")],
)
def test_snapshot_value_beyond_the_physical_bound_is_refused(
    column: str, value: float, bound: str
) -> None:
    rows = records()
    rows[4][column] = value
    details = rejected(parse_json, json.dumps({"snapshots": rows}).encode())
    assert [(d["row"], d["column"]) for d in details] == [(5, column)]
    assert bound in details[0]["reason"]


def test_declared_unit_is_converted_before_the_bound() -> None:
    # 5400 degC is 10211.67 degR: beyond the temperature bound once converted (and under it
    # if the unit were ignored).
    rows = records()
    for row in rows:
        row["T30[degC]"] = row.pop("T30") / 1.8 - 273.15
    parse_json(json.dumps({"snapshots": rows}).encode())  # in range: accepted
    rows[0]["T30[degC]"] = 5400.0
    details = rejected(parse_json, json.dumps({"snapshots": rows}).encode())
    assert [(d["row"], d["column"]) for d in details] == [(1, "T30[degC]")]


def test_upload_with_an_absurd_temperature_stores_nothing(
    client: TestClient, session: Session
) -> None:
    fleet: Fleet = make_fleet(session)
    rows = records()
    for row in rows:
        row["tail"] = "N101"
    rows[1]["T30"] = 1e308
    before = counts(session, fleet.operator_id)
    response = client.post("/api/v1/snapshots", json={"snapshots": rows}, headers=fleet.analyst)
    assert response.status_code == 422, response.text
    detail = response.json()["error"]["details"][0]
    assert (detail["row"], detail["column"]) == (2, "T30") and "above" in detail["reason"]
    assert counts(session, fleet.operator_id) == before
