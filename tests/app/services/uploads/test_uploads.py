"""Snapshot uploads through the API, on SQLite and PostgreSQL: all or nothing, idempotent."""

from __future__ import annotations

import io
import json
from collections.abc import Iterator
from datetime import datetime, timedelta

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine, select
from sqlalchemy.orm import Session, sessionmaker

from app.config import Settings
from app.main import create_app
from app.models import Snapshot, Upload
from tests.support.fleet_fixture import (
    SWAP_AT,
    T0,
    Fleet,
    counts,
    csv_bytes,
    json_body,
    make_fleet,
    parquet_bytes,
    snapshot_rows,
)

CSV = {"Content-Type": "text/csv"}
PARQUET = {"Content-Type": "application/vnd.apache.parquet"}


@pytest.fixture
def fleet_data(session: Session) -> Fleet:
    return make_fleet(session)


def stored_values(
    session: Session, fleet_data: Fleet, column: str
) -> dict[tuple[int, str], float | None]:
    rows = session.execute(
        select(Snapshot.engine_id, Snapshot.recorded_at, getattr(Snapshot, column)).where(
            Snapshot.operator_id == fleet_data.operator_id
        )
    ).all()
    return {(e, t.isoformat()): v for e, t, v in rows}


def expected_engines(fleet_data: Fleet, table: pa.Table) -> list[int]:
    return [
        fleet_data.engine_at(r["tail"], r["position"], r["recorded_at"])
        for r in table.select(["tail", "position", "recorded_at"]).to_pylist()
    ]


def test_json_upload_stores_every_row_on_the_engine_installed_then(
    client: TestClient, session: Session, fleet_data: Fleet
) -> None:
    table = snapshot_rows(48)  # two days: before the swap on N101 position 1
    table = pa.concat_tables([table, snapshot_rows(16, seed=1, start=SWAP_AT)])
    response = client.post("/api/v1/snapshots", json=json_body(table), headers=fleet_data.analyst)
    assert response.status_code == 201, response.text
    out = response.json()
    assert (out["rows_received"], out["rows_stored"], out["rows_duplicate"]) == (64, 64, 0)
    assert out["status"] == "stored" and not out["replayed"]

    engines = expected_engines(fleet_data, table)
    expected = {
        (e, r["recorded_at"].isoformat()): r["T50"]
        for e, r in zip(engines, table.to_pylist(), strict=True)
    }
    assert stored_values(session, fleet_data, "t50") == expected
    # Affected engines: counted and bounded independently of the service.
    by_engine: dict[int, list] = {}
    for e, r in zip(engines, table.to_pylist(), strict=True):
        by_engine.setdefault(e, []).append(r["recorded_at"])
    got = {a["engine_id"]: a for a in out["affected"]}
    assert set(got) == set(by_engine)
    for engine_id, times in by_engine.items():
        assert got[engine_id]["rows"] == len(times)
        assert got[engine_id]["earliest"].replace("Z", "+00:00") == min(times).isoformat()
        assert got[engine_id]["latest"].replace("Z", "+00:00") == max(times).isoformat()


@pytest.mark.parametrize("how", ["csv", "csv-multipart", "parquet", "parquet-multipart"])
def test_file_uploads_and_the_same_rows_in_another_format_store_nothing_new(
    client: TestClient, session: Session, fleet_data: Fleet, how: str, tmp_path
) -> None:
    table = snapshot_rows(40)
    fmt = how.split("-")[0]
    path = tmp_path / f"snapshots.{fmt}"
    path.write_bytes(csv_bytes(table) if fmt == "csv" else parquet_bytes(table))
    if how.endswith("multipart"):
        with path.open("rb") as handle:
            response = client.post(
                "/api/v1/snapshots/file",
                files={"file": (path.name, handle, "application/octet-stream")},
                headers=fleet_data.analyst,
            )
    else:
        response = client.post(
            "/api/v1/snapshots/file",
            content=path.read_bytes(),
            headers={**fleet_data.analyst, **(CSV if fmt == "csv" else PARQUET)},
        )
    assert response.status_code == 201, response.text
    assert response.json()["rows_stored"] == 40
    before = counts(session, fleet_data.operator_id)
    again = client.post("/api/v1/snapshots", json=json_body(table), headers=fleet_data.analyst)
    assert again.status_code == 201
    assert (again.json()["rows_stored"], again.json()["rows_duplicate"]) == (0, 40)
    assert counts(session, fleet_data.operator_id)[0] == before[0]
    np.testing.assert_allclose(
        sorted(v for v in stored_values(session, fleet_data, "p30").values()),
        np.sort(table["P30"].to_numpy()),
    )


