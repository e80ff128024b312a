"""Bounds on every stream path: the sample interval (file, live opening, chunk), the chunk
index, and the stored reason of a chunk refused as out of order."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest
from fastapi.testclient import TestClient
from sqlalchemy.orm import Session

from app.signals import MAX_CHUNK_INDEX, STREAM_DT_MAX_S, STREAM_DT_MIN_S
from tests.app.services.streams.test_recordings import CSV, csv, flight, n_recordings
from tests.support.fleet_fixture import T0, Fleet, make_fleet


@pytest.fixture
def fleet_data(session: Session) -> Fleet:
    return make_fleet(session)


def with_interval(table: pa.Table, dt: float) -> pa.Table:
    return table.set_column(0, "time_s", pa.array(np.arange(table.num_rows) * dt))


def open_live(client: TestClient, fleet: Fleet, dt: object) -> object:
    return client.post(
        "/api/v1/streams/live",
        json={"tail": "N101", "position": 2, "started_at": T0.isoformat(), "dt_s": dt},
        headers=fleet.analyst,
    )


@pytest.mark.parametrize("dt", [1e-9, STREAM_DT_MIN_S / 2, STREAM_DT_MAX_S * 2])
def test_stream_file_outside_the_interval_bounds_is_refused(
    client: TestClient, session: Session, fleet_data: Fleet, dt: float
) -> None:
    before = n_recordings(session, fleet_data)
    response = client.post(
        "/api/v1/streams",
        params={"tail": "N101", "position": 1, "started_at": T0.isoformat()},
        content=csv(with_interval(flight(50), dt)),
        headers={**fleet_data.analyst, **CSV},
    )
    assert response.status_code == 422, response.text
    detail = response.json()["error"]["details"][0]
    assert detail["column"] == "time_s" and "sample interval" in detail["reason"]
    assert n_recordings(session, fleet_data) == before


@pytest.mark.parametrize("dt", ["NaN", "Infinity", 1e-9, 0, -1, 61])
def test_live_recording_interval_must_be_finite_and_bounded(
    client: TestClient, session: Session, fleet_data: Fleet, dt: object
) -> None:
    before = n_recordings(session, fleet_data)
    if isinstance(dt, str):  # NaN and Infinity: not JSON, but Python's encoder writes them
        response = client.post(
            "/api/v1/streams/live",
            content=f'{{"tail": "N101", "position": 2, "started_at": "{T0.isoformat()}", '
            f'"dt_s": {dt}}}',
            headers={**fleet_data.analyst, "Content-Type": "application/json"},
        )
    else:
        response = open_live(client, fleet_data, dt)
    assert response.status_code == 422, response.text
    assert "dt_s" in response.json()["error"]["message"]
    assert n_recordings(session, fleet_data) == before


def test_chunk_index_beyond_the_bound_is_a_4xx(
    client: TestClient, fleet_data: Fleet
) -> None:
    opened = open_live(client, fleet_data, 0.05)
    rid = opened.json()["id"]  # type: ignore[attr-defined]
    for index in (2**70, MAX_CHUNK_INDEX + 1):
        response = client.post(
            f"/api/v1/streams/{rid}/chunks", params={"index": index},
            content=csv(flight(10)), headers={**fleet_data.analyst, **CSV},
        )
        assert response.status_code == 422, response.text
        assert "index" in response.json()["error"]["message"]


def test_chunk_with_a_finer_interval_than_allowed_is_refused(
    client: TestClient, fleet_data: Fleet
) -> None:
    opened = open_live(client, fleet_data, STREAM_DT_MIN_S)
    rid = opened.json()["id"]  # type: ignore[attr-defined]
    response = client.post(
        f"/api/v1/streams/{rid}/chunks", params={"index": 0},
        content=csv(with_interval(flight(10), 1e-9)), headers={**fleet_data.analyst, **CSV},
    )
    assert response.status_code == 422, response.text
    assert "sample interval" in response.json()["error"]["details"][0]["reason"]


def test_chunk_refused_as_out_of_order_reads_back_with_its_reason(
    client: TestClient, fleet_data: Fleet
) -> None:
    opened = open_live(client, fleet_data, 0.05)
    rid = opened.json()["id"]  # type: ignore[attr-defined]
    gap = client.post(
        f"/api/v1/streams/{rid}/chunks", params={"index": 3},
        content=csv(flight(10)), headers={**fleet_data.analyst, **CSV},
    )
    assert gap.status_code == 409, gap.text
    listed = client.get(
        "/api/v1/uploads", params={"status": "rejected"}, headers=fleet_data.analyst
    )
    assert listed.status_code == 200, listed.text
    ids = [u["id"] for u in listed.json()["items"] if u["kind"] == "stream_chunk"]
    assert ids, listed.text
    for upload_id in ids:
        detail = client.get(f"/api/v1/uploads/{upload_id}", headers=fleet_data.analyst)
        assert detail.status_code == 200, detail.text
        errors = detail.json()["errors"]
        assert errors and "out of order" in errors[0]["reason"]
