"""Jobs: submission, idempotency, progress, failure, restart, cancellation, tenancy.

The synchronous tests run queued jobs with ``run_pending`` on the rolled-back test connection;
the threaded tests use a fresh database that really commits, with the runner's real threads.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import threading
from collections.abc import Iterator
from datetime import timedelta
from pathlib import Path

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import func, select, update
from sqlalchemy.orm import Session, sessionmaker

from app.config import Settings
from app.db import transaction
from app.errors import Conflict, InvalidInput
from app.jobs.claim import STALE_AFTER, claim_job, claim_next, requeue_orphans, requeue_stale
from app.jobs.kinds import load_kinds
from app.jobs.progress import ProgressReporter
from app.jobs.runner import Runner, execute, run_pending
from app.main import create_app
from app.models import Job, Operator
from app.models.base import utcnow
from app.services.jobs import store
from app.services.jobs.registry import JobCancelled, JobRegistry, parameters_checksum
from tests.support.jobs import (
    AddParameters,
    Gates,
    Live,
    add_key,
    connection,
    job_row,
    live,
    live_module,
    make_operator,
    make_registry,
    operator_exists,
    wait_until,
)

# Fixtures from jobs_support: the isolating connection replaces the shared one here.
__all__ = ["connection", "live", "live_module"]


@pytest.fixture
def registry() -> JobRegistry:
    return make_registry()


@pytest.fixture
def jobs_app(app: FastAPI, registry: JobRegistry) -> FastAPI:
    app.state.job_registry = registry
    return app


@pytest.fixture
def jobs_client(jobs_app: FastAPI) -> Iterator[TestClient]:
    with TestClient(jobs_app) as test_client:
        yield test_client


def _count_jobs(session: Session) -> int:
    return session.scalar(select(func.count()).select_from(Job)) or 0


def _submit(
    factory: sessionmaker[Session],
    registry: JobRegistry,
    operator_id: int,
    kind: str,
    **params: object,
) -> int:
    with transaction(factory) as session:
        job, _created = store.submit(
            session, operator_id=operator_id, kind=kind, parameters=params, registry=registry
        )
        return job.id


# --- submission and results ---------------------------------------------------------------


def test_submitted_job_runs_and_records_its_result(
    session_factory: sessionmaker[Session], session: Session, registry: JobRegistry
) -> None:
    operator, _key = make_operator(session, "Jobs Air")
    session.commit()
    job_id = _submit(session_factory, registry, operator.id, "add", a=2, b=40)
    queued = job_row(session_factory, job_id)
    assert (queued.status, queued.progress, queued.attempts) == ("queued", 0.0, 0)

    assert run_pending(session_factory, registry) == [job_id]
    done = job_row(session_factory, job_id)
    assert done.status == "succeeded"
    assert done.result == {"sum": 2 + 40, "operator_id": operator.id}
    assert done.progress == 1.0 and done.attempts == 1 and done.error is None
    assert done.started_at is not None and done.finished_at is not None
    assert done.created_at <= done.started_at <= done.finished_at
    assert run_pending(session_factory, registry) == []  # nothing left queued


def test_same_kind_and_parameters_while_active_return_the_existing_job(
    session_factory: sessionmaker[Session], session: Session, registry: JobRegistry
) -> None:
    operator, _key = make_operator(session, "Idem Air")
    other, _ = make_operator(session, "Other Idem Air")
    first, created = store.submit(
        session, operator_id=operator.id, kind="add", parameters={"a": 1}, registry=registry
    )
    # The same work spelled differently (default filled in, keys reordered) is the same job.
    again, created_again = store.submit(
        session, operator_id=operator.id, kind="add", parameters={"b": 0, "a": 1}, registry=registry
    )
    different, created_different = store.submit(
        session, operator_id=operator.id, kind="add", parameters={"a": 2}, registry=registry
    )
    theirs, created_theirs = store.submit(
        session, operator_id=other.id, kind="add", parameters={"a": 1}, registry=registry
    )
    session.commit()
    assert (created, created_again, created_different, created_theirs) == (True, False, True, True)
    assert again.id == first.id and len({first.id, different.id, theirs.id}) == 3
    assert first.checksum == parameters_checksum("add", AddParameters(a=1, b=0))

    run_pending(session_factory, registry)
    # Once finished, the same parameters are new work again.
    later, created_later = store.submit(
        session, operator_id=operator.id, kind="add", parameters={"a": 1}, registry=registry
    )
    assert created_later and later.id not in {first.id, different.id, theirs.id}


def test_the_active_job_index_refuses_a_second_active_copy(
    session: Session, registry: JobRegistry
) -> None:
    # What a concurrent submission meets when both pass the look-up before either inserts.
    operator, _key = make_operator(session, "Race Air")
    job, _ = store.submit(
        session, operator_id=operator.id, kind="add", parameters={"a": 5}, registry=registry
    )
    copy = Job(
        operator_id=operator.id,
        kind="add",
        parameters=job.parameters,
        checksum=job.checksum,
        status="queued",
    )
    with pytest.raises(Exception, match="(?i)unique"):
        with session.begin_nested():
            session.add(copy)
            session.flush()
    # A finished copy is allowed: the index only covers queued and running jobs.
    with session.begin_nested():
        session.add(
            Job(
                operator_id=operator.id,
                kind="add",
                parameters=job.parameters,
                checksum=job.checksum,
                status="succeeded",
            )
        )
    assert _count_jobs(session) == 2


def test_api_submit_is_202_then_200_with_the_same_job(
    jobs_client: TestClient, session: Session
) -> None:
    _operator, key = make_operator(session, "Api Jobs Air", role="analyst")
    session.commit()
    headers = {"X-API-Key": key}
    body = {"kind": "add", "parameters": {"a": 3, "b": 4}}
    first = jobs_client.post("/api/v1/jobs", json=body, headers=headers)
    second = jobs_client.post("/api/v1/jobs", json=body, headers=headers)
    assert (first.status_code, second.status_code) == (202, 200)
    assert first.json()["id"] == second.json()["id"]
    assert first.json()["status"] == "queued" and first.json()["parameters"] == {"a": 3, "b": 4}
    assert _count_jobs(session) == 1


# --- bad input stores nothing -------------------------------------------------------------


@pytest.mark.parametrize(
    ("body", "column"),
    [
        ({"kind": "add", "parameters": {"a": "three"}}, "a"),
        ({"kind": "add", "parameters": {}}, "a"),
        ({"kind": "add", "parameters": {"a": 1, "c": 2}}, "c"),
        ({"kind": "no_such_kind", "parameters": {}}, "kind"),
    ],
)
def test_bad_parameters_are_422_and_store_nothing(
    jobs_client: TestClient, session: Session, body: dict[str, object], column: str
) -> None:
    _operator, key = make_operator(session, "Bad Params Air")
    session.commit()
    response = jobs_client.post("/api/v1/jobs", json=body, headers={"X-API-Key": key})
    assert response.status_code == 422
    error = response.json()["error"]
    assert error["code"] == "invalid_input"
    assert [detail["column"] for detail in error["details"]] == [column]
    assert _count_jobs(session) == 0


def test_bad_parameters_raise_before_anything_is_stored(
    session: Session, registry: JobRegistry
) -> None:
    operator, _key = make_operator(session, "Bad Store Air")
    with pytest.raises(InvalidInput, match="'add'"):
        store.submit(
            session, operator_id=operator.id, kind="add", parameters={"a": []}, registry=registry
        )
    assert _count_jobs(session) == 0


def test_roles_decide_who_submits_and_cancels(jobs_client: TestClient, session: Session) -> None:
    operator, viewer = make_operator(session, "Roles Air", role="viewer")
    analyst = add_key(session, operator, "analyst")
    session.commit()
    body = {"kind": "add", "parameters": {"a": 1}}
    assert (
        jobs_client.post("/api/v1/jobs", json=body, headers={"X-API-Key": viewer}).status_code
        == 403
    )
    created = jobs_client.post("/api/v1/jobs", json=body, headers={"X-API-Key": analyst})
    assert created.status_code == 202
    job_id = created.json()["id"]
    cancel = f"/api/v1/jobs/{job_id}/cancel"
    assert jobs_client.post(cancel, headers={"X-API-Key": viewer}).status_code == 403
    # The viewer still sees the job and its progress.
    assert (
        jobs_client.get(f"/api/v1/jobs/{job_id}", headers={"X-API-Key": viewer}).status_code == 200
    )


def test_purge_kind_needs_an_admin_key(client: TestClient, session: Session) -> None:
    operator, analyst = make_operator(session, "Purge Roles Air", role="analyst")
    admin = add_key(session, operator, "admin")
    session.commit()
    body = {"kind": "purge_finished_jobs", "parameters": {"older_than_days": 7}}
    assert client.post("/api/v1/jobs", json=body, headers={"X-API-Key": analyst}).status_code == 403
    assert client.post("/api/v1/jobs", json=body, headers={"X-API-Key": admin}).status_code == 202


def test_job_kinds_list_their_parameter_schema(
    jobs_client: TestClient, session: Session, registry: JobRegistry
) -> None:
    _operator, key = make_operator(session, "Kinds Air", role="viewer")
    session.commit()
    response = jobs_client.get("/api/v1/jobs/kinds", headers={"X-API-Key": key})
    assert response.status_code == 200
    kinds = {kind["name"]: kind for kind in response.json()}
    assert set(kinds) == {kind.name for kind in registry}
    assert kinds["add"]["parameters_schema"] == AddParameters.model_json_schema()


# --- progress ---------------------------------------------------------------------------


def test_progress_is_written_at_most_once_per_throttle_interval(
    session_factory: sessionmaker[Session], session: Session, registry: JobRegistry
) -> None:
    operator, _key = make_operator(session, "Throttle Air")
    session.commit()
    job_id = _submit(session_factory, registry, operator.id, "add", a=1)
    claim = claim_next(session_factory, worker="test")
    assert claim is not None and claim.job_id == job_id
    now = [100.0]
    report = ProgressReporter(session_factory, claim, throttle_seconds=0.5, clock=lambda: now[0])
    expected_visible: tuple[float, str] = (0.0, "running")
    last_write: float | None = None
    for at, fraction in [(100.0, 0.1), (100.2, 0.2), (100.4, 0.3), (100.6, 0.4), (100.7, 0.5)]:
        now[0] = at
        report(fraction, f"at {fraction}")
        # The rule restated: write when nothing was written yet or the interval has passed.
        if last_write is None or at - last_write >= 0.5:
            last_write = at
            expected_visible = (fraction, f"at {fraction}")
        row = job_row(session_factory, job_id)
        assert (row.progress, row.message) == expected_visible
    with pytest.raises(ValueError, match="fraction"):
        report(1.5)
    with pytest.raises(ValueError, match="fraction"):
        report(float("nan"))


# --- failure and cancellation -------------------------------------------------------------


def test_failure_records_the_error_and_rolls_back_the_jobs_writes(
    session_factory: sessionmaker[Session], session: Session, registry: JobRegistry
) -> None:
    operator, _key = make_operator(session, "Fail Air")
    session.commit()
    job_id = _submit(session_factory, registry, operator.id, "boom", name="written by boom")
    run_pending(session_factory, registry)
    failed = job_row(session_factory, job_id)
    assert failed.status == "failed"
    assert failed.error == "ValueError: boom after writing written by boom"
    assert failed.result is None and failed.finished_at is not None
    assert not operator_exists(session_factory, "written by boom")


def test_a_job_whose_kind_disappeared_fails_with_the_reason(
    session_factory: sessionmaker[Session], session: Session, registry: JobRegistry
) -> None:
    operator, _key = make_operator(session, "Gone Air")
    session.commit()
    job_id = _submit(session_factory, registry, operator.id, "add", a=1)
    run_pending(session_factory, JobRegistry())  # a worker that does not know the kind
    failed = job_row(session_factory, job_id)
    assert failed.status == "failed" and "unknown job kind 'add'" in (failed.error or "")


def test_cancelling_a_queued_job_means_it_never_runs(
    session_factory: sessionmaker[Session], session: Session, registry: JobRegistry
) -> None:
    operator, _key = make_operator(session, "Cancel Air")
    session.commit()
    job_id = _submit(session_factory, registry, operator.id, "add", a=1)
    with transaction(session_factory) as other:
        store.cancel(other, operator_id=operator.id, job_id=job_id)
    assert run_pending(session_factory, registry) == []
    row = job_row(session_factory, job_id)
    assert (row.status, row.attempts, row.result) == ("cancelled", 0, None)
    with transaction(session_factory) as other, pytest.raises(Conflict, match="cancelled"):
        store.cancel(other, operator_id=operator.id, job_id=job_id)


def test_cancelling_a_running_job_stops_it_at_its_next_report_and_undoes_its_work(
    session_factory: sessionmaker[Session], session: Session
) -> None:
    operator, _key = make_operator(session, "Cancel Running Air")
    session.commit()
    registry = JobRegistry()

    @registry.job("cancelled_midway", parameters=AddParameters, description="cancelled by itself")
    def cancelled_midway(
        job_session: Session, parameters: AddParameters, progress: object, *, operator_id: int
    ) -> dict[str, object]:
        # What POST .../cancel does. (On the one test connection the job's transaction must
        # start after it: rolling back the job would otherwise also undo the nested cancel.)
        with transaction(session_factory) as api_session:
            running = api_session.scalar(select(Job.id).where(Job.status == "running"))
            assert running is not None
            store.cancel(api_session, operator_id=operator_id, job_id=running)
        job_session.add(Operator(name="half-done work"))
        job_session.flush()
        progress(0.5, "after the cancel")  # type: ignore[operator]
        raise AssertionError("progress should have raised JobCancelled")

    job_id = _submit(session_factory, registry, operator.id, "cancelled_midway", a=1)
    run_pending(session_factory, registry)
    row = job_row(session_factory, job_id)
    assert (row.status, row.error) == ("cancelled", None)
    assert not operator_exists(session_factory, "half-done work")


def test_cancel_over_the_api_and_conflict_when_finished(
    jobs_client: TestClient,
    session: Session,
    session_factory: sessionmaker[Session],
    registry: JobRegistry,
) -> None:
    operator, key = make_operator(session, "Cancel Api Air", role="analyst")
    session.commit()
    headers = {"X-API-Key": key}
    queued = _submit(session_factory, registry, operator.id, "add", a=1)
    finished = _submit(session_factory, registry, operator.id, "add", a=2)
    # Cancel the first before a runner gets to it; the second runs.
    response = jobs_client.post(f"/api/v1/jobs/{queued}/cancel", headers=headers)
    assert response.status_code == 200 and response.json()["status"] == "cancelled"
    assert run_pending(session_factory, registry) == [finished]
    conflict = jobs_client.post(f"/api/v1/jobs/{finished}/cancel", headers=headers)
    assert conflict.status_code == 409
    assert job_row(session_factory, finished).status == "succeeded"


def test_work_that_breaks_a_constraint_at_commit_fails_and_stores_nothing(
    session_factory: sessionmaker[Session], session: Session
) -> None:
    operator, _key = make_operator(session, "Constraint Air")
    session.commit()
    registry = JobRegistry()

    @registry.job("duplicate", parameters=AddParameters, description="adds a duplicate name")
    def duplicate(
        job_session: Session, parameters: AddParameters, progress: object, *, operator_id: int
    ) -> dict[str, object]:
        job_session.add(Operator(name="unique side effect"))
        job_session.add(Operator(name="Constraint Air"))  # flushed with the result: refused
        return {"added": 2}

    job_id = _submit(session_factory, registry, operator.id, "duplicate", a=1)
    run_pending(session_factory, registry)
    row = job_row(session_factory, job_id)
    assert row.status == "failed" and (row.error or "").startswith("IntegrityError")
    assert row.result is None
    assert not operator_exists(session_factory, "unique side effect")


class RecordingDispatch:
    def __init__(self) -> None:
        self.job_ids: list[int] = []

    def dispatch(self, job_id: int) -> None:
        self.job_ids.append(job_id)


@pytest.mark.parametrize("fails", [False, True])
def test_jobs_a_job_queues_are_dispatched_when_it_commits(
    session_factory: sessionmaker[Session], session: Session, fails: bool
) -> None:
    operator, _key = make_operator(session, f"Chain Air {fails}")
    session.commit()
    registry = make_registry()

    @registry.job("chain", parameters=AddParameters, description="queues an add job")
    def chain(
        job_session: Session, parameters: AddParameters, progress: object, *, operator_id: int
    ) -> dict[str, object]:
        follow_up, _ = store.submit(
            job_session,
            operator_id=operator_id,
            kind="add",
            parameters={"a": parameters.a},
            registry=registry,
        )
        if fails:
            raise RuntimeError("failed after queueing")
        return {"follow_up": follow_up.id}

    job_id = _submit(session_factory, registry, operator.id, "chain", a=11)
    claim = claim_next(session_factory, worker="test")
    assert claim is not None
    sent = RecordingDispatch()
    status = execute(session_factory, claim, registry, heartbeat_seconds=None, dispatcher=sent)
    queued = session.scalars(
        select(Job.id).where(Job.operator_id == operator.id, Job.kind == "add")
    ).all()
    if fails:
        assert (status, sent.job_ids, queued) == ("failed", [], [])
    else:
        result = job_row(session_factory, job_id).result
        assert status == "succeeded" and result == {"follow_up": queued[0]}
        assert sent.job_ids == list(queued) and len(queued) == 1


def test_dispatch_waits_for_the_outermost_commit_and_happens_once(
    session_factory: sessionmaker[Session], session: Session, registry: JobRegistry
) -> None:
    operator, _key = make_operator(session, "Dispatch Air")
    session.commit()
    sent = RecordingDispatch()
    with session_factory() as request_session:
        job, _ = store.submit(
            request_session,
            operator_id=operator.id,
            kind="add",
            parameters={"a": 1},
            registry=registry,
        )
        store.dispatch_after_commit(request_session, sent.dispatch, job.id)
        with request_session.begin_nested():  # a savepoint commit: workers cannot see it yet
            request_session.add(Operator(name="Dispatch Air savepoint"))
        assert sent.job_ids == []
        request_session.commit()
        assert sent.job_ids == [job.id]
        request_session.add(Operator(name="Dispatch Air later"))
        request_session.commit()
        assert sent.job_ids == [job.id]

    with session_factory() as rolled_back:
        other, _ = store.submit(
            rolled_back,
            operator_id=operator.id,
            kind="add",
            parameters={"a": 2},
            registry=registry,
        )
        store.dispatch_after_commit(rolled_back, sent.dispatch, other.id)
        rolled_back.rollback()
        rolled_back.commit()
    assert sent.job_ids == [job.id]


# --- restart --------------------------------------------------------------------------------


def test_restart_requeues_stale_running_jobs_and_fences_the_lost_worker(
    session_factory: sessionmaker[Session], session: Session, registry: JobRegistry
) -> None:
    operator, _key = make_operator(session, "Restart Air")
    session.commit()
    job_id = _submit(session_factory, registry, operator.id, "add", a=7, b=8)
    lost = claim_next(session_factory, worker="a worker that dies")
    assert lost is not None and lost.attempt == 1
    fresh_id = _submit(session_factory, registry, operator.id, "add", a=1)
    fresh = claim_next(session_factory, worker="a worker that lives")
    assert fresh is not None and fresh.job_id == fresh_id

    later = utcnow() + timedelta(minutes=10)
    with transaction(session_factory) as other:  # the live worker kept beating
        other.execute(update(Job).where(Job.id == fresh_id).values(heartbeat_at=later))
    requeued = requeue_stale(session_factory, stale_after=timedelta(minutes=2), now=later)
    assert requeued == [job_id]
    assert job_row(session_factory, fresh_id).status == "running"

    # The dead worker wakes up: its progress and its result are refused.
    with pytest.raises(JobCancelled):
        ProgressReporter(session_factory, lost, throttle_seconds=0)(0.3)
    assert run_pending(session_factory, registry) == [job_id]
    assert execute(session_factory, lost, registry, heartbeat_seconds=None) == "succeeded"
    done = job_row(session_factory, job_id)
    assert done.attempts == 2 and done.result == {"sum": 7 + 8, "operator_id": operator.id}


def test_a_starting_process_takes_over_the_jobs_a_stopped_process_of_its_host_left(
    session_factory: sessionmaker[Session], session: Session, registry: JobRegistry
) -> None:
    operator, _key = make_operator(session, "Orphan Air")
    session.commit()
    finished = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                              capture_output=True, text=True, check=True)
    gone = int(finished.stdout)  # a process that has exited
    host = socket.gethostname()
    workers = {
        "orphan": f"inprocess:{host}:{gone}:1",
        "live here": f"inprocess:{host}:{os.getpid()}:1",
        "elsewhere": f"celery:another-host:{gone}:1",
        "unnamed": "a worker named otherwise",
    }
    jobs = {}
    for number, (name, worker) in enumerate(workers.items()):
        jobs[name] = _submit(session_factory, registry, operator.id, "add", a=number)
        assert claim_next(session_factory, worker=worker) is not None
    # Every heartbeat is fresh: only the orphan is taken over, without waiting.
    assert requeue_orphans(session_factory) == [jobs["orphan"]]
    assert requeue_stale(session_factory) == []
    statuses = {name: job_row(session_factory, job_id).status for name, job_id in jobs.items()}
    assert statuses == {
        "orphan": "queued", "live here": "running", "elsewhere": "running", "unnamed": "running"
    }
    assert run_pending(session_factory, registry) == [jobs["orphan"]]
    assert job_row(session_factory, jobs["orphan"]).attempts == 2


def test_the_heartbeat_timeout_is_a_setting(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path, job_stale_after_seconds=30, job_heartbeat_seconds=5)
    assert settings.job_stale_after == timedelta(seconds=30)
    assert Settings(data_dir=tmp_path).job_stale_after == STALE_AFTER
    with pytest.raises(ValueError, match="shorter"):
        Settings(data_dir=tmp_path, job_stale_after_seconds=10, job_heartbeat_seconds=10)


def test_a_job_whose_workers_keep_dying_fails_after_max_attempts(
    session_factory: sessionmaker[Session], session: Session, registry: JobRegistry
) -> None:
    operator, _key = make_operator(session, "Dying Air")
    session.commit()
    job_id = _submit(session_factory, registry, operator.id, "add", a=1)
    now = utcnow()
    for attempt in range(1, 4):
        claim = claim_next(session_factory, worker=f"dies {attempt}")
        assert claim is not None and claim.attempt == attempt
        now += timedelta(minutes=10)
        requeue_stale(session_factory, stale_after=timedelta(minutes=2), max_attempts=3, now=now)
    row = job_row(session_factory, job_id)
    assert row.status == "failed" and "3 times" in (row.error or "")
    assert run_pending(session_factory, registry) == []


# --- tenancy --------------------------------------------------------------------------------


def test_another_operators_job_is_not_found(
    jobs_client: TestClient,
    session: Session,
    session_factory: sessionmaker[Session],
    registry: JobRegistry,
) -> None:
    owner, owner_key = make_operator(session, "Owner Air")
    _stranger, stranger_key = make_operator(session, "Stranger Air")
    session.commit()
    job_id = _submit(session_factory, registry, owner.id, "add", a=1)
    mine = {"X-API-Key": owner_key}
    theirs = {"X-API-Key": stranger_key}
    assert jobs_client.get(f"/api/v1/jobs/{job_id}", headers=mine).status_code == 200
    assert jobs_client.get(f"/api/v1/jobs/{job_id}", headers=theirs).status_code == 404
    assert jobs_client.post(f"/api/v1/jobs/{job_id}/cancel", headers=theirs).status_code == 404
    assert jobs_client.get("/api/v1/jobs", headers=theirs).json() == {"items": [], "total": 0}
    assert job_row(session_factory, job_id).status == "queued"
    # Resubmitting the same work under another operator is another job, not theirs.
    response = jobs_client.post(
        "/api/v1/jobs", json={"kind": "add", "parameters": {"a": 1}}, headers=theirs
    )
    assert response.status_code == 202 and response.json()["id"] != job_id


def test_list_filters_by_status_and_kind(
    jobs_client: TestClient,
    session: Session,
    session_factory: sessionmaker[Session],
    registry: JobRegistry,
) -> None:
    operator, key = make_operator(session, "List Air", role="viewer")
    session.commit()
    added = [_submit(session_factory, registry, operator.id, "add", a=n) for n in range(3)]
    boom = _submit(session_factory, registry, operator.id, "boom", name="list boom")
    run_pending(session_factory, registry)
    queued = _submit(session_factory, registry, operator.id, "add", a=99)
    headers = {"X-API-Key": key}

    def ids(query: str) -> list[int]:
        response = jobs_client.get(f"/api/v1/jobs{query}", headers=headers)
        assert response.status_code == 200
        body = response.json()
        assert body["total"] >= len(body["items"])
        return [item["id"] for item in body["items"]]

    everything = sorted([*added, boom, queued], reverse=True)
    assert ids("") == everything
    assert ids("?status=succeeded") == sorted(added, reverse=True)
    assert ids("?status=failed&status=queued") == sorted([boom, queued], reverse=True)
    assert ids("?kind=boom") == [boom]
    assert ids("?limit=2&offset=1") == everything[1:3]
    assert jobs_client.get("/api/v1/jobs?status=lost", headers=headers).status_code == 422


# --- the real kind --------------------------------------------------------------------------


def test_purge_finished_jobs_deletes_only_old_finished_jobs_of_the_operator(
    session_factory: sessionmaker[Session], session: Session
) -> None:
    registry = load_kinds()
    operator, _key = make_operator(session, "Purge Air")
    other, _ = make_operator(session, "Purge Other Air")
    now = utcnow()
    cases = []  # (operator, status, finished days ago or None)
    for owner in (operator, other):
        for status in ("succeeded", "failed", "cancelled", "queued", "running"):
            for days in (None, 1, 20, 40, 400):
                if (days is None) != (status in ("queued", "running")):
                    continue
                cases.append((owner.id, status, days))
    rows = []
    for index, (owner_id, status, days) in enumerate(cases):
        row = Job(
            operator_id=owner_id,
            kind="purge_finished_jobs",
            parameters={"case": index},
            checksum=f"case-{index}",
            status=status,
            finished_at=None if days is None else now - timedelta(days=days),
        )
        session.add(row)
        rows.append(row)
    session.commit()
    expected_gone = {
        row.id
        for row, (owner_id, status, days) in zip(rows, cases, strict=True)
        if owner_id == operator.id and days is not None and days > 30
    }
    assert len(expected_gone) == 6
    job_id = _submit(
        session_factory,
        registry,
        operator.id,
        "purge_finished_jobs",
        older_than_days=30,
        batch_size=4,
    )
    # Run just this job: the queued fixture rows are not for running.
    claim = claim_job(session_factory, job_id, worker="test")
    assert claim is not None
    assert execute(session_factory, claim, registry, heartbeat_seconds=None) == "succeeded"
    done = job_row(session_factory, job_id)
    assert done.result is not None and done.result["deleted"] == len(expected_gone)
    assert done.message == f"deleted {len(expected_gone)} of {len(expected_gone)} finished jobs"
    remaining = set(session.scalars(select(Job.id)).all())
    assert remaining == ({row.id for row in rows} - expected_gone) | {job_id}


# --- real threads on a database that commits ------------------------------------------------


def test_runner_threads_show_progress_while_running_and_run_jobs_side_by_side(
    live: tuple[str, sessionmaker[Session]],
) -> None:
    _url, factory = live
    gates = Gates()
    registry = make_registry(gates)
    with transaction(factory) as session:
        operator, _key = make_operator(session, "Live Air")
        operator_id = operator.id
    runner = Runner(factory, registry, workers=2, poll_seconds=0.05, heartbeat_seconds=0.05)
    runner.start()
    try:
        waiting = _submit(factory, registry, operator_id, "wait", name="made by the waiting job")
        runner.dispatch(waiting)
        assert gates.started.wait(20), "the waiting job never started"
        row = job_row(factory, waiting)
        assert (row.status, row.progress, row.message) == (
            "running",
            0.5,
            "half way: made by the waiting job",
        )
        first_beat = row.heartbeat_at
        assert first_beat is not None
        wait_until(
            lambda: (job_row(factory, waiting).heartbeat_at or first_beat) > first_beat,
            "a heartbeat of the waiting job",
        )
        # The second worker thread runs another job while the first one waits.
        added = _submit(factory, registry, operator_id, "add", a=20, b=22)
        runner.dispatch(added)
        wait_until(lambda: job_row(factory, added).status == "succeeded", "the add job")
        assert job_row(factory, added).result == {"sum": 20 + 22, "operator_id": operator_id}
        assert job_row(factory, waiting).status == "running"
        assert not operator_exists(factory, "made by the waiting job")

        gates.release.set()
        wait_until(lambda: job_row(factory, waiting).status == "succeeded", "the waiting job")
        assert operator_exists(factory, "made by the waiting job")
    finally:
        gates.release.set()
        runner.stop()


def test_runner_threads_stop_a_cancelled_running_job(
    live: tuple[str, sessionmaker[Session]],
) -> None:
    _url, factory = live
    gates = Gates()
    registry = make_registry(gates)
    with transaction(factory) as session:
        operator, _key = make_operator(session, "Live Cancel Air")
        operator_id = operator.id
    runner = Runner(factory, registry, workers=1, poll_seconds=0.05, throttle_seconds=0.02)
    runner.start()
    try:
        job_id = _submit(factory, registry, operator_id, "spin", name="spun by the job")
        runner.dispatch(job_id)
        assert gates.started.wait(20)
        wait_until(lambda: job_row(factory, job_id).progress > 0, "progress of the spinning job")
        with transaction(factory) as session:
            store.cancel(session, operator_id=operator_id, job_id=job_id)
        # The worker thread is free again once the job has stopped: it runs the next one.
        added = _submit(factory, registry, operator_id, "add", a=1, b=1)
        runner.dispatch(added)
        wait_until(lambda: job_row(factory, added).status == "succeeded", "the next job")
        row = job_row(factory, job_id)
        assert row.status == "cancelled" and row.progress < 1.0
        # Committed chunks stay (jobs are idempotent per chunk); the open one is undone.
        assert operator_exists(factory, "spun by the job: first chunk")
        assert not operator_exists(factory, "spun by the job: last chunk")
    finally:
        runner.stop()


def test_concurrent_claims_take_every_job_exactly_once(
    live: tuple[str, sessionmaker[Session]],
) -> None:
    _url, factory = live
    registry = make_registry()
    with transaction(factory) as session:
        operator, _key = make_operator(session, "Claim Race Air")
        operator_id = operator.id
    submitted = [_submit(factory, registry, operator_id, "add", a=n) for n in range(40)]
    claims: list[list[int]] = [[] for _ in range(4)]
    start = threading.Barrier(len(claims))

    def take(mine: list[int]) -> None:
        start.wait()
        while (claim := claim_next(factory, worker=f"racer {id(mine)}")) is not None:
            mine.append(claim.job_id)

    threads = [threading.Thread(target=take, args=(mine,)) for mine in claims]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=60)
    taken = [job_id for mine in claims for job_id in mine]
    assert sorted(taken) == sorted(submitted)  # all taken, none twice
    assert {job_row(factory, job_id).attempts for job_id in submitted} == {1}


def test_runner_start_requeues_what_a_stopped_process_left_running(
    live: tuple[str, sessionmaker[Session]],
) -> None:
    _url, factory = live
    registry = make_registry()
    with transaction(factory) as session:
        operator, _key = make_operator(session, "Live Restart Air")
        operator_id = operator.id
    job_id = _submit(factory, registry, operator_id, "add", a=5, b=6)
    assert claim_next(factory, worker="the process that was killed") is not None
    with transaction(factory) as session:  # its last heartbeat was long ago
        session.execute(
            update(Job).where(Job.id == job_id).values(heartbeat_at=utcnow() - timedelta(hours=1))
        )
    runner = Runner(factory, registry, workers=1, poll_seconds=0.05)
    runner.start()
    try:
        wait_until(lambda: job_row(factory, job_id).status == "succeeded", "the requeued job")
    finally:
        runner.stop()
    row = job_row(factory, job_id)
    assert row.attempts == 2 and row.result == {"sum": 5 + 6, "operator_id": operator_id}


def test_a_job_that_reads_reports_and_writes_in_each_chunk_succeeds(live: Live) -> None:
    # On SQLite a progress write between the job's read and its write would leave the job's
    # transaction with a stale snapshot ("database is locked" at its write); the runner holds
    # such reports back until the job commits.
    _url, factory = live
    gates = Gates()
    registry = make_registry(gates)
    with transaction(factory) as session:
        operator, _key = make_operator(session, "Chunks Air")
        operator_id = operator.id
    runner = Runner(
        factory, registry, workers=1, poll_seconds=0.02, heartbeat_seconds=0.01, throttle_seconds=0
    )
    runner.start()
    try:
        job_id = _submit(factory, registry, operator_id, "chunks", name="chunked")
        runner.dispatch(job_id)
        assert gates.started.wait(20), "the first chunk never committed"
        row = job_row(factory, job_id)
        assert (row.status, row.message) == ("running", "chunked: chunk 0")
        gates.release.set()
        wait_until(lambda: job_row(factory, job_id).status != "running", "the chunked job")
    finally:
        gates.release.set()
        runner.stop()
    row = job_row(factory, job_id)
    assert (row.status, row.error, row.result) == ("succeeded", None, {"chunks": 3})
    with transaction(factory) as session:
        names = session.scalars(select(Operator.name).where(Operator.name.like("chunked %")))
        # Each chunk saw the rows of the chunks before it (and the one operator made above).
        assert sorted(names) == [f"chunked {chunk} after {chunk + 1}" for chunk in range(3)]


def test_the_runner_sweep_requeues_dead_workers_jobs_but_not_its_own(live: Live) -> None:
    # Heartbeats off and a tiny stale time: the runner's own waiting job looks stale too, as a
    # job holding SQLite's write lock does. Only the dead worker's job may be requeued.
    _url, factory = live
    gates = Gates()
    registry = make_registry(gates)
    with transaction(factory) as session:
        operator, _key = make_operator(session, "Sweep Air")
        operator_id = operator.id
    runner = Runner(
        factory,
        registry,
        workers=2,
        poll_seconds=0.02,
        heartbeat_seconds=1000,
        stale_after=timedelta(seconds=0.2),
    )
    runner.start()
    try:
        own = _submit(factory, registry, operator_id, "wait", name="waited for the sweep")
        runner.dispatch(own)
        assert gates.started.wait(20)
        # Once the runner's own job looks stale, any sweep that requeues the dead worker's job
        # below would requeue it too, were it not known to be alive.
        wait_until(
            lambda: (
                utcnow() - (job_row(factory, own).heartbeat_at or utcnow()) > timedelta(seconds=0.5)
            ),
            "the runner's own job to look stale",
        )
        # A job another process claimed before it died.
        parameters = AddParameters(a=30, b=12)
        with transaction(factory) as session:
            row = Job(
                operator_id=operator_id,
                kind="add",
                parameters=parameters.model_dump(),
                checksum=parameters_checksum("add", parameters),
                status="running",
                attempts=1,
                heartbeat_at=utcnow() - timedelta(hours=1),
            )
            session.add(row)
            session.flush()
            dead = row.id
        wait_until(lambda: job_row(factory, dead).status == "succeeded", "the dead worker's job")
        assert job_row(factory, dead).attempts == 2
        gates.release.set()
        wait_until(lambda: job_row(factory, own).status == "succeeded", "the runner's own job")
        assert job_row(factory, own).attempts == 1
    finally:
        gates.release.set()
        runner.stop()


def test_the_app_runs_jobs_in_process_when_background_jobs_are_on(
    live: tuple[str, sessionmaker[Session]], tmp_path: Path
) -> None:
    url, factory = live
    with transaction(factory) as session:
        _operator, key = make_operator(session, "Embedded Air", role="analyst")
    # Threads: the test's own job kinds (a child process would load the product's).
    settings = Settings(data_dir=tmp_path / "data", database_url=url, log_json=False,
                        job_host="thread")
    app = create_app(settings, background_jobs=True)
    app.state.job_registry = make_registry()
    with TestClient(app) as client:
        headers = {"X-API-Key": key}
        response = client.post(
            "/api/v1/jobs", json={"kind": "add", "parameters": {"a": 8, "b": 9}}, headers=headers
        )
        assert response.status_code == 202
        job_url = f"/api/v1/jobs/{response.json()['id']}"
        wait_until(
            lambda: client.get(job_url, headers=headers).json()["status"] == "succeeded",
            "the job submitted over the API",
        )
        assert client.get(job_url, headers=headers).json()["result"]["sum"] == 8 + 9