def test_same_body_twice_replays_the_first_result(
    client: TestClient, session: Session, fleet_data: Fleet
) -> None:
    body = csv_bytes(snapshot_rows(20))
    first = client.post(
        "/api/v1/snapshots/file", content=body, headers={**fleet_data.analyst, **CSV}
    )
    assert first.status_code == 201
    before = counts(session, fleet_data.operator_id)
    second = client.post(
        "/api/v1/snapshots/file", content=body, headers={**fleet_data.analyst, **CSV}
    )
    assert second.status_code == 200
    assert second.json()["replayed"] and second.json()["id"] == first.json()["id"]
    assert {k: v for k, v in second.json().items() if k != "replayed"} == {
        k: v for k, v in first.json().items() if k != "replayed"
    }
    assert counts(session, fleet_data.operator_id) == before


def test_idempotency_key_replays_same_content_and_refuses_other_content(
    client: TestClient, session: Session, fleet_data: Fleet
) -> None:
    key = {"Idempotency-Key": "batch-2026-03-01"}
    headers = {**fleet_data.analyst, **key}
    first = client.post("/api/v1/snapshots", json=json_body(snapshot_rows(12)), headers=headers)
    assert first.status_code == 201
    before = counts(session, fleet_data.operator_id)
    replay = client.post("/api/v1/snapshots", json=json_body(snapshot_rows(12)), headers=headers)
    assert replay.status_code == 200 and replay.json()["id"] == first.json()["id"]
    other = json_body(snapshot_rows(12, seed=5, start=T0 + timedelta(days=1)))
    conflict = client.post("/api/v1/snapshots", json=other, headers=headers)
    assert conflict.status_code == 409
    assert f"upload {first.json()['id']}" in conflict.json()["error"]["message"]
    assert counts(session, fleet_data.operator_id) == before
    # The same other content under a fresh key is a new upload.
    fresh = client.post(
        "/api/v1/snapshots", json=other, headers={**fleet_data.analyst, "Idempotency-Key": "b2"}
    )
    assert fresh.status_code == 201 and fresh.json()["rows_stored"] == 12


def test_a_changed_value_for_a_stored_snapshot_is_a_conflict(
    client: TestClient, session: Session, fleet_data: Fleet
) -> None:
    table = snapshot_rows(8)
    assert (
        client.post("/api/v1/snapshots", json=json_body(table), headers=fleet_data.analyst)
    ).status_code == 201
    before = counts(session, fleet_data.operator_id)
    changed = json_body(pa.concat_tables([table, snapshot_rows(8, start=T0 + timedelta(days=1))]))
    changed["snapshots"][5]["T30"] += 1.0
    response = client.post("/api/v1/snapshots", json=changed, headers=fleet_data.analyst)
    assert response.status_code == 409
    details = response.json()["error"]["details"]
    assert [(d["row"], d["column"]) for d in details] == [(6, "T30")]
    assert counts(session, fleet_data.operator_id) == before
    # Leaving out an optional column is not a change: the rows are the stored ones.
    fewer = client.post(
        "/api/v1/snapshots",
        json=json_body(table.drop_columns(["flight_id", "T50"])),
        headers=fleet_data.analyst,
    )
    assert fewer.status_code == 201 and fewer.json()["rows_duplicate"] == 8
    assert counts(session, fleet_data.operator_id)[0] == before[0]


