"""Stream recordings: a whole-flight file, live chunks in order, resends, and their samples."""

from __future__ import annotations

import io
import json
from datetime import timedelta
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.models import StreamChunk, StreamRecording
from tests.support.fleet_fixture import (
    SWAP_AT,
    T0,
    Fleet,
    make_fleet,
)

DT = 0.05  # 20 Hz
CSV = {"Content-Type": "text/csv"}
PARQUET = {"Content-Type": "application/vnd.apache.parquet"}


@pytest.fixture
def fleet_data(session: Session) -> Fleet:
    return make_fleet(session)


def flight(n: int, start_s: float = 0.0, seed: int = 0) -> pa.Table:
    rng = np.random.default_rng(seed)
    t = start_s + np.arange(n) * DT
    return pa.table(
        {
            "time_s": t,
            "alt_ft": np.linspace(0, 35000, n),
            "mach": np.linspace(0.0, 0.8, n),
            "dtamb_k": np.zeros(n),
            "power_pct": np.full(n, 90.0),
            "Wf": rng.uniform(0.5, 2.0, n),
            "T30[degC]": rng.uniform(500, 600, n),
            "Nc": rng.uniform(8500, 9100, n),
        }
    )


def parquet(table: pa.Table, manifest: dict | None = None) -> bytes:
    if manifest is not None:
        table = table.replace_schema_metadata({b"fleethealth.manifest": json.dumps(manifest)})
    sink = io.BytesIO()
    pq.write_table(table, sink)
    return sink.getvalue()


def csv(table: pa.Table) -> bytes:
    sink = io.BytesIO()
    pacsv.write_csv(table, sink)
    return sink.getvalue()


def n_recordings(session: Session, fleet_data: Fleet) -> int:
    return int(
        session.scalar(
            select(func.count())
            .select_from(StreamRecording)
            .where(StreamRecording.operator_id == fleet_data.operator_id)
        )
        or 0
    )


def test_whole_flight_file_is_a_closed_recording_on_the_engine_installed_then(
    client: TestClient, session: Session, fleet_data: Fleet, tmp_path: Path
) -> None:
    table = flight(400)
    path = tmp_path / "flight.parquet"
    path.write_bytes(parquet(table))
    params = {
        "tail": "N101",
        "position": 1,
        "started_at": (SWAP_AT + timedelta(hours=2)).isoformat(),
    }
    response = client.post(
        "/api/v1/streams",
        params=params,
        content=path.read_bytes(),
        headers={**fleet_data.analyst, **PARQUET},
    )
    assert response.status_code == 201, response.text
    recording = response.json()["recording"]
    assert recording["engine_id"] == fleet_data.engine_at("N101", 1, SWAP_AT + timedelta(hours=2))
    assert recording["status"] == "closed" and recording["n_samples"] == 400
    assert recording["dt_s"] == pytest.approx(DT)
    assert set(recording["signals"]) == {
        "alt_ft",
        "mach",
        "dtamb_k",
        "power_pct",
        "Wf",
        "T30",
        "Nc",
    }
    samples = client.get(
        f"/api/v1/streams/{recording['id']}/samples",
        params={"format": "parquet"},
        headers=fleet_data.viewer,
    )
    back = pq.read_table(io.BytesIO(samples.content))
    np.testing.assert_allclose(
        back["T30"].to_numpy(), (table["T30[degC]"].to_numpy() + 273.15) * 1.8
    )
    np.testing.assert_array_equal(back["time_s"].to_numpy(), table["time_s"].to_numpy())
    # The same file again: the first answer, nothing new.
    again = client.post(
        "/api/v1/streams",
        params=params,
        content=path.read_bytes(),
        headers={**fleet_data.analyst, **PARQUET},
    )
    assert again.status_code == 200 and again.json()["recording"]["id"] == recording["id"]
    assert n_recordings(session, fleet_data) == 1


def test_metadata_from_the_simulator_manifest(
    client: TestClient, session: Session, fleet_data: Fleet
) -> None:
    manifest = {"tail": "N102", "position": 2, "started_at": T0.isoformat(), "flight_id": "SIM-1"}
    response = client.post(
        "/api/v1/streams",
        content=parquet(flight(50), manifest),
        headers={**fleet_data.analyst, **PARQUET},
    )
    assert response.status_code == 201, response.text
    recording = response.json()["recording"]
    assert recording["engine_id"] == fleet_data.engines["ESN-4"]
    assert recording["flight_id"] == "SIM-1"
    missing = client.post(
        "/api/v1/streams", content=csv(flight(50)), headers={**fleet_data.analyst, **CSV}
    )
    assert missing.status_code == 422
    assert {d["column"] for d in missing.json()["error"]["details"]} == {
        "tail",
        "position",
        "started_at",
    }


