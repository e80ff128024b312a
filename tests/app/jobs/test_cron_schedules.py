"""Cron schedules: validated with croniter (a bad expression is a 422 naming ``cron`` and stores
nothing), next run computed in UTC, due runs submitted and advanced, "run now" and each
schedule's last job; interval schedules as before (SQLite and PostgreSQL)."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import func, select
from sqlalchemy.orm import Session, sessionmaker

from app.jobs.runner import run_pending
from app.jobs.scheduler import submit_due
from app.models import Job, JobSchedule
from app.services.jobs import schedules
from app.services.jobs.registry import JobRegistry
from tests.support.jobs import (
    add_key,
    connection,
    job_row,
    jobs_client,
    make_operator,
    registry,
)

__all__ = ["connection", "jobs_client", "registry"]

API = "/api/v1/schedules"


def next_six_utc(after: datetime) -> datetime:
    """06:00 UTC on the day of ``after`` if still ahead, else the next day's: by hand."""
    at_six = after.astimezone(UTC).replace(hour=6, minute=0, second=0, microsecond=0)
    return at_six if at_six > after else at_six + timedelta(days=1)


def test_a_cron_schedule_is_due_at_its_next_time_in_utc(
    jobs_client: TestClient, session: Session
) -> None:
    _operator, key = make_operator(session, "Cron Air")
    session.commit()
    before = datetime.now(UTC)
    created = jobs_client.post(API, json={"kind": "add", "parameters": {"a": 2},
                                          "cron": " 0  6 * * * "}, headers={"X-API-Key": key})
    after = datetime.now(UTC)
    assert created.status_code == 201, created.text
    body = created.json()
    assert (body["cron"], body["interval_seconds"], body["last_job"]) == ("0 6 * * *", None, None)
    next_run = datetime.fromisoformat(body["next_run_at"])
    assert next_run in (next_six_utc(before), next_six_utc(after))
    assert next_run.utcoffset() == timedelta(0)


@pytest.mark.parametrize(
    ("body", "columns"),
    [
        ({"cron": "61 * * * *"}, {"cron"}),                       # minute out of range
        ({"cron": "0 6 * * * *"}, {"cron"}),                      # six fields
        ({"cron": "every day"}, {"cron"}),                        # not cron at all
        ({"cron": "0 0 31 2 *"}, {"cron"}),                       # 31 February: never due
        ({"cron": "0 6 * * *", "interval_seconds": 3600}, {"cron", "interval_seconds"}),
        ({}, {"cron", "interval_seconds"}),                       # neither
        ({"cron": "x" * 101}, {"cron"}),                          # longer than the column
    ],
)
def test_bad_cron_is_422_naming_the_field_and_stores_nothing(
    jobs_client: TestClient, session: Session, body: dict[str, object], columns: set[str]
) -> None:
    _operator, key = make_operator(session, "Bad Cron Air")
    session.commit()
    response = jobs_client.post(API, json={"kind": "add", "parameters": {"a": 1}, **body},
                                headers={"X-API-Key": key})
    assert response.status_code == 422, response.text
    details = response.json()["error"]["details"]
    named = {d.get("column") for d in details} | {
        part for d in details for part in d.get("location", [])
    }
    assert columns <= named, details
    assert session.scalar(select(func.count()).select_from(JobSchedule)) == 0