def _bad_bodies(fleet_data: Fleet) -> Iterator[tuple[str, bytes, dict[str, str], tuple]]:
    """(case, body, headers, (status, row, column)) of each kind of bad input."""
    good = snapshot_rows(10)
    rows = json_body(good)["snapshots"]

    def as_json(records: list[dict]) -> bytes:
        return json.dumps({"snapshots": records}).encode()

    def edited(index: int, **changes: object) -> list[dict]:
        copy = [dict(r) for r in rows]
        copy[index].update(changes)
        return copy

    js = {"Content-Type": "application/json"}
    text = as_json(edited(3, Nf=123456.789)).decode().replace("123456.789", "NaN")
    yield "nan", text.encode(), js, (422, 4, "Nf")
    text = as_json(edited(2, Nf=123456.789)).decode().replace("123456.789", "Infinity")
    yield "inf", text.encode(), js, (422, 3, "Nf")
    yield (
        "naive time",
        as_json(edited(1, recorded_at="2026-03-01T00:00:00")),
        js,
        (
            422,
            2,
            "recorded_at",
        ),
    )
    yield "unknown column", as_json(edited(0, EGT=900.0)), js, (422, None, "EGT")
    unit_csv = csv_bytes(good.rename_columns([*good.column_names[:-1], "Wf[gal/h]"]))
    yield "unknown unit", unit_csv, CSV, (422, None, "Wf[gal/h]")
    yield "wrong type", as_json(edited(4, alt_ft="high")), js, (422, 5, "alt_ft")
    broken = csv_bytes(good).decode().splitlines()
    broken[3] += ",9,9"
    yield "malformed csv", ("\n".join(broken) + "\n").encode(), CSV, (422, None, None)
    yield "malformed parquet", b"PAR1" + b"\x00" * 64 + b"PAR1", PARQUET, (422, None, None)
    parquet = parquet_bytes(good)
    yield "truncated parquet", parquet[: len(parquet) - 40], PARQUET, (422, None, None)
    yield "truncated json", as_json(rows)[:-30], js, (422, None, None)
    yield "empty body", b"", CSV, (422, None, None)
    yield "empty json", b"", js, (422, None, None)
    yield "duplicate rows", as_json([*rows, rows[2]]), js, (422, 11, "recorded_at")
    yield "unknown tail", as_json(edited(6, tail="N999")), js, (422, 7, "tail")
    yield "no engine at position", as_json(edited(7, position=3)), js, (422, 8, "position")
    yield (
        "another operator's tail",
        as_json(edited(8, tail=fleet_data.other_tail)),
        js,
        (
            422,
            9,
            "tail",
        ),
    )
    yield (
        "before any installation",
        as_json(edited(9, recorded_at="2024-01-01T00:00:00Z")),
        js,
        (422, 10, "position"),
    )


def test_every_kind_of_bad_input_is_refused_naming_row_and_column_and_stores_nothing(
    client: TestClient, session: Session, fleet_data: Fleet
) -> None:
    # One test walks all cases so the fleet is built once per backend.
    for case, body, headers, (code, row, column) in _bad_bodies(fleet_data):
        before = counts(session, fleet_data.operator_id)
        path = (
            "/api/v1/snapshots" if "json" in headers["Content-Type"] else "/api/v1/snapshots/file"
        )
        response = client.post(path, content=body, headers={**fleet_data.analyst, **headers})
        assert response.status_code == code, (case, response.text)
        error = response.json()["error"]
        assert error["message"], case
        first = error["details"][0]
        assert (first.get("row"), first.get("column")) == (row, column), (case, error)
        assert first["reason"], case
        assert counts(session, fleet_data.operator_id) == before, case
        # The refusal is in the history, with the same errors.
        upload_id = int(error["message"].rsplit("[upload ", 1)[1].rstrip("]"))
        detail = client.get(f"/api/v1/uploads/{upload_id}", headers=fleet_data.viewer).json()
        assert detail["status"] == "rejected" and detail["errors"][0] == {
            "row": row,
            "column": column,
            "reason": first["reason"],
        }, case


def test_wrong_media_type_and_roles(
    client: TestClient, session: Session, fleet_data: Fleet
) -> None:
    body = csv_bytes(snapshot_rows(4))
    response = client.post(
        "/api/v1/snapshots/file",
        content=body,
        headers={**fleet_data.analyst, "Content-Type": "text/plain"},
    )
    assert response.status_code == 415
    viewer = client.post(
        "/api/v1/snapshots/file", content=body, headers={**fleet_data.viewer, **CSV}
    )
    assert viewer.status_code == 403
    assert client.post("/api/v1/snapshots/file", content=body, headers=CSV).status_code == 401
    assert counts(session, fleet_data.operator_id) == (0, 0)


def test_bodies_over_the_limit_get_413_with_or_without_content_length(
    settings: Settings,
    db_engine: Engine,
    session_factory: sessionmaker[Session],
    session: Session,
    fleet_data: Fleet,
) -> None:
    small = create_app(settings.model_copy(update={"max_body_bytes": 2000}), db_engine)
    small.state.sessionmaker = session_factory
    body = csv_bytes(snapshot_rows(40))
    assert len(body) > 2000
    with TestClient(small) as client:
        sized = client.post(
            "/api/v1/snapshots/file", content=body, headers={**fleet_data.analyst, **CSV}
        )
        assert sized.status_code == 413

        def chunks() -> Iterator[bytes]:
            view = io.BytesIO(body)
            while block := view.read(500):
                yield block

        streamed = client.post(
            "/api/v1/snapshots/file", content=chunks(), headers={**fleet_data.analyst, **CSV}
        )
        assert streamed.status_code == 413
        assert "transfer-encoding" not in sized.request.headers
        assert streamed.request.headers.get("transfer-encoding") == "chunked"
    assert counts(session, fleet_data.operator_id) == (0, 0)


