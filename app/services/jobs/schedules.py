"""Job schedules of an operator: create, list, change, delete, and the last job of each.
Callers commit.

A schedule runs every ``interval_seconds`` or at the times of its ``cron`` expression (UTC,
``app.services.jobs.cron``), exactly one of the two.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.errors import InvalidInput, NotFound
from app.models.base import utcnow
from app.models.jobs import Job, JobSchedule
from app.services.jobs.cron import check_cron, next_cron_time
from app.services.jobs.references import check_references
from app.services.jobs.registry import JobRegistry


def create_schedule(
    session: Session,
    *,
    operator_id: int,
    kind: str,
    parameters: dict[str, Any] | None,
    registry: JobRegistry,
    interval_seconds: int | None = None,
    cron: str | None = None,
    first_run_at: datetime | None = None,
    enabled: bool = True,
) -> JobSchedule:
    """A schedule whose first job is due at ``first_run_at`` (default: now for an interval,
    the expression's next time for a cron schedule)."""
    validated = registry.get(kind).validate(parameters)
    check_references(session, operator_id, validated)
    normalised = validated.model_dump(mode="json")
    now = utcnow()
    interval_seconds, cron = _check_timing(interval_seconds, cron, now=now)
    if first_run_at is None:
        first_run_at = now if cron is None else next_cron_time(cron, now)
    schedule = JobSchedule(
        operator_id=operator_id,
        kind=kind,
        parameters=normalised,
        interval_seconds=interval_seconds,
        cron=cron,
        enabled=enabled,
        next_run_at=first_run_at,
    )
    session.add(schedule)
    session.flush()
    return schedule


def get_schedule(session: Session, *, operator_id: int, schedule_id: int) -> JobSchedule:
    schedule = session.get(JobSchedule, schedule_id)
    if schedule is None or schedule.operator_id != operator_id:
        raise NotFound(f"schedule {schedule_id} not found")
    return schedule


def list_schedules(session: Session, *, operator_id: int) -> list[JobSchedule]:
    return list(
        session.scalars(
            select(JobSchedule)
            .where(JobSchedule.operator_id == operator_id)
            .order_by(JobSchedule.id)
        ).all()
    )


def last_jobs(session: Session, *, operator_id: int, schedule_ids: list[int]) -> dict[int, Job]:
    """schedule id -> the newest job it submitted (scheduled or run now)."""
    if not schedule_ids:
        return {}
    newest = (
        select(func.max(Job.id))
        .where(Job.operator_id == operator_id, Job.schedule_id.in_(schedule_ids))
        .group_by(Job.schedule_id)
    )
    jobs = session.scalars(select(Job).where(Job.id.in_(newest))).all()
    return {job.schedule_id: job for job in jobs if job.schedule_id is not None}


def update_schedule(
    session: Session,
    *,
    operator_id: int,
    schedule_id: int,
    registry: JobRegistry,
    parameters: dict[str, Any] | None = None,
    interval_seconds: int | None = None,
    cron: str | None = None,
    enabled: bool | None = None,
    next_run_at: datetime | None = None,
) -> JobSchedule:
    """Change the given fields; ``None`` leaves a field as it is. A new ``cron`` replaces the
    interval (and a new interval the cron); a new cron sets the next run to its next time,
    unless ``next_run_at`` is given."""
    schedule = get_schedule(session, operator_id=operator_id, schedule_id=schedule_id)
    if parameters is not None:
        kind = registry.get(schedule.kind)
        validated = kind.validate(parameters)
        check_references(session, operator_id, validated)
        schedule.parameters = validated.model_dump(mode="json")
    if interval_seconds is not None or cron is not None:
        now = utcnow()
        schedule.interval_seconds, schedule.cron = _check_timing(interval_seconds, cron, now=now)
        if schedule.cron is not None and next_run_at is None:
            schedule.next_run_at = next_cron_time(schedule.cron, now)
    if enabled is not None:
        schedule.enabled = enabled
    if next_run_at is not None:
        schedule.next_run_at = next_run_at
    session.flush()
    return schedule


def delete_schedule(session: Session, *, operator_id: int, schedule_id: int) -> JobSchedule:
    """Delete a schedule; the jobs it submitted stay (their ``schedule_id`` becomes null)."""
    schedule = get_schedule(session, operator_id=operator_id, schedule_id=schedule_id)
    session.delete(schedule)
    session.flush()
    return schedule


def mark_run(schedule: JobSchedule) -> None:
    """A job of the schedule was submitted now, outside its times ("run now"); its next
    scheduled run stays."""
    schedule.last_run_at = utcnow()


def _check_timing(
    interval_seconds: int | None, cron: str | None, *, now: datetime
) -> tuple[int | None, str | None]:
    if (interval_seconds is None) == (cron is None):
        reason = "give either cron or interval_seconds, not both" if cron is not None else (
            "give cron or interval_seconds"
        )
        raise InvalidInput(
            reason,
            details=[{"column": "cron", "reason": reason},
                     {"column": "interval_seconds", "reason": reason}],
        )
    if cron is not None:
        return None, check_cron(cron, now=now)
    assert interval_seconds is not None
    if interval_seconds < 60:
        raise InvalidInput(
            f"interval_seconds must be at least 60, not {interval_seconds}",
            details=[{"column": "interval_seconds", "reason": "must be at least 60"}],
        )
    return interval_seconds, None
