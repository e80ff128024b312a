"""A running job's writes besides its own transaction: throttled progress reports, the
heartbeat thread, and the watch that holds both back while the job's SQLite transaction holds
the database's one write lock.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from sqlalchemy import event, update
from sqlalchemy.exc import OperationalError
from sqlalchemy.orm import Session

from app.db import BUSY_TIMEOUT_S, WriteGate, in_read_phase, transaction, write_gate
from app.errors import ServiceUnavailable
from app.jobs.claim import Claim, SessionFactory, owned
from app.models.base import utcnow
from app.models.jobs import Job
from app.services.jobs.registry import JobCancelled

log = logging.getLogger("fleethealth.jobs")

PROGRESS_THROTTLE_SECONDS = 0.5
# While a job's own transaction holds SQLite's single write lock, a progress write would wait;
# it gives up quickly instead and the next report tries again.
SQLITE_PROGRESS_WAIT_MS = 200


@contextmanager
def short_write(factory: SessionFactory) -> Iterator[Session]:
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


def locked(exc: OperationalError) -> bool:
    return "database is locked" in str(exc.orig)


class SqliteTransactionWatch:
    """Makes a job's SQLite transactions take the write lock at once, and tells when they do.

    SQLite has one writer. A transaction that reads and later writes fails ("database is
    locked") if another connection committed in between, since its snapshot is stale; so a
    job's transaction begins IMMEDIATE: it holds the lock from its first statement to its
    commit, and other writers wait for it instead. Meanwhile ``busy()`` is true: the job's
    progress is held back and its heartbeat skipped, both written after its commit. Other
    databases are never busy. A job's reads in ``app.db.read_phase`` stay deferred: they hold
    no lock, and the writes after them begin a transaction of their own.
    """

    def __init__(self, session: Session) -> None:
        self._dbapi: Any = None
        self._gate: WriteGate | None = None
        event.listen(session, "after_begin", self._begun)
        # The turn is given back at the commit, before the runner's after-commit work (written
        # progress takes a turn of its own), and at the latest when the transaction ends.
        event.listen(session, "after_commit", self._let_go)
        event.listen(session, "after_rollback", self._let_go)
        event.listen(session, "after_transaction_end", self._ended)

    def _begun(self, session: Session, _transaction: object, connection: Any) -> None:
        if connection.dialect.name != "sqlite" or connection.in_nested_transaction():
            return  # a savepoint inside a caller's transaction (tests) is not ours to change
        if in_read_phase(session):
            return  # a read (``app.db.read_phase``): deferred, it blocks no writer
        dbapi = connection.connection.dbapi_connection
        if dbapi.in_transaction:
            # A deferred BEGIN was sent (nothing ran yet): begin again, taking the lock.
            connection.exec_driver_sql("ROLLBACK")
        # In line with the other writers of the file, in this process and the server's.
        gate = write_gate(connection.engine)
        if gate is not None:
            if not gate.acquire(BUSY_TIMEOUT_S):
                raise ServiceUnavailable(
                    f"the database is busy: no write turn in {BUSY_TIMEOUT_S:.0f} s"
                )
            self._gate = gate
        connection.exec_driver_sql("BEGIN IMMEDIATE")
        self._dbapi = dbapi

    def _let_go(self, _session: Session) -> None:
        gate, self._gate = self._gate, None
        if gate is not None:
            gate.release()

    def _ended(self, session: Session, _transaction: object) -> None:
        if not session.in_transaction():
            self._dbapi = None
            self._let_go(session)

    def busy(self) -> bool:
        # sqlite3's in_transaction is safe to read from the heartbeat thread.
        dbapi = self._dbapi
        return dbapi is not None and bool(dbapi.in_transaction)


def never_busy() -> bool:
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
        busy: Callable[[], bool] = never_busy,
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
            with short_write(self._factory) as session:
                written = session.execute(
                    update(Job)
                    .where(*owned(self._claim))
                    .values(progress=self.fraction, message=self.message, heartbeat_at=utcnow()),
                    execution_options={"synchronize_session": False},
                ).rowcount  # type: ignore[attr-defined]
        except OperationalError as exc:
            if not locked(exc):
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
        busy: Callable[[], bool] = never_busy,
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
                with short_write(self._factory) as session:
                    written = session.execute(
                        update(Job).where(*owned(self._claim)).values(heartbeat_at=utcnow()),
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