def test_a_due_cron_schedule_submits_once_and_moves_to_its_next_time(
    session_factory: sessionmaker[Session], session: Session, registry: JobRegistry
) -> None:
    operator, _key = make_operator(session, "Cron Due Air")
    due_at = datetime(2026, 3, 2, 6, 0, tzinfo=UTC)
    cron = schedules.create_schedule(
        session, operator_id=operator.id, kind="add", parameters={"a": 3}, registry=registry,
        cron="0 6 * * 1-5", first_run_at=due_at,  # week days at 06:00 UTC; 2 March is a Monday
    )
    interval = schedules.create_schedule(
        session, operator_id=operator.id, kind="add", parameters={"a": 4}, registry=registry,
        interval_seconds=3600, first_run_at=due_at,
    )
    session.commit()
    # Friday 6 March 07:30: the runs of Tuesday to Friday were missed; one job, next Monday.
    now = datetime(2026, 3, 6, 7, 30, tzinfo=UTC)
    submitted = submit_due(session_factory, registry, now=now)
    assert len(submitted) == 2
    assert {job_row(session_factory, j).schedule_id for j in submitted} == {cron.id, interval.id}
    assert submit_due(session_factory, registry, now=now) == []
    session.refresh(cron)
    session.refresh(interval)
    assert cron.next_run_at == datetime(2026, 3, 9, 6, 0, tzinfo=UTC)
    assert interval.next_run_at == datetime(2026, 3, 6, 8, 0, tzinfo=UTC)  # phase kept
    assert cron.last_run_at == now


def test_run_now_submits_the_job_and_the_list_shows_its_progress(
    jobs_client: TestClient, session: Session, session_factory: sessionmaker[Session],
    registry: JobRegistry,
) -> None:
    operator, key = make_operator(session, "Run Now Air")
    analyst = add_key(session, operator, "analyst")
    _other, stranger = make_operator(session, "Run Now Stranger Air")
    session.commit()
    mine = {"X-API-Key": key}
    schedule = jobs_client.post(API, json={"kind": "add", "parameters": {"a": 5},
                                           "cron": "30 2 * * *"}, headers=mine).json()
    url = f"{API}/{schedule['id']}/run"
    assert jobs_client.post(url, headers={"X-API-Key": analyst}).status_code == 403
    assert jobs_client.post(url, headers={"X-API-Key": stranger}).status_code == 404
    assert session.scalar(select(func.count()).select_from(Job)) == 0

    ran = jobs_client.post(url, headers=mine)
    assert ran.status_code == 202, ran.text
    job = ran.json()
    assert (job["kind"], job["parameters"], job["schedule_id"], job["status"]) == (
        "add", {"a": 5, "b": 0}, schedule["id"], "queued")
    again = jobs_client.post(url, headers=mine)  # still queued: the same job
    assert (again.status_code, again.json()["id"]) == (200, job["id"])
    listed = jobs_client.get(API, headers=mine).json()
    [item] = listed
    assert item["last_job"]["id"] == job["id"] and item["last_job"]["status"] == "queued"
    assert item["next_run_at"] == schedule["next_run_at"]  # run now leaves the times alone
    assert item["last_run_at"] is not None

    assert run_pending(session_factory, registry) == [job["id"]]
    done = jobs_client.get(f"{API}/{schedule['id']}", headers=mine).json()["last_job"]
    assert (done["id"], done["status"], done["progress"]) == (job["id"], "succeeded", 1.0)
    assert jobs_client.get(f"/api/v1/jobs/{job['id']}", headers=mine).json()["result"] == {
        "sum": 5, "operator_id": operator.id}


def test_patching_cron_replaces_the_interval_and_a_bad_one_changes_nothing(
    jobs_client: TestClient, session: Session
) -> None:
    _operator, key = make_operator(session, "Patch Cron Air")
    session.commit()
    mine = {"X-API-Key": key}
    created = jobs_client.post(API, json={"kind": "add", "parameters": {"a": 1},
                                          "interval_seconds": 3600}, headers=mine).json()
    url = f"{API}/{created['id']}"
    bad = jobs_client.patch(url, json={"cron": "0 25 * * *"}, headers=mine)
    assert bad.status_code == 422 and "cron" in bad.text
    assert jobs_client.get(url, headers=mine).json()["interval_seconds"] == 3600
    patched = jobs_client.patch(url, json={"cron": "0 6 * * *"}, headers=mine).json()
    assert (patched["cron"], patched["interval_seconds"]) == ("0 6 * * *", None)
    run = datetime.fromisoformat(patched["next_run_at"])
    assert (run.hour, run.minute) == (6, 0) and run > datetime.now(UTC)
    back = jobs_client.patch(url, json={"interval_seconds": 600}, headers=mine).json()
    assert (back["cron"], back["interval_seconds"]) == (None, 600)
