"""Running claimed jobs: the code every runner shares, and the in-process thread pool.

The in-process ``Runner`` (embedded default) and the Celery task ``run_job`` (deployment) both
claim a job with one atomic UPDATE (``app.jobs.claim``) and run it with ``execute``, which
reports progress and beats through ``app.jobs.progress``. Tests run queued jobs synchronously
with ``run_pending(session_factory)``.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from datetime import timedelta
from typing import Any

from sqlalchemy import event, select, update
from sqlalchemy.orm import Session

from app.db import transaction
from app.errors import ServiceError
from app.jobs.claim import (
    HEARTBEAT_SECONDS,
    STALE_AFTER,
    Claim,
    SessionFactory,
    claim_next,
    owned,
    requeue_orphans,
    requeue_stale,
    worker_name,
)
from app.jobs.kinds import load_kinds
from app.jobs.progress import (
    PROGRESS_THROTTLE_SECONDS,
    Heartbeat,
    ProgressReporter,
    SqliteTransactionWatch,
    never_busy,
)
from app.models.base import utcnow
from app.models.jobs import Job
from app.services.jobs.dispatch import Dispatcher
from app.services.jobs.registry import JobCancelled, JobRegistry

log = logging.getLogger("fleethealth.jobs")


def execute(
    factory: SessionFactory,
    claim: Claim,
    registry: JobRegistry,
    *,
    throttle_seconds: float = PROGRESS_THROTTLE_SECONDS,
    heartbeat_seconds: float | None = HEARTBEAT_SECONDS,
    dispatcher: Dispatcher | None = None,
    sqlite_guard: bool = True,
) -> str:
    """Run a claimed job to its end and return its final status.

    The function runs in its own session; its result and the status 'succeeded' are written in
    that same transaction, so the work and the record of it commit together. An exception rolls
    the work back and records the error; ``JobCancelled`` rolls back and leaves 'cancelled'.
    ``heartbeat_seconds=None`` runs without a heartbeat thread (synchronous tests, whose
    session factory shares one connection). Jobs the function queues (``store.submit`` on its
    session) go to ``dispatcher`` once the session commits them. ``sqlite_guard`` holds
    progress and heartbeats back while the job's SQLite transaction is open (see
    ``SqliteTransactionWatch``); ``run_pending`` turns it off, having no other writers.
    """
    with transaction(factory) as session:
        job = session.get(Job, claim.job_id)
        assert job is not None, f"claimed job {claim.job_id} vanished"
        kind_name, raw_parameters, operator_id = job.kind, job.parameters, job.operator_id
    try:
        kind = registry.get(kind_name)
        parameters = kind.validate(raw_parameters)
    except ServiceError as exc:
        return _record_failure(factory, claim, exc.message)

    session = factory()
    busy = SqliteTransactionWatch(session).busy if sqlite_guard else never_busy
    progress = ProgressReporter(factory, claim, throttle_seconds=throttle_seconds, busy=busy)
    _flush_at_commit(session, progress)
    if dispatcher is not None:
        _dispatch_queued_jobs(session, dispatcher)
    heartbeat = Heartbeat(factory, claim, heartbeat_seconds, busy) if heartbeat_seconds else None
    try:
        try:
            result = kind.function(session, parameters, progress, operator_id=operator_id)
            result = _json_result(kind_name, result)
        except JobCancelled:
            session.rollback()
            log.info("job %s (%s) stopped: cancelled", claim.job_id, kind_name)
            return _status(factory, claim.job_id)
        except Exception as exc:  # the job's own failure is recorded, never raised to the runner
            session.rollback()
            log.exception("job %s (%s) failed", claim.job_id, kind_name)
            return _record_failure(factory, claim, f"{type(exc).__name__}: {exc}")
        progress.finished = True
        try:
            now = utcnow()
            done = session.execute(
                update(Job)
                .where(*owned(claim))
                .values(
                    status="succeeded",
                    progress=1.0,
                    message=progress.message if progress.message != "running" else "done",
                    result=result,
                    finished_at=now,
                    heartbeat_at=now,
                ),
                execution_options={"synchronize_session": False},
            )
            if done.rowcount == 0:  # type: ignore[attr-defined]
                # Cancelled (or requeued as stale) after the last progress report: undo it all.
                session.rollback()
                return _status(factory, claim.job_id)
            session.commit()
        except Exception as exc:  # e.g. the commit broke a constraint: the work is not stored
            session.rollback()
            log.exception("job %s (%s) could not commit", claim.job_id, kind_name)
            return _record_failure(factory, claim, f"{type(exc).__name__}: {exc}")
        return "succeeded"
    finally:
        session.close()
        if heartbeat is not None:
            heartbeat.stop()


def _flush_at_commit(session: Session, progress: ProgressReporter) -> None:
    """Write held-back progress as soon as the job's session commits (its lock is free)."""

    def flush(committed: Session) -> None:
        if not committed.in_nested_transaction():
            progress.flush()

    event.listen(session, "after_commit", flush)


def _dispatch_queued_jobs(session: Session, dispatcher: Dispatcher) -> None:
    """Hand every job queued in ``session`` to ``dispatcher`` when (and if) it commits."""
    queued: list[int] = []

    def collect(_session: Session, instance: object) -> None:
        if isinstance(instance, Job):
            queued.append(instance.id)

    def send(committed: Session) -> None:
        if committed.in_nested_transaction():  # a savepoint: not visible to workers yet
            return
        ids = list(queued)
        queued.clear()
        for job_id in ids:
            dispatcher.dispatch(job_id)

    def forget(_session: Session) -> None:
        queued.clear()

    event.listen(session, "pending_to_persistent", collect)
    event.listen(session, "after_commit", send)
    event.listen(session, "after_rollback", forget)


