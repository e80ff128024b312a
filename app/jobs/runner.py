"""Claiming and running jobs: the code every runner shares, and the in-process thread pool.

The in-process ``Runner`` (embedded default) and the Celery task ``run_job`` (deployment) both
claim a job with one atomic UPDATE and run it with ``execute``. Tests run queued jobs
synchronously with ``run_pending(session_factory)``.
"""

from __future__ import annotations

import json
import logging
import math
import os
import socket
import threading
import time
from collections.abc import Callable, Collection, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

from sqlalchemy import event, or_, select, true, update
from sqlalchemy.exc import OperationalError
from sqlalchemy.orm import Session, aliased, sessionmaker

from app.db import transaction
from app.errors import ServiceError
from app.jobs.kinds import load_kinds
from app.models.base import utcnow
from app.models.jobs import Job
from app.services.jobs.dispatch import Dispatcher
from app.services.jobs.registry import JobCancelled, JobRegistry

log = logging.getLogger("fleethealth.jobs")

SessionFactory = sessionmaker[Session]

# A worker that stopped (killed process, lost machine) leaves its job 'running' without
# heartbeats; after STALE_AFTER the job is requeued, at most MAX_ATTEMPTS claims in all.
HEARTBEAT_SECONDS = 15.0
STALE_AFTER = timedelta(seconds=120)
MAX_ATTEMPTS = 3
PROGRESS_THROTTLE_SECONDS = 0.5
# While a job's own transaction holds SQLite's single write lock, a progress write would wait;
# it gives up quickly instead and the next report tries again.
SQLITE_PROGRESS_WAIT_MS = 200


def worker_name(prefix: str) -> str:
    return f"{prefix}:{socket.gethostname()}:{os.getpid()}:{threading.get_ident()}"


@dataclass(frozen=True)
class Claim:
    """A job this worker owns: every later write is conditioned on ``attempt``."""

    job_id: int
    attempt: int


def _claim_values(worker: str) -> dict[str, Any]:
    now = utcnow()
    return {
        "status": "running",
        "attempts": Job.attempts + 1,
        "started_at": now,
        "heartbeat_at": now,
        "worker": worker[:200],
        "message": "running",
    }


def claim_next(
    factory: SessionFactory, *, worker: str, serial_kinds: Sequence[str] = ()
) -> Claim | None:
    """Atomically take the oldest queued job that may start, or None when there is none.

    One UPDATE ... WHERE status = 'queued' RETURNING: of two workers racing for a job only one
    gets the row back. On PostgreSQL the inner SELECT skips rows another worker has locked.
    An idle worker only reads: on SQLite even an UPDATE of no rows takes the one write lock.
    A job of a kind in ``serial_kinds`` waits while one of its kind runs for its operator.
    """
    with transaction(factory) as session:
        if session.scalar(select(Job.id).where(Job.status == "queued").limit(1)) is None:
            return None
    oldest = (
        select(Job.id)
        .where(Job.status == "queued", _may_start(serial_kinds))
        .order_by(Job.id)
        .limit(1)
        .with_for_update(skip_locked=True)
        .scalar_subquery()
    )
    return _claim(factory, Job.id == oldest, worker, serial_kinds)


def claim_job(
    factory: SessionFactory, job_id: int, *, worker: str, serial_kinds: Sequence[str] = ()
) -> Claim | None:
    """Atomically take job ``job_id`` if it is still queued and may start (a Celery message
    names its job; one that must wait stays queued for the next tick's message)."""
    return _claim(factory, Job.id == job_id, worker, serial_kinds)


def _may_start(serial_kinds: Sequence[str]) -> Any:
    """A queued job may start unless its kind is serial and one of its kind runs for its
    operator. (At most one job of a serial kind is queued per operator, see
    ``app.services.jobs.store.queue_estimation``, so two claims cannot both pass.)"""
    if not serial_kinds:
        return true()
    running = aliased(Job)
    sibling = (
        select(running.id)
        .where(running.operator_id == Job.operator_id, running.kind == Job.kind,
               running.status == "running")
        .exists()
    )
    return or_(Job.kind.not_in(list(serial_kinds)), ~sibling)


def _claim(
    factory: SessionFactory, which: Any, worker: str, serial_kinds: Sequence[str] = ()
) -> Claim | None:
    with transaction(factory) as session:
        row = session.execute(
            update(Job)
            .where(which, Job.status == "queued", _may_start(serial_kinds))
            .values(**_claim_values(worker))
            .returning(Job.id, Job.attempts),
            execution_options={"synchronize_session": False},
        ).first()
    return None if row is None else Claim(job_id=row[0], attempt=row[1])


