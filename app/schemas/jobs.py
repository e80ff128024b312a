"""Requests and responses of the jobs and schedules API."""

from __future__ import annotations

from datetime import datetime
from typing import Any, Literal

from pydantic import AwareDatetime, BaseModel, ConfigDict, Field

JobStatus = Literal["queued", "running", "succeeded", "failed", "cancelled"]


class JobSubmit(BaseModel):
    model_config = ConfigDict(extra="forbid")

    kind: str = Field(description="A registered job kind (GET /api/v1/jobs/kinds).")
    parameters: dict[str, Any] = Field(
        default_factory=dict, description="The kind's parameters; validated before storing."
    )


class JobOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    kind: str
    status: JobStatus
    progress: float = Field(description="Fraction done, 0 to 1.")
    message: str
    parameters: dict[str, Any]
    result: dict[str, Any] | None
    error: str | None
    attempts: int
    schedule_id: int | None
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    heartbeat_at: datetime | None


class JobList(BaseModel):
    items: list[JobOut]
    total: int = Field(description="Jobs matching the filters, over all pages.")


class JobKindOut(BaseModel):
    name: str
    description: str
    role: str = Field(description="Least role that may submit it.")
    submittable: bool = Field(description="False for kinds only services submit.")
    parameters_schema: dict[str, Any]


CRON_DESCRIPTION = (
    "Five-field cron expression (minute hour day-of-month month day-of-week), in UTC, "
    "e.g. '0 6 * * *' every day at 06:00 UTC; give it or interval_seconds."
)


class ScheduleCreate(BaseModel):
    model_config = ConfigDict(extra="forbid")

    kind: str
    parameters: dict[str, Any] = Field(default_factory=dict)
    interval_seconds: int | None = Field(
        default=None, ge=60, description="Time between runs, at least a minute; or cron."
    )
    cron: str | None = Field(default=None, max_length=100, description=CRON_DESCRIPTION)
    first_run_at: AwareDatetime | None = Field(
        default=None,
        description="When the first job is due (with a time zone); default now for an "
        "interval, the next time of the cron expression for a cron schedule.",
    )
    enabled: bool = True


class ScheduleUpdate(BaseModel):
    model_config = ConfigDict(extra="forbid")

    parameters: dict[str, Any] | None = None
    interval_seconds: int | None = Field(
        default=None, ge=60, description="A new interval; replaces a cron expression."
    )
    cron: str | None = Field(
        default=None, max_length=100, description="A new cron expression; replaces an interval."
    )
    next_run_at: AwareDatetime | None = None
    enabled: bool | None = None


class ScheduleJobOut(BaseModel):
    """The newest job a schedule submitted, with its progress."""

    model_config = ConfigDict(from_attributes=True)

    id: int
    status: JobStatus
    progress: float = Field(description="Fraction done, 0 to 1.")
    message: str
    created_at: datetime
    finished_at: datetime | None


class ScheduleOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    kind: str
    parameters: dict[str, Any]
    interval_seconds: int | None = Field(description="Time between runs; null for cron.")
    cron: str | None = Field(description="The cron expression (UTC); null for an interval.")
    enabled: bool
    next_run_at: datetime = Field(description="When the next job is due (UTC).")
    last_run_at: datetime | None
    created_at: datetime
    last_job: ScheduleJobOut | None = Field(
        default=None, description="The newest job the schedule submitted (scheduled or run now)."
    )
