"""Job schedules: when they are due, what they submit, the scheduler thread, the admin API."""

from __future__ import annotations

import threading
from datetime import UTC, datetime, timedelta

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import func, select
from sqlalchemy.orm import Session, sessionmaker

from app.db import transaction
from app.jobs.runner import run_pending
from app.jobs.scheduler import Scheduler, next_run_after, submit_due
from app.models import Job, JobSchedule
from app.services.jobs import schedules
from app.services.jobs.registry import JobRegistry
from tests.support.jobs import (
    add_key,
    connection,
    job_row,
    jobs_client,
    live,
    live_module,
    make_operator,
    make_registry,
    registry,
)

# Fixtures from jobs_support: the isolating connection replaces the shared one here.
__all__ = ["connection", "jobs_client", "live", "live_module", "registry"]

T0 = datetime(2026, 3, 1, 6, 0, tzinfo=UTC)


@pytest.mark.parametrize(
    ("interval", "now_offset"),
    [(3600, 0), (3600, 1), (3600, 3599), (3600, 3600), (3600, 7201), (60, 86_399), (86_400, -5)],
)
def test_next_run_is_the_first_step_of_the_interval_after_now(
    interval: int, now_offset: int
) -> None:
    now = T0 + timedelta(seconds=now_offset)
    # Walk the steps one by one: the first one strictly after now, at least one step on.
    walked = T0 + timedelta(seconds=interval)
    while walked <= now:
        walked += timedelta(seconds=interval)
    assert next_run_after(T0, interval, now) == walked


def _schedule(
    session: Session, registry: JobRegistry, operator_id: int, **overrides: object
) -> JobSchedule:
    fields: dict[str, object] = {
        "kind": "add",
        "parameters": {"a": 1},
        "interval_seconds": 3600,
        "first_run_at": T0,
    }
    fields.update(overrides)
    return schedules.create_schedule(
        session,
        operator_id=operator_id,
        registry=registry,
        **fields,  # type: ignore[arg-type]
    )


def test_due_schedules_submit_one_job_each_and_advance(
    session_factory: sessionmaker[Session], session: Session, registry: JobRegistry
) -> None:
    operator, _key = make_operator(session, "Schedule Air")
    due = _schedule(session, registry, operator.id)
    later = _schedule(session, registry, operator.id, first_run_at=T0 + timedelta(hours=2))
    disabled = _schedule(session, registry, operator.id, parameters={"a": 2}, enabled=False)
    session.commit()

    now = T0 + timedelta(minutes=5)
    submitted = submit_due(session_factory, registry, now=now)
    assert len(submitted) == 1
    job = job_row(session_factory, submitted[0])
    assert (job.kind, job.parameters, job.schedule_id) == ("add", {"a": 1, "b": 0}, due.id)
    # Submitted once per due run: asking again at the same time submits nothing.
    assert submit_due(session_factory, registry, now=now) == []

    for schedule in (due, later, disabled):
        session.refresh(schedule)
    assert due.next_run_at == next_run_after(T0, 3600, now) and due.last_run_at == now
    assert later.next_run_at == T0 + timedelta(hours=2) and later.last_run_at is None
    assert disabled.next_run_at == T0 and disabled.last_run_at is None


def test_a_run_due_while_the_last_job_is_still_active_reuses_it(
    session_factory: sessionmaker[Session], session: Session, registry: JobRegistry
) -> None:
    operator, _key = make_operator(session, "Overlap Air")
    _schedule(session, registry, operator.id)
    session.commit()
    first = submit_due(session_factory, registry, now=T0)
    # An hour later the first job has not run yet: no second copy of the same work.
    assert submit_due(session_factory, registry, now=T0 + timedelta(hours=1)) == []
    assert run_pending(session_factory, registry) == first
    second = submit_due(session_factory, registry, now=T0 + timedelta(hours=2))
    assert len(second) == 1 and second != first
    count = session.scalar(
        select(func.count()).select_from(Job).where(Job.operator_id == operator.id)
    )
    assert count == 2


def test_missed_runs_are_skipped_not_made_up(
    session_factory: sessionmaker[Session], session: Session, registry: JobRegistry
) -> None:
    operator, _key = make_operator(session, "Downtime Air")
    schedule = _schedule(session, registry, operator.id)
    session.commit()
    now = T0 + timedelta(hours=5, minutes=30)  # the service was down for five runs
    assert len(submit_due(session_factory, registry, now=now)) == 1
    session.refresh(schedule)
    assert schedule.next_run_at == T0 + timedelta(hours=6)


def test_a_schedule_whose_kind_is_gone_is_advanced_and_submits_nothing(
    session_factory: sessionmaker[Session], session: Session, registry: JobRegistry
) -> None:
    operator, _key = make_operator(session, "Gone Kind Air")
    schedule = _schedule(session, registry, operator.id)
    session.commit()
    assert submit_due(session_factory, JobRegistry(), now=T0) == []
    session.refresh(schedule)
    assert schedule.next_run_at == T0 + timedelta(hours=1)
    count = session.scalar(
        select(func.count()).select_from(Job).where(Job.operator_id == operator.id)
    )
    assert count == 0