def test_live_chunks_in_order_resends_gaps_and_conflicts(
    client: TestClient, session: Session, fleet_data: Fleet
) -> None:
    opened = client.post(
        "/api/v1/streams/live",
        json={"tail": "N101", "position": 2, "started_at": T0.isoformat(), "dt_s": DT},
        headers=fleet_data.analyst,
    )
    assert opened.status_code == 201, opened.text
    rid = opened.json()["id"]
    whole = flight(300, seed=4)
    parts = [whole.slice(0, 100), whole.slice(100, 120), whole.slice(220, 80)]
    url = f"/api/v1/streams/{rid}/chunks"
    first = client.post(
        url, params={"index": 0}, content=csv(parts[0]), headers={**fleet_data.analyst, **CSV}
    )
    assert first.status_code == 201, first.text
    # Skipping a chunk is refused, naming the one expected.
    gap = client.post(
        url, params={"index": 2}, content=csv(parts[2]), headers={**fleet_data.analyst, **CSV}
    )
    assert gap.status_code == 409 and "expects chunk 1" in gap.json()["error"]["message"]
    # A chunk that does not continue the time axis is refused.
    shifted = parts[1].set_column(0, "time_s", pa.array(parts[1]["time_s"].to_numpy() + 1.0))
    bad = client.post(
        url, params={"index": 1}, content=csv(shifted), headers={**fleet_data.analyst, **CSV}
    )
    assert bad.status_code == 422 and bad.json()["error"]["details"][0]["column"] == "time_s"
    # Chunked transfer encoding (no Content-Length) works for chunk bodies.
    body = parquet(parts[1])
    streamed = client.post(
        url,
        params={"index": 1},
        content=iter([body[:1000], body[1000:]]),
        headers={**fleet_data.analyst, **PARQUET},
    )
    assert streamed.status_code == 201, streamed.text
    assert streamed.request.headers.get("transfer-encoding") == "chunked"
    resend = client.post(
        url, params={"index": 1}, content=body, headers={**fleet_data.analyst, **PARQUET}
    )
    assert resend.status_code == 200 and resend.json()["replayed"]
    other = client.post(
        url, params={"index": 1}, content=csv(parts[2]), headers={**fleet_data.analyst, **CSV}
    )
    assert other.status_code == 409
    last = client.post(
        url, params={"index": 2}, content=csv(parts[2]), headers={**fleet_data.analyst, **CSV}
    )
    assert last.status_code == 201 and last.json()["recording"]["n_samples"] == 300
    closed = client.post(f"/api/v1/streams/{rid}/close", headers=fleet_data.analyst)
    assert closed.json()["status"] == "closed"
    late = client.post(
        url, params={"index": 3}, content=csv(parts[2]), headers={**fleet_data.analyst, **CSV}
    )
    assert late.status_code == 409
    chunks = session.scalar(select(func.count()).where(StreamChunk.recording_id == rid))
    assert chunks == 3
    samples = client.get(f"/api/v1/streams/{rid}/samples", headers=fleet_data.viewer)
    back = pacsv.read_csv(io.BytesIO(samples.content))
    np.testing.assert_allclose(back["time_s"].to_numpy(), whole["time_s"].to_numpy())
    np.testing.assert_allclose(back["Nc"].to_numpy(), whole["Nc"].to_numpy())


def test_bad_stream_input_and_tenancy(
    client: TestClient, session: Session, fleet_data: Fleet
) -> None:
    before = n_recordings(session, fleet_data)
    params = {"tail": "N101", "position": 1, "started_at": T0.isoformat()}
    uneven = flight(60)
    t = uneven["time_s"].to_numpy().copy()
    t[30:] += 0.01
    cases = [
        ({**params, "tail": "N999"}, csv(flight(60)), CSV, 422),
        ({**params, "position": 3}, csv(flight(60)), CSV, 422),
        (params, csv(uneven.set_column(0, "time_s", pa.array(t))), CSV, 422),
        (params, b"time_s,alt_ft\n0,nan\n", CSV, 422),
        (params, parquet(flight(60))[:-10], PARQUET, 422),
        (params, b"", CSV, 422),
        ({**params, "tail": fleet_data.other_tail}, csv(flight(60)), CSV, 422),
    ]
    for query, body, headers, code in cases:
        response = client.post(
            "/api/v1/streams", params=query, content=body, headers={**fleet_data.analyst, **headers}
        )
        assert response.status_code == code, (query, response.text)
    assert n_recordings(session, fleet_data) == before
    ok = client.post(
        "/api/v1/streams",
        params=params,
        content=csv(flight(60)),
        headers={**fleet_data.analyst, **CSV},
    )
    rid = ok.json()["recording"]["id"]
    assert client.get(f"/api/v1/streams/{rid}", headers=fleet_data.other).status_code == 404
    assert (
        client.post(
            f"/api/v1/streams/{rid}/chunks",
            params={"index": 1},
            content=csv(flight(5)),
            headers={**fleet_data.other, **CSV},
        )
    ).status_code == 404
    assert client.get("/api/v1/streams", headers=fleet_data.viewer).json()["total"] == 1
    viewer = client.post(
        "/api/v1/streams",
        params=params,
        content=csv(flight(60)),
        headers={**fleet_data.viewer, **CSV},
    )
    assert viewer.status_code == 403


def test_a_builtin_type_stream_without_its_condition_is_refused_naming_it(
    client: TestClient, session: Session, fleet_data: Fleet
) -> None:
    """The built-in engine's type is scheduled on the whole operating condition: a file
    without one of its columns is a 422 naming the column and the type, nothing stored."""
    before = n_recordings(session, fleet_data)
    params = {"tail": "N101", "position": 1, "started_at": T0.isoformat()}
    for name in ("alt_ft", "mach", "dtamb_k", "power_pct"):
        body = csv(flight(60).drop_columns([name]))
        response = client.post("/api/v1/streams", params=params, content=body,
                               headers={**fleet_data.analyst, **CSV})
        assert response.status_code == 422, response.text
        assert response.json()["error"]["details"] == [{
            "row": None, "column": name,
            "reason": f"required column {name!r} is missing (engine type 'generic' is "
                      "scheduled on it)"}]
    assert n_recordings(session, fleet_data) == before
