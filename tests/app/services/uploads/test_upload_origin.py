"""Upload history: file names and sources kept, bad file names refused storing nothing, and
back-dated uploads flagged with the events they caused (SQLite and PostgreSQL)."""

from __future__ import annotations

import io
from datetime import timedelta
from pathlib import Path

import pyarrow as pa
import pyarrow.csv as pacsv
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.models import Event, Upload
from app.services.fleet import service as fleet_service
from app.services.snapshots import store
from tests.app.services.snapshots import test_pipeline as pipeline_case
from tests.app.services.trends.test_trends import add_aircraft, add_engine
from tests.support.fleet_fixture import (
    Fleet,
    counts,
    csv_bytes,
    make_fleet,
    parquet_bytes,
    snapshot_rows,
)

MEDIA = {"csv": "text/csv", "parquet": "application/vnd.apache.parquet"}


@pytest.fixture
def fleet_data(session: Session) -> Fleet:
    return make_fleet(session)


def all_uploads(session: Session, operator_id: int) -> int:
    return int(session.scalar(
        select(func.count()).select_from(Upload).where(Upload.operator_id == operator_id)
    ) or 0)


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
@pytest.mark.parametrize("how", ["raw", "multipart"])
def test_file_name_source_and_key_name_are_kept_and_listed(
    client: TestClient, session: Session, fleet_data: Fleet, tmp_path: Path, fmt: str, how: str
) -> None:
    table = snapshot_rows(24, seed=5)
    path = tmp_path / f"day 12 é.{fmt}"
    path.write_bytes(csv_bytes(table) if fmt == "csv" else parquet_bytes(table))
    if how == "multipart":
        with path.open("rb") as handle:
            response = client.post(
                "/api/v1/snapshots/file", params={"source": "browser"},
                files={"file": (path.name, handle, MEDIA[fmt])}, headers=fleet_data.analyst,
            )
    else:  # a raw body names its file in the query, a path cut to its last component
        response = client.post(
            "/api/v1/snapshots/file",
            params={"filename": f"C:\\exports\\{path.name}", "source": "cli"},
            content=path.read_bytes(),
            headers={**fleet_data.analyst, "Content-Type": MEDIA[fmt]},
        )
    assert response.status_code == 201, response.text
    source = "browser" if how == "multipart" else "cli"
    out = response.json()
    assert (out["filename"], out["source"], out["api_key_name"]) == (path.name, source, "eng")
    assert out["back_dated"] is False  # nothing estimated yet
    listed = client.get("/api/v1/uploads", headers=fleet_data.analyst).json()["items"]
    assert [(u["id"], u["filename"], u["source"]) for u in listed] == [
        (out["id"], path.name, source)
    ]
    detail = client.get(f"/api/v1/uploads/{out['id']}", headers=fleet_data.analyst).json()
    assert detail["filename"] == path.name and detail["events"] == []
    row = session.get(Upload, out["id"])
    assert row is not None and (row.filename, row.source) == (path.name, source)


def test_a_refused_file_keeps_its_name_in_the_history_and_json_defaults_to_api(
    client: TestClient, session: Session, fleet_data: Fleet
) -> None:
    bad = csv_bytes(snapshot_rows(4)).replace(b"N101", b"N999", 1)  # an unknown tail
    response = client.post("/api/v1/snapshots/file", params={"filename": "bad.csv"},
                           content=bad, headers={**fleet_data.analyst, "Content-Type": "text/csv"})
    assert response.status_code == 422, response.text
    rejected = client.get("/api/v1/uploads", params={"status": "rejected"},
                          headers=fleet_data.analyst).json()["items"]
    assert [(u["filename"], u["source"], u["api_key_name"]) for u in rejected] == [
        ("bad.csv", "api", "eng")
    ]


# Multipart clients percent-encode a line break, CR and NUL in a part's file name (as
# browsers do), so those arrive as plain text there; an escape character does not.
@pytest.mark.parametrize(("name", "how"), [
    ("x" * 256 + ".csv", "raw"), ("x" * 256 + ".csv", "multipart"),  # over 255 characters
    ("day\n12.csv", "raw"),                                         # a line break
    ("day\x0012.csv", "raw"),                                       # NUL
    ("day\x1b[31m.csv", "raw"), ("day\x1b[31m.csv", "multipart"),    # an escape sequence
    ("evil\u202ecsv.exe", "raw"), ("evil\u202ecsv.exe", "multipart"),  # a bidi override
    ("exports/", "raw"), ("exports/", "multipart"),  # no name left once the folder is cut
])
def test_bad_file_names_are_refused_and_store_nothing(
    client: TestClient, session: Session, fleet_data: Fleet, name: str, how: str
) -> None:
    body = csv_bytes(snapshot_rows(8))
    before = (counts(session, fleet_data.operator_id), all_uploads(session, fleet_data.operator_id))
    if how == "multipart":
        response = client.post("/api/v1/snapshots/file",
                               files={"file": (name, body, "text/csv")},
                               headers=fleet_data.analyst)
    else:
        response = client.post("/api/v1/snapshots/file", params={"filename": name},
                               content=body,
                               headers={**fleet_data.analyst, "Content-Type": "text/csv"})
    assert response.status_code == 422, response.text
    assert "filename" in response.text
    after = (counts(session, fleet_data.operator_id), all_uploads(session, fleet_data.operator_id))
    assert after == before


