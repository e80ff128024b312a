"""Data coverage: each tail's and engine's last record and the installed engines whose data
is overdue (SQLite and PostgreSQL)."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pyarrow as pa
import pyarrow.compute as pc
import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy.orm import Session

from tests.support.fleet_fixture import Fleet, csv_bytes, make_fleet, snapshot_rows

API = "/api/v1/fleet/data-coverage"


@pytest.fixture
def fleet_data(session: Session) -> Fleet:
    return make_fleet(session)


def upload(client: TestClient, fleet: Fleet, table: pa.Table) -> None:
    response = client.post("/api/v1/snapshots/file", content=csv_bytes(table),
                           headers={**fleet.analyst, "Content-Type": "text/csv"})
    assert response.status_code == 201, response.text


def newest(table: pa.Table, tail: str, position: int | None = None) -> datetime:
    mask = pc.equal(table["tail"], tail)
    if position is not None:
        mask = pc.and_(mask, pc.equal(table["position"], position))
    value: datetime = pc.max(table.filter(mask)["recorded_at"]).as_py()
    return value


def test_last_data_per_tail_and_engine_and_the_overdue_engines(
    app: FastAPI, client: TestClient, fleet_data: Fleet
) -> None:
    now = datetime.now(UTC).replace(microsecond=0)
    old = snapshot_rows(16, seed=1, start=now - timedelta(days=12))  # both tails, 12 days ago
    recent = snapshot_rows(8, seed=2, start=now - timedelta(hours=5))
    recent = recent.filter(pc.equal(recent["tail"], "N101"))  # N101 reported again today
    upload(client, fleet_data, old)
    upload(client, fleet_data, recent)

    coverage = client.get(API, headers=fleet_data.viewer).json()
    assert coverage["overdue_days"] == 7.0
    tails = {t["tail"]: t for t in coverage["tails"]}
    assert list(tails) == ["N101", "N102"]
    assert datetime.fromisoformat(tails["N101"]["last_data"]) == newest(recent, "N101")
    assert datetime.fromisoformat(tails["N102"]["last_data"]) == newest(old, "N102")
    assert (tails["N101"]["engines_installed"], tails["N101"]["engines_overdue"]) == (2, 0)
    assert (tails["N102"]["engines_installed"], tails["N102"]["engines_overdue"]) == (2, 2)

    engines = {e["esn"]: e for e in coverage["engines"]}
    # Installed now: ESN-5 and ESN-2 on N101, ESN-3 and ESN-4 on N102; ESN-1 was removed.
    for esn, tail, position, table in (("ESN-5", "N101", 1, recent), ("ESN-2", "N101", 2, recent),
                                       ("ESN-3", "N102", 1, old), ("ESN-4", "N102", 2, old)):
        e = engines[esn]
        assert (e["tail"], e["position"]) == (tail, position)
        assert datetime.fromisoformat(e["last_data"]) == newest(table, tail, position)
        assert e["overdue"] is (table is old), esn
    assert (engines["ESN-1"]["tail"], engines["ESN-1"]["last_data"],
            engines["ESN-1"]["overdue"]) == (None, None, False)
    assert coverage["n_overdue"] == 2
    assert [e["esn"] for e in coverage["engines"][:2]] == ["ESN-3", "ESN-4"]  # overdue first

    # A longer overdue age: nothing overdue; the setting is the default age.
    assert client.get(API, params={"overdue_days": 30},
                      headers=fleet_data.viewer).json()["n_overdue"] == 0
    app.state.settings = app.state.settings.model_copy(update={"data_overdue_days": 20.0})
    assert client.get(API, headers=fleet_data.viewer).json()["n_overdue"] == 0
    assert client.get(API, params={"overdue_days": 0.1},
                      headers=fleet_data.viewer).json()["n_overdue"] == 4


def test_an_installed_engine_without_any_data_is_overdue_from_its_installation(
    client: TestClient, fleet_data: Fleet
) -> None:
    coverage = client.get(API, headers=fleet_data.viewer).json()
    overdue = {e["esn"] for e in coverage["engines"] if e["overdue"]}
    assert overdue == {"ESN-2", "ESN-3", "ESN-4", "ESN-5"}  # installed in March, no data
    assert all(t["last_data"] is None for t in coverage["tails"])


@pytest.mark.parametrize("value", ["0", "-1", "x", "4000"])
def test_a_bad_overdue_age_is_422_naming_it(
    client: TestClient, fleet_data: Fleet, value: str
) -> None:
    response = client.get(API, params={"overdue_days": value}, headers=fleet_data.viewer)
    assert response.status_code == 422
    assert "overdue_days" in response.text


def test_another_operators_fleet_is_not_seen(client: TestClient, fleet_data: Fleet) -> None:
    coverage = client.get(API, headers=fleet_data.other).json()
    assert not {e["esn"] for e in coverage["engines"]} & {"ESN-1", "ESN-2", "ESN-3"}
    assert "N101" not in {t["tail"] for t in coverage["tails"]}