def test_upload_history_and_tenancy(
    client: TestClient, session: Session, fleet_data: Fleet
) -> None:
    ok = client.post(
        "/api/v1/snapshots", json=json_body(snapshot_rows(4)), headers=fleet_data.analyst
    )
    bad = client.post(
        "/api/v1/snapshots/file", content=b"recorded_at\n", headers={**fleet_data.analyst, **CSV}
    )
    assert (ok.status_code, bad.status_code) == (201, 422)
    page = client.get("/api/v1/uploads", headers=fleet_data.viewer).json()
    assert [u["status"] for u in page["items"]] == ["rejected", "stored"]
    assert page["total"] == 2
    rejected = client.get("/api/v1/uploads?status=rejected", headers=fleet_data.viewer).json()
    assert [u["id"] for u in rejected["items"]] == [page["items"][0]["id"]]
    upload_id = ok.json()["id"]
    assert client.get(f"/api/v1/uploads/{upload_id}", headers=fleet_data.other).status_code == 404
    assert client.get("/api/v1/uploads", headers=fleet_data.other).json()["total"] == 0
    stored = session.get(Upload, upload_id)
    assert stored is not None and stored.api_key_id is not None


def test_engine_snapshots_as_json_and_csv(
    client: TestClient, session: Session, fleet_data: Fleet
) -> None:
    table = snapshot_rows(80)
    assert (
        client.post(
            "/api/v1/snapshots/file",
            content=parquet_bytes(table),
            headers={**fleet_data.analyst, **PARQUET},
        )
    ).status_code == 201
    engine_id = fleet_data.engines["ESN-3"]  # N102 position 1
    mine = table.filter(
        pa.compute.and_(
            pa.compute.equal(table["tail"], "N102"), pa.compute.equal(table["position"], 1)
        )
    )
    start, end = T0 + timedelta(hours=1), T0 + timedelta(hours=2)
    url = f"/api/v1/engines/{engine_id}/snapshots"
    params = {"start": start.isoformat(), "end": end.isoformat()}
    got = client.get(url, params=params, headers=fleet_data.viewer)
    assert got.status_code == 200
    body = got.json()
    window = [r for r in mine.to_pylist() if start <= r["recorded_at"] < end]
    assert body["esn"] == "ESN-3" and body["count"] == len(window) == 6
    assert [s["T30"] for s in body["snapshots"]] == [r["T30"] for r in window]
    assert [s["T50"] for s in body["snapshots"]] == [r["T50"] for r in window]
    assert body["units"]["T30"] == "degR"
    csv = client.get(url, params={**params, "format": "csv"}, headers=fleet_data.viewer)
    assert csv.headers["content-type"].startswith("text/csv")
    back = pacsv.read_csv(io.BytesIO(csv.content))
    np.testing.assert_array_equal(back["T30"].to_numpy(), [r["T30"] for r in window])
    limited = client.get(url, params={"limit": 3}, headers=fleet_data.viewer).json()
    assert [datetime.fromisoformat(s["recorded_at"]) for s in limited["snapshots"]] == [
        r["recorded_at"] for r in mine.to_pylist()[:3]
    ]
    assert client.get(url, headers=fleet_data.other).status_code == 404


def test_one_hundred_thousand_rows_in_one_request(
    client: TestClient, session: Session, fleet_data: Fleet
) -> None:
    n = 100_000
    table = snapshot_rows(n, seed=3, start=T0 - timedelta(days=300))
    response = client.post(
        "/api/v1/snapshots/file",
        content=parquet_bytes(table),
        headers={**fleet_data.analyst, **PARQUET},
    )
    assert response.status_code == 201, response.text[:500]
    assert response.json()["rows_stored"] == n
    assert counts(session, fleet_data.operator_id)[0] == n
    rows = session.execute(
        select(Snapshot.recorded_at, Snapshot.nc, Snapshot.t50).where(
            Snapshot.operator_id == fleet_data.operator_id
        )
    ).all()
    assert len(rows) == n
    np.testing.assert_allclose(sum(r[1] for r in rows), float(np.sum(table["Nc"].to_numpy())))
    assert sum(r[2] is None for r in rows) == table["T50"].null_count