def test_an_unknown_source_is_refused(client: TestClient, session: Session,
                                      fleet_data: Fleet) -> None:
    response = client.post("/api/v1/snapshots/file", params={"source": "robot"},
                           content=csv_bytes(snapshot_rows(4)),
                           headers={**fleet_data.analyst, "Content-Type": "text/csv"})
    assert response.status_code == 422
    assert all_uploads(session, fleet_data.operator_id) == 0


def _csv(times: list, y: pipeline_case.np.ndarray, idx: range, tail: str) -> bytes:
    columns = [s.name for s in pipeline_case._model().sensors]
    table = pa.table({
        "recorded_at": pa.array([times[i] for i in idx], pa.timestamp("us", tz="UTC")),
        "tail": [tail] * len(idx), "position": [1] * len(idx),
        "phase": ["takeoff" if i % 2 == 0 else "cruise" for i in idx],
        "alt_ft": [0.0] * len(idx), "mach": [0.0] * len(idx), "dtamb_k": [0.0] * len(idx),
        "power_pct": [100.0] * len(idx),
        **{c: y[list(idx), k] for k, c in enumerate(columns)},
    })
    sink = io.BytesIO()
    pacsv.write_csv(table, sink)
    return sink.getvalue()


def test_a_back_dated_upload_is_flagged_and_links_the_events_its_rerun_created(
    client: TestClient, session: Session
) -> None:
    """An engine estimated to its last record, then sent the records where an HPC fault
    began: the late upload is back-dated and its detail links the fault's event; the first
    upload is not back-dated and links no event the late one's re-run created."""
    fleet = pipeline_case._fleet_with_design(session)
    aircraft = add_aircraft(session, fleet, "F-BD")
    engine = add_engine(session, fleet, "BD1")
    times, y = pipeline_case._records(seed=21, fault="HPC", at=450)
    fleet_service.install(session, operator_id=fleet.operator_id, engine_id=engine.id,
                          aircraft_id=aircraft.id, position=1,
                          installed_at=times[0] - timedelta(days=1))
    session.commit()
    key = {"X-API-Key": fleet.key}

    def send(idx: range, name: str) -> dict:
        response = client.post("/api/v1/snapshots/file", params={"filename": name},
                               content=_csv(times, y, idx, "F-BD"),
                               headers={**key, "Content-Type": "text/csv"})
        assert response.status_code == 201, response.text
        return response.json()

    first = send(range(0, 400), "early.csv")
    store.catch_up(session, fleet.operator_id)
    assert not any(e.kind != "wear" for e in session.scalars(
        select(Event).where(Event.engine_id == engine.id)))
    late = send(range(400, pipeline_case.N), "late.csv")  # after the last estimate: not late
    assert late["back_dated"] is False
    store.catch_up(session, fleet.operator_id)
    # Now the records before the fault again, with a different first half: back-dated.
    shifted = y.copy()
    times_b = [t + timedelta(minutes=5) for t in times]  # new records between the old ones
    back = client.post("/api/v1/snapshots/file", params={"filename": "backfill.csv"},
                       content=_csv(times_b, shifted, range(440, 470), "F-BD"),
                       headers={**key, "Content-Type": "text/csv"})
    assert back.status_code == 201, back.text
    back_out = back.json()
    assert back_out["back_dated"] is True
    (affected,) = back_out["affected"]
    assert affected["estimated_until"].replace("Z", "+00:00") == times[-1].isoformat()
    # Told apart by what they are, not by id (SQLite reuses the id of a deleted row).
    before_rerun = {(e.kind, e.detected_at) for e in session.scalars(
        select(Event).where(Event.engine_id == engine.id))}
    store.catch_up(session, fleet.operator_id)
    session.expire_all()
    every = session.scalars(select(Event).where(Event.engine_id == engine.id)).all()
    new_since = [e for e in every if (e.kind, e.detected_at) not in before_rerun
                 and e.detected_at >= times_b[440]]
    assert new_since
    listed = client.get("/api/v1/uploads", headers=key).json()["items"]
    assert [(u["filename"], u["back_dated"]) for u in listed if u["filename"]] == [
        ("backfill.csv", True), ("late.csv", False), ("early.csv", False)
    ]
    detail = client.get(f"/api/v1/uploads/{back_out['id']}", headers=key).json()
    assert sorted(e["id"] for e in detail["events"]) == sorted(e.id for e in new_since)
    # The re-run now detects the fault at one of the back-dated records: linked to it.
    own = {t.isoformat().replace("+00:00", "Z") for t in times_b[440:470]}
    assert any(e["kind"] == "isolated_fault" and e["fault"] == "HPC" and e["detected_at"] in own
               for e in detail["events"])
    # And back: each linked event names the back-dated upload among the uploads that caused it.
    for e in detail["events"]:
        causes = client.get(f"/api/v1/events/{e['id']}/uploads", headers=key).json()
        assert back_out["id"] in [u["id"] for u in causes]
    unlinked = [e for e in every if e.id not in {x["id"] for x in detail["events"]}]
    for e in unlinked:
        causes = client.get(f"/api/v1/events/{e.id}/uploads", headers=key).json()
        assert back_out["id"] not in [u["id"] for u in causes]
    assert client.get("/api/v1/events/999999/uploads", headers=key).status_code == 404
    first_detail = client.get(f"/api/v1/uploads/{first['id']}", headers=key).json()
    assert all(e["id"] not in {x["id"] for x in detail["events"]}
               or e["detected_at"] < times[400].isoformat() for e in first_detail["events"])
