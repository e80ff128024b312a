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


class PurgeStreamSamples(BaseModel):
    model_config = ConfigDict(extra="forbid")

    older_than_days: float | None = Field(
        None, gt=0, le=36500,
        description="Delete the sample files of recordings closed this many days ago "
        "(default: the service's stream_retention_days; unset there: keep them).",
    )


@registry.job(
    "purge_stream_samples",
    parameters=PurgeStreamSamples,
    description="Delete the raw sample files of the operator's closed stream recordings older "
    "than the retention (stream_retention_days); their metadata, estimates and steady-window "
    "records are kept.",
    role="admin",
)
def purge_stream_samples(
    session: Session, parameters: PurgeStreamSamples, progress: Progress, *, operator_id: int
) -> dict[str, Any]:
    from app.config import get_settings
    from app.services.streams import retention

    settings = get_settings()
    days = parameters.older_than_days or settings.stream_retention_days
    if days is None:
        return {"recordings": 0, "files": 0, "bytes": 0,
                "message": "no retention set (stream_retention_days): samples are kept"}
    older_than = timedelta(days=days)
    total = len(retention.due(session, operator_id=operator_id, older_than=older_than))
    progress(0.0, f"{total} recordings closed more than {days:g} days ago keep samples")
    done = retention.purge(session, operator_id=operator_id, data_dir=settings.data_dir,
                           older_than=older_than, commit=session.commit)
    progress(1.0, f"removed the samples of {done.recordings} recordings")
    return {"recordings": done.recordings, "files": done.files, "bytes": done.bytes,
            "older_than_days": days}