@pytest.mark.parametrize(
    ("body", "column"),
    [
        ({"kind": "add", "parameters": {"a": "x"}, "interval_seconds": 3600}, "a"),
        ({"kind": "nope", "parameters": {}, "interval_seconds": 3600}, "kind"),
        ({"kind": "add", "parameters": {"a": 1}, "interval_seconds": 10}, "interval_seconds"),
        (
            {
                "kind": "add",
                "parameters": {"a": 1},
                "interval_seconds": 3600,
                "first_run_at": "2026-03-01T06:00:00",
            },
            "first_run_at",
        ),
    ],
)
def test_bad_schedules_are_422_and_store_nothing(
    jobs_client: TestClient, session: Session, body: dict[str, object], column: str
) -> None:
    _operator, key = make_operator(session, "Bad Schedule Air")
    session.commit()
    response = jobs_client.post("/api/v1/schedules", json=body, headers={"X-API-Key": key})
    assert response.status_code == 422
    details = response.json()["error"]["details"]
    assert any(
        detail.get("column") == column or column in detail.get("location", []) for detail in details
    ), details
    assert session.scalar(select(func.count()).select_from(JobSchedule)) == 0


def test_schedules_api_is_for_admins_of_their_own_operator(
    jobs_client: TestClient, session: Session
) -> None:
    operator, admin = make_operator(session, "Schedule Api Air")
    analyst = add_key(session, operator, "analyst")
    _other, stranger = make_operator(session, "Schedule Stranger Air")
    session.commit()
    mine = {"X-API-Key": admin}
    body = {
        "kind": "add",
        "parameters": {"a": 4},
        "interval_seconds": 7200,
        "first_run_at": "2026-03-01T06:00:00+01:00",
    }
    assert (
        jobs_client.post("/api/v1/schedules", json=body, headers={"X-API-Key": analyst}).status_code
        == 403
    )
    created = jobs_client.post("/api/v1/schedules", json=body, headers=mine)
    assert created.status_code == 201
    schedule = created.json()
    assert schedule["parameters"] == {"a": 4, "b": 0}
    assert datetime.fromisoformat(schedule["next_run_at"]) == T0 - timedelta(hours=1)
    url = f"/api/v1/schedules/{schedule['id']}"

    assert [s["id"] for s in jobs_client.get("/api/v1/schedules", headers=mine).json()] == [
        schedule["id"]
    ]
    assert jobs_client.get("/api/v1/schedules", headers={"X-API-Key": stranger}).json() == []
    for method in ("get", "patch", "delete"):
        kwargs = {"json": {"enabled": False}} if method == "patch" else {}
        response = getattr(jobs_client, method)(url, headers={"X-API-Key": stranger}, **kwargs)
        assert response.status_code == 404, method

    patched = jobs_client.patch(
        url, json={"enabled": False, "parameters": {"a": 5, "b": 1}}, headers=mine
    )
    assert patched.status_code == 200
    assert (patched.json()["enabled"], patched.json()["parameters"]) == (False, {"a": 5, "b": 1})
    assert jobs_client.patch(url, json={"parameters": {"a": "x"}}, headers=mine).status_code == 422
    assert jobs_client.get(url, headers=mine).json()["parameters"] == {"a": 5, "b": 1}

    assert jobs_client.delete(url, headers=mine).status_code == 200
    assert jobs_client.get(url, headers=mine).status_code == 404


class RecordingDispatch:
    def __init__(self) -> None:
        self.job_ids: list[int] = []
        self.dispatched = threading.Event()

    def dispatch(self, job_id: int) -> None:
        self.job_ids.append(job_id)
        self.dispatched.set()


def test_the_scheduler_thread_submits_due_jobs_and_hands_them_to_the_runner(
    live: tuple[str, sessionmaker[Session]],
) -> None:
    _url, factory = live
    registry = make_registry()
    with transaction(factory) as session:
        operator, _key = make_operator(session, "Scheduler Thread Air")
        schedule = _schedule(session, registry, operator.id)
        schedule_id = schedule.id
    dispatcher = RecordingDispatch()
    scheduler = Scheduler(factory, registry, dispatcher, tick_seconds=0.05)
    scheduler.start()
    try:
        assert dispatcher.dispatched.wait(20), "the scheduler submitted nothing"
    finally:
        scheduler.stop()
    assert len(dispatcher.job_ids) == 1
    job = job_row(factory, dispatcher.job_ids[0])
    assert (job.status, job.schedule_id) == ("queued", schedule_id)
    assert run_pending(factory, registry) == [job.id]
    assert job_row(factory, job.id).result == {"sum": 1, "operator_id": operator.id}
