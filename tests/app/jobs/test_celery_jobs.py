"""A real Celery worker (``fleethealth worker`` in a subprocess) runs a job against Redis.

Skips with a reason where Redis does not answer, except under CI (``CI`` set), where that is an
error: CI on this machine must run it.
"""

from __future__ import annotations

import os
import subprocess
import sys
import uuid
from collections.abc import Iterator
from datetime import timedelta
from pathlib import Path

import pytest
from sqlalchemy import select, update
from sqlalchemy.orm import Session, sessionmaker

from app.db import transaction
from app.jobs.celery_app import CeleryDispatch
from app.jobs.celery_tasks import celery
from app.jobs.kinds import load_kinds
from app.models import Job
from app.models.base import utcnow
from app.services.jobs import store
from tests.support.jobs import job_row, live, live_module, make_operator, wait_until
from tests.support.paths import ROOT

__all__ = ["live", "live_module"]  # fixtures from jobs_support


def redis_unavailable_reason(url: str) -> str | None:
    import redis

    try:
        redis.Redis.from_url(url, socket_connect_timeout=3).ping()
    except Exception as exc:  # any failure to reach the server means: no Redis here
        return f"no Redis at {url}: {exc}"
    return None


@pytest.fixture(scope="module")
def redis_url() -> str:
    url = str(celery.conf.broker_url)
    reason = redis_unavailable_reason(url)
    if reason is not None:
        if os.environ.get("CI"):
            pytest.fail(f"CI must run the Celery tests, but {reason}")
        pytest.skip(reason)
    return url


@pytest.fixture
def left_running(live: tuple[str, sessionmaker[Session]]) -> int:
    """A job a crashed worker left running an hour ago, there before the worker starts."""
    _url, factory = live
    registry = load_kinds()
    with transaction(factory) as session:
        operator, _key = make_operator(session, "Crashed Worker Air")
        job, _ = store.submit(
            session,
            operator_id=operator.id,
            kind="purge_finished_jobs",
            parameters={"older_than_days": 365},
            registry=registry,
        )
        job.status, job.attempts, job.worker = "running", 1, "celery:a crashed worker"
        job.heartbeat_at = utcnow() - timedelta(hours=1)
        return job.id


