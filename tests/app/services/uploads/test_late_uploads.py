"""Late uploads: records recorded longer before the upload arrived than the lateness
(FLEETHEALTH_UPLOAD_LATENESS_DAYS, default 7 days) are counted and the upload flagged late
(SQLite and PostgreSQL)."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pyarrow as pa
import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy.orm import Session

from app.models import Upload
from tests.support.fleet_fixture import Fleet, csv_bytes, make_fleet, snapshot_rows


@pytest.fixture
def fleet_data(session: Session) -> Fleet:
    return make_fleet(session)


def post_csv(client: TestClient, fleet: Fleet, table: pa.Table, name: str) -> dict:
    response = client.post(
        "/api/v1/snapshots/file", params={"filename": name}, content=csv_bytes(table),
        headers={**fleet.analyst, "Content-Type": "text/csv"},
    )
    assert response.status_code == 201, response.text
    return response.json()


def test_records_older_than_the_lateness_make_an_upload_late(
    client: TestClient, session: Session, fleet_data: Fleet
) -> None:
    now = datetime.now(UTC).replace(microsecond=0)
    old = snapshot_rows(8, seed=1, start=now - timedelta(days=10))  # 10 days before arrival
    recent = snapshot_rows(12, seed=2, start=now - timedelta(days=1))
    mixed = pa.concat_tables([old, recent])
    late = post_csv(client, fleet_data, mixed, "mixed.csv")
    assert (late["rows_stored"], late["rows_late"], late["late"]) == (20, 8, True)
    fresh = post_csv(client, fleet_data, snapshot_rows(8, seed=3, start=now - timedelta(hours=6)),
                     "fresh.csv")
    assert (fresh["rows_late"], fresh["late"]) == (0, False)
    listed = {u["id"]: (u["rows_late"], u["late"])
              for u in client.get("/api/v1/uploads", headers=fleet_data.analyst).json()["items"]}
    assert listed == {late["id"]: (8, True), fresh["id"]: (0, False)}
    detail = client.get(f"/api/v1/uploads/{late['id']}", headers=fleet_data.analyst).json()
    assert (detail["rows_late"], detail["late"]) == (8, True)
    row = session.get(Upload, late["id"])
    assert row is not None and row.rows_late == 8


def test_the_lateness_is_a_setting(
    app: FastAPI, client: TestClient, fleet_data: Fleet
) -> None:
    now = datetime.now(UTC).replace(microsecond=0)
    app.state.settings = app.state.settings.model_copy(update={"upload_lateness_days": 30.0})
    ten_days = post_csv(client, fleet_data,
                        snapshot_rows(8, seed=4, start=now - timedelta(days=10)), "ten days.csv")
    assert (ten_days["rows_late"], ten_days["late"]) == (0, False)
    app.state.settings = app.state.settings.model_copy(update={"upload_lateness_days": 2.0})
    three_days = post_csv(client, fleet_data,
                          snapshot_rows(8, seed=5, start=now - timedelta(days=3)), "three.csv")
    assert (three_days["rows_late"], three_days["late"]) == (8, True)


def test_a_refused_upload_counts_no_late_records(
    client: TestClient, fleet_data: Fleet
) -> None:
    old = snapshot_rows(4, seed=6, start=datetime.now(UTC) - timedelta(days=40))
    bad = csv_bytes(old).replace(b"N101", b"N999", 1)
    response = client.post("/api/v1/snapshots/file", params={"filename": "bad.csv"},
                           content=bad, headers={**fleet_data.analyst, "Content-Type": "text/csv"})
    assert response.status_code == 422
    [rejected] = client.get("/api/v1/uploads", params={"status": "rejected"},
                            headers=fleet_data.analyst).json()["items"]
    assert (rejected["rows_late"], rejected["late"]) == (0, False)
