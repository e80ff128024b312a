"""Claiming jobs: the atomic UPDATE that takes a queued job, and requeueing the jobs whose
worker stopped beating.

Every later write of a claimed job is conditioned on its claim (``owned``), so a worker whose
job was cancelled or taken over writes nothing.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

from sqlalchemy import func, or_, select, true, update
from sqlalchemy.orm import Session, aliased, sessionmaker

from app.db import transaction
from app.models.base import utcnow
from app.models.jobs import Job

log = logging.getLogger("fleethealth.jobs")

SessionFactory = sessionmaker[Session]

# A worker that stopped (killed process, lost machine) leaves its job 'running' without
# heartbeats; after STALE_AFTER the job is requeued, at most MAX_ATTEMPTS claims in all.
HEARTBEAT_SECONDS = 15.0
STALE_AFTER = timedelta(seconds=120)
MAX_ATTEMPTS = 3

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
    operator. Two of a serial kind can be queued at once (a follow-up queued while one ran,
    then a new one after it ended); ``_claim`` makes their claims take turns."""
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


# The PostgreSQL advisory lock under which claims that check for a running sibling take turns
# (any number that no other lock of the database's clients uses).
SERIAL_CLAIM_LOCK = 0x666C6565  # "flee"


def _claim(
    factory: SessionFactory, which: Any, worker: str, serial_kinds: Sequence[str] = ()
) -> Claim | None:
    with transaction(factory) as session:
        if serial_kinds and session.get_bind().dialect.name == "postgresql":
            # Under READ COMMITTED two claims in flight at once would each miss the other's
            # uncommitted running sibling, and both start. Taking turns, each claim's UPDATE
            # reads after the one before committed. (On SQLite the write lock does this.)
            session.execute(select(func.pg_advisory_xact_lock(SERIAL_CLAIM_LOCK)))
        row = session.execute(
            update(Job)
            .where(which, Job.status == "queued", _may_start(serial_kinds))
            .values(**_claim_values(worker))
            .returning(Job.id, Job.attempts),
            execution_options={"synchronize_session": False},
        ).first()
    return None if row is None else Claim(job_id=row[0], attempt=row[1])


def owned(claim: Claim) -> tuple[Any, ...]:
    return (Job.id == claim.job_id, Job.status == "running", Job.attempts == claim.attempt)


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
    ids = _requeue(factory, stale, max_attempts, "requeued: its worker stopped")
    if ids:
        log.warning("requeued jobs whose worker stopped: %s", ids)
    return ids


def requeue_orphans(
    factory: SessionFactory,
    *,
    max_attempts: int = MAX_ATTEMPTS,
    host: str | None = None,
    process_alive: Callable[[int], bool] | None = None,
) -> list[int]:
    """Requeue at once the running jobs that a stopped process of this host left (orphans),
    without waiting for their heartbeats to go stale; fail those out of attempts.

    A job's ``worker`` names the host and process that claimed it (``worker_name``); a job
    claimed here by a process that no longer exists is an orphan. Jobs of other hosts, of
    live processes and of workers named otherwise wait for ``requeue_stale``. (Hosts that
    share a name but not their process ids, e.g. containers given one hostname, must not
    share a database with this check on; the default container hostnames differ.)
    """
    host = host or socket.gethostname()
    process_alive = process_alive or _process_alive
    with transaction(factory, write=False) as session:
        running = session.execute(
            select(Job.id, Job.worker).where(Job.status == "running")
        ).all()
    orphans = {
        (job_id, worker)
        for job_id, worker in running
        if (claimant := _claimant(worker)) is not None
        and claimant[0] == host
        and claimant[1] != os.getpid()
        and not process_alive(claimant[1])
    }
    if not orphans:
        return []
    which = (
        Job.status == "running",
        Job.id.in_([job_id for job_id, _ in orphans]),
        Job.worker.in_({worker for _, worker in orphans}),
    )
    ids = _requeue(factory, which, max_attempts, "requeued: its process stopped")
    if ids:
        log.warning("requeued jobs a stopped process left running: %s", ids)
    return ids


def _claimant(worker: str | None) -> tuple[str, int] | None:
    """(host, process id) of a ``worker_name``, or None for a worker named otherwise."""
    parts = (worker or "").split(":")
    if len(parts) != 4 or not parts[2].isdigit():
        return None
    return parts[1], int(parts[2])


def _process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def _requeue(
    factory: SessionFactory, which: tuple[Any, ...], max_attempts: int, message: str
) -> list[int]:
    """Requeue the running jobs ``which`` selects, failing those out of attempts."""
    with transaction(factory) as session:
        session.execute(
            update(Job)
            .where(*which, Job.attempts >= max_attempts)
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
            .where(*which, Job.attempts < max_attempts)
            .values(status="queued", message=message, worker=None)
            .returning(Job.id),
            execution_options={"synchronize_session": False},
        ).scalars()
        return sorted(requeued)


def queued_before(factory: SessionFactory, cutoff: datetime) -> list[int]:
    """Ids of jobs still queued that were created before ``cutoff`` (their message was lost)."""
    with transaction(factory) as session:
        return list(
            session.scalars(
                select(Job.id).where(Job.status == "queued", Job.created_at < cutoff)
            ).all()
        )