@pytest.fixture
def worker_queue(
    live: tuple[str, sessionmaker[Session]], redis_url: str, tmp_path: Path, left_running: int
) -> Iterator[str]:
    """``fleethealth worker`` on its own queue and the test database; stopped afterwards."""
    import redis

    url, _factory = live
    queue = f"fleethealth-test-{uuid.uuid4().hex[:12]}"
    env = {
        **os.environ,
        "FLEETHEALTH_DATABASE_URL": url,
        "FLEETHEALTH_REDIS_URL": redis_url,
        "FLEETHEALTH_DATA_DIR": str(tmp_path / "worker-data"),
        "FLEETHEALTH_LOG_JSON": "false",
    }
    log_path = tmp_path / "worker.log"
    with log_path.open("w") as log:
        worker = subprocess.Popen(
            [sys.executable, "-c", "from app.cli import main; main()", "worker"]
            + ["--concurrency", "1", "--queue", queue],
            cwd=ROOT,
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
    try:
        yield queue
    finally:
        worker.terminate()
        try:
            worker.wait(timeout=20)
        except subprocess.TimeoutExpired:
            worker.kill()
            worker.wait(timeout=10)
        client = redis.Redis.from_url(redis_url)
        client.delete(queue, f"_kombu.binding.{queue}")
        print(log_path.read_text()[-4000:])  # shown by pytest when the test failed


def test_a_celery_worker_runs_a_job_to_completion(
    live: tuple[str, sessionmaker[Session]], worker_queue: str, left_running: int
) -> None:
    _url, factory = live
    registry = load_kinds()
    now = utcnow()
    with transaction(factory) as session:
        operator, _key = make_operator(session, "Celery Air")
        operator_id = operator.id
        days_ago = [3, 10, 45, 60, 90]
        for index, days in enumerate(days_ago):
            session.add(
                Job(
                    operator_id=operator_id,
                    kind="purge_finished_jobs",
                    parameters={"case": index},
                    checksum=f"case-{index}",
                    status="succeeded",
                    finished_at=now - timedelta(days=days),
                )
            )
    with transaction(factory) as session:
        job, created = store.submit(
            session,
            operator_id=operator_id,
            kind="purge_finished_jobs",
            parameters={"older_than_days": 30, "batch_size": 2},
            registry=registry,
        )
        store.dispatch_after_commit(session, CeleryDispatch(worker_queue).dispatch, job.id)
        job_id = job.id
    assert created

    wait_until(
        lambda: job_row(factory, job_id).status not in ("queued", "running"),
        "the Celery worker to finish the job",
        timeout=60,
    )
    done = job_row(factory, job_id)
    assert done.status == "succeeded", done.error
    expected = sum(1 for days in days_ago if days > 30)
    assert done.result is not None and done.result["deleted"] == expected
    assert done.worker is not None and done.worker.startswith("celery:")
    assert done.message == f"deleted {expected} of {expected} finished jobs"
    with transaction(factory) as session:
        left = session.scalars(
            select(Job.finished_at).where(Job.operator_id == operator_id, Job.id != job_id)
        ).all()
    assert sorted(now - finished for finished in left if finished is not None) == [
        timedelta(days=days) for days in sorted(days_ago) if days <= 30
    ]

    # A second message for the finished job (a duplicate delivery) changes nothing: the worker
    # takes messages in order, so once a later job is done the duplicate was handled.
    CeleryDispatch(worker_queue).dispatch(job_id)
    with transaction(factory) as session:
        later, _ = store.submit(
            session,
            operator_id=operator_id,
            kind="purge_finished_jobs",
            parameters={"older_than_days": 1},
            registry=registry,
        )
        store.dispatch_after_commit(session, CeleryDispatch(worker_queue).dispatch, later.id)
        later_id = later.id
    wait_until(
        lambda: job_row(factory, later_id).status == "succeeded", "the later job", timeout=60
    )
    again = job_row(factory, job_id)
    assert (again.status, again.attempts, again.result) == ("succeeded", 1, done.result)

    # The job the crashed worker left was requeued when this worker started, and run again.
    wait_until(
        lambda: job_row(factory, left_running).status == "succeeded", "the left job", timeout=60
    )
    rerun = job_row(factory, left_running)
    assert rerun.attempts == 2 and rerun.worker != "celery:a crashed worker"


def test_beat_sends_the_tick_and_the_tick_submits_requeues_and_resends(
    live: tuple[str, sessionmaker[Session]], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The tick's bookkeeping, called as the worker would (no broker needed: sends recorded)."""
    from app.jobs import celery_tasks
    from app.jobs.claim import claim_next
    from app.services.jobs.schedules import create_schedule
    from tests.support.jobs import make_registry

    entries = celery.conf.beat_schedule.values()
    assert {entry["task"] for entry in entries} == {celery_tasks.tick.name}
    assert celery_tasks.tick.name in celery.tasks and celery_tasks.run_job.name in celery.tasks

    _url, factory = live
    registry = make_registry()
    sent: list[int] = []
    monkeypatch.setattr(CeleryDispatch, "dispatch", lambda self, job_id: sent.append(job_id))
    monkeypatch.setattr(celery_tasks, "_context", None)
    celery_tasks.configure(factory, registry)
    long_ago = utcnow() - timedelta(hours=1)
    with transaction(factory) as session:
        operator, _key = make_operator(session, "Tick Air")
        operator_id = operator.id
        schedule = create_schedule(
            session,
            operator_id=operator_id,
            kind="add",
            parameters={"a": 1},
            interval_seconds=3600,
            registry=registry,
            first_run_at=long_ago,
        )
        schedule_id = schedule.id
    with transaction(factory) as session:
        stale, _ = store.submit(
            session, operator_id=operator_id, kind="add", parameters={"a": 2}, registry=registry
        )
        lost, _ = store.submit(
            session, operator_id=operator_id, kind="add", parameters={"a": 3}, registry=registry
        )
        stale_id, lost_id = stale.id, lost.id
    assert claim_next(factory, worker="a worker that died") is not None  # takes `stale`
    with transaction(factory) as session:
        session.execute(update(Job).where(Job.id == stale_id).values(heartbeat_at=long_ago))
        session.execute(update(Job).where(Job.id == lost_id).values(created_at=long_ago))
    try:
        outcome = celery_tasks.tick()
    finally:
        monkeypatch.setattr(celery_tasks, "_context", None)

    scheduled = outcome["submitted"]
    assert len(scheduled) == 1 and job_row(factory, scheduled[0]).schedule_id == schedule_id
    assert (outcome["requeued"], outcome["resent"]) == ([stale_id], [lost_id])
    assert sorted(sent) == sorted([stale_id, lost_id, *scheduled])
    assert job_row(factory, stale_id).status == "queued"


def test_an_app_set_to_celery_sends_jobs_to_the_broker_and_runs_none_itself(
    live: tuple[str, sessionmaker[Session]], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from fastapi.testclient import TestClient

    from app.config import Settings
    from app.main import create_app
    from tests.support.jobs import make_registry

    url, factory = live
    with transaction(factory) as session:
        _operator, key = make_operator(session, "Celery App Air", role="analyst")
    sent: list[int] = []
    monkeypatch.setattr(CeleryDispatch, "dispatch", lambda self, job_id: sent.append(job_id))
    settings = Settings(
        data_dir=tmp_path / "data", database_url=url, log_json=False, job_runner="celery"
    )
    app = create_app(settings, background_jobs=True)
    app.state.job_registry = make_registry()
    with TestClient(app) as client:
        assert isinstance(app.state.job_dispatcher, CeleryDispatch)
        response = client.post(
            "/api/v1/jobs",
            json={"kind": "add", "parameters": {"a": 1}},
            headers={"X-API-Key": key},
        )
        assert response.status_code == 202
    job_id = response.json()["id"]
    assert sent == [job_id]
    assert job_row(factory, job_id).status == "queued"  # no runner in the API process