def _owned(claim: Claim) -> tuple[Any, ...]:
    return (Job.id == claim.job_id, Job.status == "running", Job.attempts == claim.attempt)


@contextmanager
def _short_write(factory: SessionFactory) -> Iterator[Session]:
    """A short transaction that gives up fast on a locked SQLite file (raises OperationalError)."""
    with transaction(factory) as session:
        connection = session.connection()
        if connection.dialect.name != "sqlite":
            yield session
            return
        previous = connection.exec_driver_sql("PRAGMA busy_timeout").scalar()
        connection.exec_driver_sql(f"PRAGMA busy_timeout = {SQLITE_PROGRESS_WAIT_MS}")
        try:
            yield session
        finally:
            connection.exec_driver_sql(f"PRAGMA busy_timeout = {int(previous or 0)}")


def _locked(exc: OperationalError) -> bool:
    return "database is locked" in str(exc.orig)


class SqliteTransactionWatch:
    """Makes a job's SQLite transactions take the write lock at once, and tells when they do.

    SQLite has one writer. A transaction that reads and later writes fails ("database is
    locked") if another connection committed in between, since its snapshot is stale; so a
    job's transaction begins IMMEDIATE: it holds the lock from its first statement to its
    commit, and other writers wait for it instead. Meanwhile ``busy()`` is true: the job's
    progress is held back and its heartbeat skipped, both written after its commit. Other
    databases are never busy.
    """

    def __init__(self, session: Session) -> None:
        self._dbapi: Any = None
        event.listen(session, "after_begin", self._begun)
        event.listen(session, "after_transaction_end", self._ended)

    def _begun(self, _session: Session, _transaction: object, connection: Any) -> None:
        if connection.dialect.name != "sqlite" or connection.in_nested_transaction():
            return  # a savepoint inside a caller's transaction (tests) is not ours to change
        dbapi = connection.connection.dbapi_connection
        if dbapi.in_transaction:
            # A deferred BEGIN was sent (nothing ran yet): begin again, taking the lock.
            connection.exec_driver_sql("ROLLBACK")
        connection.exec_driver_sql("BEGIN IMMEDIATE")
        self._dbapi = dbapi

    def _ended(self, session: Session, _transaction: object) -> None:
        if not session.in_transaction():
            self._dbapi = None

    def busy(self) -> bool:
        # sqlite3's in_transaction is safe to read from the heartbeat thread.
        dbapi = self._dbapi
        return dbapi is not None and bool(dbapi.in_transaction)


def _never_busy() -> bool:
    return False


class ProgressReporter:
    """The ``progress(fraction, message)`` callback a job function receives.

    Writes at most every ``throttle_seconds`` (the first report always), each in its own short
    transaction, so the dashboard sees it while the job's own transaction is still open. Raises
    ``JobCancelled`` when the write finds the job no longer running under this claim. While
    ``busy()`` (see ``SqliteTransactionWatch``) reports are kept and written by ``flush()``,
    which the runner calls when the job's session commits.
    """

    def __init__(
        self,
        factory: SessionFactory,
        claim: Claim,
        *,
        throttle_seconds: float = PROGRESS_THROTTLE_SECONDS,
        clock: Callable[[], float] = time.monotonic,
        busy: Callable[[], bool] = _never_busy,
    ) -> None:
        self._factory = factory
        self._claim = claim
        self._throttle = throttle_seconds
        self._clock = clock
        self._busy = busy
        self._last_write: float | None = None
        self._unwritten = False
        self.finished = False
        self.fraction = 0.0
        self.message = "running"

    def __call__(self, fraction: float, message: str | None = None) -> None:
        if not (math.isfinite(fraction) and 0.0 <= fraction <= 1.0):
            raise ValueError(f"progress must be a fraction between 0 and 1, not {fraction!r}")
        self.fraction = float(fraction)
        if message is not None:
            self.message = message[:500]
        self._unwritten = True
        now = self._clock()
        if self._last_write is not None and now - self._last_write < self._throttle:
            return
        if self._busy():
            return
        self._last_write = now
        self._write()

    def flush(self) -> None:
        """Write the latest report if it was held back; never raises (called at commit)."""
        if not self._unwritten or self.finished:
            return
        try:
            self._write()
        except Exception as exc:  # cancellation is seen at the next report or the end
            log.debug("progress of job %s not written at commit: %s", self._claim.job_id, exc)

    def _write(self) -> None:
        self._unwritten = False
        try:
            with _short_write(self._factory) as session:
                written = session.execute(
                    update(Job)
                    .where(*_owned(self._claim))
                    .values(progress=self.fraction, message=self.message, heartbeat_at=utcnow()),
                    execution_options={"synchronize_session": False},
                ).rowcount  # type: ignore[attr-defined]
        except OperationalError as exc:
            if not _locked(exc):
                raise
            self._last_write = None  # another connection holds the lock; report again next time
            self._unwritten = True
            return
        if written == 0:
            raise JobCancelled(f"job {self._claim.job_id} is no longer running here")


