"""Housekeeping kinds: keep the jobs table small when schedules run jobs every day."""

from __future__ import annotations

from datetime import timedelta
from typing import Any

from pydantic import BaseModel, ConfigDict, Field
from sqlalchemy import delete, func, select
from sqlalchemy.orm import Session

from app.models.base import utcnow
from app.models.jobs import FINISHED_STATUSES, Job
from app.services.jobs.registry import Progress, registry


class PurgeFinishedJobs(BaseModel):
    model_config = ConfigDict(extra="forbid")

    older_than_days: int = Field(
        30, ge=1, le=3650, description="Delete finished jobs that finished this many days ago."
    )
    batch_size: int = Field(500, ge=1, le=10_000, description="Jobs deleted per transaction.")


@registry.job(
    "purge_finished_jobs",
    parameters=PurgeFinishedJobs,
    description="Delete the operator's succeeded, failed and cancelled jobs older than N days.",
    role="admin",
)
def purge_finished_jobs(
    session: Session, parameters: PurgeFinishedJobs, progress: Progress, *, operator_id: int
) -> dict[str, Any]:
    """Delete in batches, committing each: a restart goes on with what is left (idempotent)."""
    cutoff = utcnow() - timedelta(days=parameters.older_than_days)
    old = (
        Job.operator_id == operator_id,
        Job.status.in_(FINISHED_STATUSES),
        Job.finished_at < cutoff,
    )
    total = session.scalar(select(func.count()).select_from(Job).where(*old)) or 0
    progress(0.0, f"{total} finished jobs older than {parameters.older_than_days} days")
    deleted = 0
    while ids := session.scalars(
        select(Job.id).where(*old).order_by(Job.id).limit(parameters.batch_size)
    ).all():
        session.execute(delete(Job).where(Job.id.in_(ids)))
        session.commit()
        deleted += len(ids)
        total = max(total, deleted)  # jobs that aged past the cutoff meanwhile
        progress(deleted / total, f"deleted {deleted} of {total} finished jobs")
    return {"deleted": deleted, "cutoff": cutoff.isoformat()}
