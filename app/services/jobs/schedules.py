"""Job schedules of an operator: create, list, change, delete. Callers commit."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from app.errors import InvalidInput, NotFound
from app.models.base import utcnow
from app.models.jobs import JobSchedule
from app.services.jobs.references import check_references
from app.services.jobs.registry import JobRegistry


def create_schedule(
    session: Session,
    *,
    operator_id: int,
    kind: str,
    parameters: dict[str, Any] | None,
    interval_seconds: int,
    registry: JobRegistry,
    first_run_at: datetime | None = None,
    enabled: bool = True,
) -> JobSchedule:
    """A schedule whose first job is due at ``first_run_at`` (default: now)."""
    validated = registry.get(kind).validate(parameters)
    check_references(session, operator_id, validated)
    normalised = validated.model_dump(mode="json")
    _check_interval(interval_seconds)
    schedule = JobSchedule(
        operator_id=operator_id,
        kind=kind,
        parameters=normalised,
        interval_seconds=interval_seconds,
        enabled=enabled,
        next_run_at=first_run_at or utcnow(),
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


def update_schedule(
    session: Session,
    *,
    operator_id: int,
    schedule_id: int,
    registry: JobRegistry,
    parameters: dict[str, Any] | None = None,
    interval_seconds: int | None = None,
    enabled: bool | None = None,
    next_run_at: datetime | None = None,
) -> JobSchedule:
    """Change the given fields; ``None`` leaves a field as it is."""
    schedule = get_schedule(session, operator_id=operator_id, schedule_id=schedule_id)
    if parameters is not None:
        kind = registry.get(schedule.kind)
        validated = kind.validate(parameters)
        check_references(session, operator_id, validated)
        schedule.parameters = validated.model_dump(mode="json")
    if interval_seconds is not None:
        _check_interval(interval_seconds)
        schedule.interval_seconds = interval_seconds
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


def _check_interval(interval_seconds: int) -> None:
    if interval_seconds < 60:
        raise InvalidInput(
            f"interval_seconds must be at least 60, not {interval_seconds}",
            details=[{"column": "interval_seconds", "reason": "must be at least 60"}],
        )