def _json_result(kind: str, result: object) -> dict[str, Any]:
    if not isinstance(result, dict):
        raise TypeError(f"job kind {kind!r} returned {type(result).__name__}, not a dict")
    # Round-trip so a result that JSON cannot hold fails here, not at commit.
    loaded: dict[str, Any] = json.loads(json.dumps(result, allow_nan=False))
    return loaded


MAX_ERROR_CHARS = 4000


def _record_failure(factory: SessionFactory, claim: Claim, error: str) -> str:
    if len(error) > MAX_ERROR_CHARS:  # database errors quote whole statements and parameters
        error = error[: MAX_ERROR_CHARS - 15] + " ... (cut off)"
    with transaction(factory) as session:
        session.execute(
            update(Job)
            .where(*owned(claim))
            .values(status="failed", error=error, message="failed", finished_at=utcnow()),
            execution_options={"synchronize_session": False},
        )
    return _status(factory, claim.job_id)


def _status(factory: SessionFactory, job_id: int) -> str:
    with transaction(factory) as session:
        return session.scalar(select(Job.status).where(Job.id == job_id)) or "missing"


def run_pending(
    factory: SessionFactory,
    registry: JobRegistry | None = None,
    *,
    throttle_seconds: float = 0.0,
) -> list[int]:
    """Run every queued job here and now, one after another; return their ids in order.

    For tests and one-shot commands: no threads, no heartbeat, so it works with a session
    factory bound to a single connection.
    """
    registry = registry or load_kinds()
    worker = worker_name("inline")
    ran: list[int] = []
    serial = registry.serial_kinds()
    while (claim := claim_next(factory, worker=worker, serial_kinds=serial)) is not None:
        execute(
            factory,
            claim,
            registry,
            throttle_seconds=throttle_seconds,
            heartbeat_seconds=None,
            sqlite_guard=False,
        )
        ran.append(claim.job_id)
    return ran


class Runner:
    """The embedded default's job runner: ``workers`` threads claiming queued jobs.

    On start it requeues the jobs a stopped process of this host left running (orphans, at
    once); on start and then every ``stale_after / 2`` from an idle worker, jobs whose worker
    stopped beating (a previous process, killed, here or elsewhere). ``dispatch(job_id)``
    wakes an idle worker at once; otherwise workers look for queued jobs every
    ``poll_seconds``.
    """

    def __init__(
        self,
        factory: SessionFactory,
        registry: JobRegistry,
        *,
        workers: int = 2,
        poll_seconds: float = 2.0,
        heartbeat_seconds: float = HEARTBEAT_SECONDS,
        stale_after: timedelta = STALE_AFTER,
        throttle_seconds: float = PROGRESS_THROTTLE_SECONDS,
    ) -> None:
        if workers < 1:
            raise ValueError("a runner needs at least one worker thread")
        self._factory = factory
        self._registry = registry
        self._workers = workers
        self._poll = poll_seconds
        self._heartbeat = heartbeat_seconds
        self._stale_after = stale_after
        self._throttle = throttle_seconds
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._lock = threading.Lock()
        self._last_sweep = time.monotonic()
        self._running: set[int] = set()

    def start(self) -> None:
        requeue_orphans(self._factory)
        requeue_stale(self._factory, stale_after=self._stale_after)
        self._last_sweep = time.monotonic()
        for number in range(self._workers):
            thread = threading.Thread(target=self._work, name=f"job-worker-{number}", daemon=True)
            thread.start()
            self._threads.append(thread)

    def dispatch(self, job_id: int) -> None:
        self._wake.set()

    def stop(self, timeout: float = 10.0) -> None:
        """Stop claiming; wait up to ``timeout`` s for running jobs (the rest are requeued
        as stale by the next start)."""
        self._stop.set()
        self._wake.set()
        deadline = time.monotonic() + timeout
        for thread in self._threads:
            thread.join(timeout=max(0.0, deadline - time.monotonic()))
        self._threads.clear()

    def _sweep_if_due(self) -> None:
        """Requeue stale jobs now and then (a process restarted sooner than ``stale_after``
        finds its old jobs still fresh at start)."""
        with self._lock:
            if time.monotonic() - self._last_sweep < self._stale_after.total_seconds() / 2:
                return
            self._last_sweep = time.monotonic()
            alive = set(self._running)
        requeue_stale(self._factory, stale_after=self._stale_after, alive=alive)

    def _work(self) -> None:
        worker = worker_name("inprocess")
        while not self._stop.is_set():
            try:
                claim = claim_next(
                    self._factory, worker=worker, serial_kinds=self._registry.serial_kinds()
                )
                if claim is not None:
                    with self._lock:
                        self._running.add(claim.job_id)
                    try:
                        execute(
                            self._factory,
                            claim,
                            self._registry,
                            throttle_seconds=self._throttle,
                            heartbeat_seconds=self._heartbeat,
                            dispatcher=self,
                        )
                    finally:
                        with self._lock:
                            self._running.discard(claim.job_id)
                    continue
                self._sweep_if_due()
            except Exception:  # a database hiccup must not kill the worker thread
                log.exception("job worker %s: claiming or running a job failed", worker)
            # Leave the event set while stopping so every other worker thread sees it too.
            if self._wake.wait(self._poll) and not self._stop.is_set():
                self._wake.clear()
