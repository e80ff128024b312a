"""Submitting, reading and cancelling jobs. Callers pass the session and commit it."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from sqlalchemy import event, func, select, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from app.errors import Conflict, NotFound
from app.models.base import utcnow
from app.models.jobs import ACTIVE_STATUSES, Job
from app.services.jobs.references import check_references
from app.services.jobs.registry import JobRegistry, parameters_checksum


def submit(
    session: Session,
    *,
    operator_id: int,
    kind: str,
    parameters: dict[str, Any] | None,
    registry: JobRegistry,
    schedule_id: int | None = None,
) -> tuple[Job, bool]:
    """Queue a job, or return the queued or running job with the same kind and parameters.

    Returns ``(job, created)``. Unknown kinds and bad parameters raise ``InvalidInput`` before
    anything is stored. The caller commits, then hands ``job.id`` to a dispatcher (see
    ``dispatch_after_commit``).
    """
    job_kind = registry.get(kind)
    validated = job_kind.validate(parameters)
    check_references(session, operator_id, validated)
    checksum = parameters_checksum(kind, validated)
    existing = _active_job(session, operator_id, kind, checksum)
    if existing is not None:
        return existing, False
    job = Job(
        operator_id=operator_id,
        kind=kind,
        parameters=validated.model_dump(mode="json"),
        checksum=checksum,
        status="queued",
        progress=0.0,
        message="queued",
        attempts=0,
        schedule_id=schedule_id,
    )
    try:
        # A concurrent submission of the same work hits the partial unique index; the savepoint
        # keeps the caller's transaction usable so the winner's row can be returned instead.
        with session.begin_nested():
            session.add(job)
            session.flush()
    except IntegrityError:
        existing = _active_job(session, operator_id, kind, checksum)
        if existing is None:
            raise
        return existing, False
    return job, True


def _active_job(session: Session, operator_id: int, kind: str, checksum: str) -> Job | None:
    return session.scalar(
        select(Job).where(
            Job.operator_id == operator_id,
            Job.kind == kind,
            Job.checksum == checksum,
            Job.status.in_(ACTIVE_STATUSES),
        )
    )


def get_job(session: Session, *, operator_id: int, job_id: int) -> Job:
    """The operator's job ``job_id``; another operator's job is not found."""
    job = session.get(Job, job_id, populate_existing=True)
    if job is None or job.operator_id != operator_id:
        raise NotFound(f"job {job_id} not found")
    return job


def list_jobs(
    session: Session,
    *,
    operator_id: int,
    statuses: Sequence[str] = (),
    kinds: Sequence[str] = (),
    limit: int = 100,
    offset: int = 0,
) -> tuple[list[Job], int]:
    """The operator's jobs, newest first, and how many match in all."""
    conditions = [Job.operator_id == operator_id]
    if statuses:
        conditions.append(Job.status.in_(statuses))
    if kinds:
        conditions.append(Job.kind.in_(kinds))
    total = session.scalar(select(func.count()).select_from(Job).where(*conditions)) or 0
    rows = session.scalars(
        select(Job).where(*conditions).order_by(Job.id.desc()).limit(limit).offset(offset)
    ).all()
    return list(rows), total


def cancel(session: Session, *, operator_id: int, job_id: int) -> Job:
    """Cancel a queued or running job.

    A queued job never starts; a running one stops at its next progress report (its function
    gets ``JobCancelled``) and its uncommitted work is rolled back. A finished job is a 409.
    The UPDATE comes first: on SQLite a transaction that reads before it writes can find its
    snapshot stale when the running job has just written its progress.
    """
    cancelled = session.execute(
        update(Job)
        .where(
            Job.id == job_id,
            Job.operator_id == operator_id,
            Job.status.in_(ACTIVE_STATUSES),
        )
        .values(status="cancelled", finished_at=utcnow(), message="cancelled"),
        execution_options={"synchronize_session": False},
    )
    job = get_job(session, operator_id=operator_id, job_id=job_id)
    if cancelled.rowcount == 0:  # type: ignore[attr-defined]
        raise Conflict(f"job {job_id} has {job.status} already; only queued or running jobs cancel")
    return job


def queue_estimation(session: Session, *, operator_id: int, job_registry: JobRegistry) -> Job:
    """Queue the estimation of the operator's new snapshots (the caller dispatches it once
    committed); see ``queue_serial``."""
    return queue_serial(session, operator_id=operator_id, kind="estimate_engines",
                        job_registry=job_registry)


def queue_sending(session: Session, *, operator_id: int, job_registry: JobRegistry) -> Job:
    """Queue the sending of the operator's pending notifications (the caller dispatches it once
    committed); see ``queue_serial``."""
    return queue_serial(session, operator_id=operator_id, kind="send_notifications",
                        job_registry=job_registry)


def queue_serial(
    session: Session, *, operator_id: int, kind: str, job_registry: JobRegistry
) -> Job:
    """Queue a job of a serial kind that takes no parameters and works on whatever it finds.

    One runs at a time per operator. A running one may already have looked for work for the
    last time when the caller's rows commit, so then a follow-up is queued (once: later
    submissions find it) and starts when the running one ends; otherwise the queued job, if
    any, covers the caller's rows too.
    """
    job, _created = submit(session, operator_id=operator_id, kind=kind, parameters={},
                           registry=job_registry)
    if job.status == "running":
        job, _created = submit(session, operator_id=operator_id, kind=kind,
                               parameters={"follow_up": True}, registry=job_registry)
    return job


def dispatch_after_commit(session: Session, dispatch: Callable[[int], None], job_id: int) -> None:
    """Call ``dispatch(job_id)`` once the session commits, so a worker can see the row.

    Savepoint commits (``begin_nested``, which ``submit`` itself uses) do not count: the row
    is visible to other connections only when the outermost transaction commits.
    """

    settled = False  # listeners cannot be removed while the event runs them: a flag instead

    def after_commit(committed: Session) -> None:
        nonlocal settled
        if settled or committed.in_nested_transaction():
            return
        settled = True
        dispatch(job_id)

    def forget(_session: Session) -> None:
        nonlocal settled
        settled = True

    event.listen(session, "after_commit", after_commit)
    event.listen(session, "after_rollback", forget)