class Heartbeat:
    """Marks a running job alive every ``interval`` seconds from a daemon thread."""

    def __init__(
        self,
        factory: SessionFactory,
        claim: Claim,
        interval: float,
        busy: Callable[[], bool] = _never_busy,
    ) -> None:
        self._factory = factory
        self._claim = claim
        self._interval = interval
        self._busy = busy
        self._stop = threading.Event()
        self._thread = threading.Thread(
            target=self._beat, name=f"job-{claim.job_id}-heartbeat", daemon=True
        )
        self._thread.start()

    def _beat(self) -> None:
        while not self._stop.wait(self._interval):
            if self._busy():
                continue  # the job's transaction is open; its runner knows it is alive
            try:
                with _short_write(self._factory) as session:
                    written = session.execute(
                        update(Job).where(*_owned(self._claim)).values(heartbeat_at=utcnow()),
                        execution_options={"synchronize_session": False},
                    ).rowcount  # type: ignore[attr-defined]
            except OperationalError as exc:
                log.debug("heartbeat of job %s skipped: %s", self._claim.job_id, exc)
                continue
            if written == 0:
                return

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


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
    busy = SqliteTransactionWatch(session).busy if sqlite_guard else _never_busy
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
                .where(*_owned(claim))
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
            .where(*_owned(claim))
            .values(status="failed", error=error, message="failed", finished_at=utcnow()),
            execution_options={"synchronize_session": False},
        )
    return _status(factory, claim.job_id)


def _status(factory: SessionFactory, job_id: int) -> str:
    with transaction(factory) as session:
        return session.scalar(select(Job.status).where(Job.id == job_id)) or "missing"


def requeue_stale(
    factory: SessionFactory,
    *,
    stale_after: timedelta = STALE_AFTER,
    max_attempts: int = MAX_ATTEMPTS,
    now: datetime | None = None,
    alive: Collection[int] = (),
) -> list[int]:
    """Requeue running jobs whose worker stopped beating; fail those out of attempts.

    ``alive``: jobs the caller knows are running (its own threads), whatever their heartbeat
    says (on SQLite a job's open write transaction blocks its heartbeats). Returns the ids
    requeued (a Celery deployment sends them to the workers again).
    """
    cutoff = (now or utcnow()) - stale_after
    stale = (Job.status == "running", Job.heartbeat_at < cutoff, Job.id.not_in(list(alive)))
    with transaction(factory) as session:
        session.execute(
            update(Job)
            .where(*stale, Job.attempts >= max_attempts)
            .values(
                status="failed",
                finished_at=utcnow(),
                message="failed",
                error=f"its worker stopped {max_attempts} times; not retried again",
            ),
            execution_options={"synchronize_session": False},
        )
        requeued = session.execute(
            update(Job)
            .where(*stale, Job.attempts < max_attempts)
            .values(status="queued", message="requeued: its worker stopped", worker=None)
            .returning(Job.id),
            execution_options={"synchronize_session": False},
        ).scalars()
        ids = sorted(requeued)
    if ids:
        log.warning("requeued jobs whose worker stopped: %s", ids)
    return ids


def queued_before(factory: SessionFactory, cutoff: datetime) -> list[int]:
    """Ids of jobs still queued that were created before ``cutoff`` (their message was lost)."""
    with transaction(factory) as session:
        return list(
            session.scalars(
                select(Job.id).where(Job.status == "queued", Job.created_at < cutoff)
            ).all()
        )


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

    On start, and then every ``stale_after / 2`` from an idle worker, it requeues jobs whose
    worker stopped beating (a previous process, killed). ``dispatch(job_id)`` wakes an idle
    worker at once; otherwise workers look for queued jobs every ``poll_seconds``.
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
