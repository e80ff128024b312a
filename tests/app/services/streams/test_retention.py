"""Stream sample retention: the Parquet files of closed recordings older than the setting go;
the recording's row, chunks, estimates and steady-window records stay, the API answers 410 for
the samples and says when they went, a re-estimation keeps the estimates; open and recent
recordings keep their files; no retention set keeps everything."""

from __future__ import annotations

from datetime import timedelta
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.config import Settings
from app.jobs.kinds.maintenance import PurgeStreamSamples, purge_stream_samples
from app.models import Job, Operator, Snapshot, StreamChunk, StreamRecording, Upload
from app.services.streams import retention
from app.services.tenancy import service as tenancy
from tests.app.services.streams.test_estimation import (
    CSV,
    DT,
    Q_TRUE,
    START,
    _activate,
    _csv,
    _design_document,
    _estimate,
    _model,
    _rows,
    _simulate,
    _upload_file,
)
from tests.support.fleet_fixture import Fleet, make_fleet


@pytest.fixture
def fleet_data(session: Session) -> Fleet:
    return make_fleet(session)


def _files(settings: Settings, session: Session, recording_id: int) -> list[Path]:
    recording = session.get(StreamRecording, recording_id)
    assert recording is not None
    folder = settings.data_dir / recording.path
    return sorted(folder.glob("*.parquet")) if folder.is_dir() else []


def _steady_records(session: Session, recording_id: int) -> int:
    return session.scalar(
        select(func.count()).select_from(Snapshot)
        .join(Upload, Upload.id == Snapshot.upload_id)
        .where(Upload.recording_id == recording_id)
    ) or 0


def test_old_closed_recordings_lose_their_samples_and_keep_what_came_from_them(
    client: TestClient, session: Session, fleet_data: Fleet, settings: Settings,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    model = _model()
    _activate(session, fleet_data, model, _design_document(model))
    table = _simulate(model, 2400, Q_TRUE, seed=4)
    old = _upload_file(client, fleet_data, table, 1)
    assert old["status"] == "closed"
    _estimate(session, settings, fleet_data, old["id"])
    opened = client.post("/api/v1/streams/live", headers=fleet_data.analyst, json={
        "tail": "N102", "position": 1, "started_at": START.isoformat(), "dt_s": DT})
    live = opened.json()["id"]
    assert client.post(f"/api/v1/streams/{live}/chunks", params={"index": 0},
                       content=_csv(table.slice(0, 200)),
                       headers={**fleet_data.analyst, **CSV}).status_code == 201
    session.commit()
    estimates = _rows(session, old["id"])
    records = _steady_records(session, old["id"])
    assert estimates and _files(settings, session, old["id"])
    chunks = session.scalar(select(func.count()).select_from(StreamChunk)
                            .where(StreamChunk.recording_id == old["id"]))
    monkeypatch.setattr("app.config.get_settings", lambda: settings)

    # No retention set: the job keeps everything.
    kept = purge_stream_samples(session, PurgeStreamSamples(), lambda *a: None,
                                operator_id=fleet_data.operator_id)
    assert kept["recordings"] == 0 and "no retention" in kept["message"]
    # Closed just now: not yet older than a day.
    assert retention.purge(session, operator_id=fleet_data.operator_id,
                           data_dir=settings.data_dir, older_than=timedelta(days=1)
                           ).recordings == 0

    closed_at = session.get(StreamRecording, old["id"]).closed_at  # type: ignore[union-attr]
    assert closed_at is not None
    done = retention.purge(session, operator_id=fleet_data.operator_id,
                           data_dir=settings.data_dir, older_than=timedelta(days=1),
                           now=closed_at + timedelta(days=2))
    session.commit()
    assert done.recordings == 1 and done.files == 1 and done.bytes > 0
    assert _files(settings, session, old["id"]) == []
    assert _files(settings, session, live)  # open: kept
    # Metadata, chunks, estimates and steady-window records are kept.
    assert _rows(session, old["id"]) == estimates
    assert _steady_records(session, old["id"]) == records
    assert session.scalar(select(func.count()).select_from(StreamChunk)
                          .where(StreamChunk.recording_id == old["id"])) == chunks
    body = client.get(f"/api/v1/streams/{old['id']}", headers=fleet_data.analyst).json()
    assert body["samples_removed_at"] is not None and body["n_samples"] == 2400
    gone = client.get(f"/api/v1/streams/{old['id']}/samples", headers=fleet_data.analyst)
    assert gone.status_code == 410 and "retention" in gone.json()["error"]["message"]
    live_body = client.get(f"/api/v1/streams/{live}", headers=fleet_data.analyst).json()
    assert live_body["samples_removed_at"] is None
    # Estimating again keeps the estimates (nothing to read them from).
    again = _estimate(session, settings, fleet_data, old["id"])
    assert again["samples"] == 0 and "removed" in again["message"]
    assert _rows(session, old["id"]) == estimates
    # A second purge finds nothing more.
    assert retention.purge(session, operator_id=fleet_data.operator_id,
                           data_dir=settings.data_dir, older_than=timedelta(days=1),
                           now=closed_at + timedelta(days=3)).recordings == 0


def test_the_job_takes_the_setting_and_rejects_a_bad_age(
    client: TestClient, session: Session, fleet_data: Fleet, settings: Settings,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    model = _model()
    _activate(session, fleet_data, model, _design_document(model))
    recording = _upload_file(client, fleet_data, _simulate(model, 400, Q_TRUE, seed=5), 1)
    row = session.get(StreamRecording, recording["id"])
    assert row is not None and row.closed_at is not None
    row.closed_at -= timedelta(days=40)
    session.commit()
    monkeypatch.setattr("app.config.get_settings",
                        lambda: settings.model_copy(update={"stream_retention_days": 30.0}))
    done = purge_stream_samples(session, PurgeStreamSamples(), lambda *a: None,
                                operator_id=fleet_data.operator_id)
    assert done["recordings"] == 1 and done["older_than_days"] == 30.0
    assert _files(settings, session, recording["id"]) == []
    # A bad age is a 4xx and queues nothing.
    operator = session.get(Operator, fleet_data.operator_id)
    _row, key = tenancy.issue_api_key(session, operator=operator, role="admin", name="adm")
    session.commit()
    admin = {"X-API-Key": key}
    response = client.post("/api/v1/jobs", headers=admin, json={
        "kind": "purge_stream_samples", "parameters": {"older_than_days": 0}})
    assert response.status_code == 422
    assert session.scalar(select(func.count()).select_from(Job)
                          .where(Job.kind == "purge_stream_samples")) == 0
