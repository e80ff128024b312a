"""Jobs (progress of long work) and job schedules. Another operator's job or schedule is 404."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query, Response, status

from app.errors import Forbidden, InvalidInput
from app.schemas.jobs import (
    JobKindOut,
    JobList,
    JobOut,
    JobStatus,
    JobSubmit,
    ScheduleCreate,
    ScheduleJobOut,
    ScheduleOut,
    ScheduleUpdate,
)
from app.security import Admin, Analyst, CurrentPrincipal, DbSession
from app.services.jobs import schedules as schedule_service
from app.services.jobs import store
from app.services.jobs.queue import Jobs

router = APIRouter(prefix="/api/v1", tags=["jobs"])


@router.get("/jobs", response_model=JobList)
def list_jobs(
    session: DbSession,
    principal: CurrentPrincipal,
    status_: Annotated[list[JobStatus] | None, Query(alias="status")] = None,
    kind: Annotated[list[str] | None, Query()] = None,
    limit: Annotated[int, Query(ge=1, le=500)] = 100,
    offset: Annotated[int, Query(ge=0)] = 0,
) -> JobList:
    """Your operator's jobs, newest first; repeat ``status`` or ``kind`` to match several."""
    rows, total = store.list_jobs(
        session,
        operator_id=principal.operator_id,
        statuses=status_ or (),
        kinds=kind or (),
        limit=limit,
        offset=offset,
    )
    return JobList(items=[JobOut.model_validate(row) for row in rows], total=total)


@router.post(
    "/jobs",
    response_model=JobOut,
    status_code=status.HTTP_202_ACCEPTED,
    responses={200: {"description": "The same job is queued or running already", "model": JobOut}},
)
def submit_job(
    body: JobSubmit,
    session: DbSession,
    principal: Analyst,
    jobs: Jobs,
    response: Response,
) -> JobOut:
    """Queue a job (202), or get the queued or running job with the same kind and parameters
    (200). Parameters are checked before anything is stored (422)."""
    kind = jobs.registry.get(body.kind)
    if not kind.submittable:
        raise InvalidInput(
            f"job kind {body.kind!r} is started by the service, not submitted directly",
            details=[{"column": "kind", "reason": "not submittable"}],
        )
    if not principal.can(kind.role):
        raise Forbidden(f"job kind {body.kind!r} needs the {kind.role} role")
    job, created = jobs.submit(
        session, operator_id=principal.operator_id, kind=body.kind, parameters=body.parameters
    )
    if not created:
        response.status_code = status.HTTP_200_OK
    return JobOut.model_validate(job)


@router.get("/jobs/kinds", response_model=list[JobKindOut])
def list_job_kinds(_principal: CurrentPrincipal, jobs: Jobs) -> list[JobKindOut]:
    """The registered job kinds with the JSON schema of their parameters."""
    return [
        JobKindOut(
            name=kind.name,
            description=kind.description,
            role=kind.role,
            submittable=kind.submittable,
            parameters_schema=kind.parameters.model_json_schema(),
        )
        for kind in jobs.registry
    ]


@router.get("/jobs/{job_id}", response_model=JobOut)
def get_job(job_id: int, session: DbSession, principal: CurrentPrincipal) -> JobOut:
    """One job with its status, progress, message, and result or error."""
    return JobOut.model_validate(
        store.get_job(session, operator_id=principal.operator_id, job_id=job_id)
    )


@router.post("/jobs/{job_id}/cancel", response_model=JobOut)
def cancel_job(job_id: int, session: DbSession, principal: Analyst) -> JobOut:
    """Cancel a queued or running job (a running job stops at its next progress report)."""
    return JobOut.model_validate(
        store.cancel(session, operator_id=principal.operator_id, job_id=job_id)
    )


def _schedules_out(session: DbSession, operator_id: int, rows: list[Any]) -> list[ScheduleOut]:
    """Schedules with the newest job each submitted."""
    last = schedule_service.last_jobs(
        session, operator_id=operator_id, schedule_ids=[row.id for row in rows]
    )
    out = []
    for row in rows:
        item = ScheduleOut.model_validate(row)
        job = last.get(row.id)
        item.last_job = None if job is None else ScheduleJobOut.model_validate(job)
        out.append(item)
    return out


@router.get("/schedules", response_model=list[ScheduleOut])
def list_schedules(session: DbSession, principal: Admin) -> list[ScheduleOut]:
    """Your operator's schedules with their next run and the newest job each submitted."""
    rows = schedule_service.list_schedules(session, operator_id=principal.operator_id)
    return _schedules_out(session, principal.operator_id, rows)


@router.post("/schedules", response_model=ScheduleOut, status_code=status.HTTP_201_CREATED)
def create_schedule(
    body: ScheduleCreate, session: DbSession, principal: Admin, jobs: Jobs
) -> ScheduleOut:
    """Submit a job of ``kind`` every ``interval_seconds`` or at the times of ``cron`` (UTC),
    the first at ``first_run_at``. A bad cron expression is a 422 naming ``cron``."""
    schedule = schedule_service.create_schedule(
        session,
        operator_id=principal.operator_id,
        kind=body.kind,
        parameters=body.parameters,
        interval_seconds=body.interval_seconds,
        cron=body.cron,
        first_run_at=body.first_run_at,
        enabled=body.enabled,
        registry=jobs.registry,
    )
    return ScheduleOut.model_validate(schedule)


@router.get("/schedules/{schedule_id}", response_model=ScheduleOut)
def get_schedule(schedule_id: int, session: DbSession, principal: Admin) -> ScheduleOut:
    row = schedule_service.get_schedule(
        session, operator_id=principal.operator_id, schedule_id=schedule_id
    )
    return _schedules_out(session, principal.operator_id, [row])[0]


@router.patch("/schedules/{schedule_id}", response_model=ScheduleOut)
def update_schedule(
    schedule_id: int,
    body: ScheduleUpdate,
    session: DbSession,
    principal: Admin,
    jobs: Jobs,
) -> ScheduleOut:
    """Change parameters, interval or cron, next run or enabled; fields left out stay."""
    schedule = schedule_service.update_schedule(
        session,
        operator_id=principal.operator_id,
        schedule_id=schedule_id,
        registry=jobs.registry,
        parameters=body.parameters,
        interval_seconds=body.interval_seconds,
        cron=body.cron,
        enabled=body.enabled,
        next_run_at=body.next_run_at,
    )
    return _schedules_out(session, principal.operator_id, [schedule])[0]


@router.post(
    "/schedules/{schedule_id}/run",
    response_model=JobOut,
    status_code=status.HTTP_202_ACCEPTED,
    responses={200: {"description": "The schedule's job is queued or running already",
                     "model": JobOut}},
)
def run_schedule_now(
    schedule_id: int, session: DbSession, principal: Admin, jobs: Jobs, response: Response
) -> JobOut:
    """Submit the schedule's job now (202), or get its queued or running job (200); the
    schedule's next run stays as it was."""
    schedule = schedule_service.get_schedule(
        session, operator_id=principal.operator_id, schedule_id=schedule_id
    )
    job, created = jobs.submit(
        session, operator_id=principal.operator_id, kind=schedule.kind,
        parameters=schedule.parameters, schedule_id=schedule.id,
    )
    schedule_service.mark_run(schedule)
    if not created:
        response.status_code = status.HTTP_200_OK
    return JobOut.model_validate(job)


@router.delete("/schedules/{schedule_id}", response_model=ScheduleOut)
def delete_schedule(schedule_id: int, session: DbSession, principal: Admin) -> ScheduleOut:
    """Delete a schedule and answer what it was; the jobs it submitted stay."""
    return ScheduleOut.model_validate(
        schedule_service.delete_schedule(
            session, operator_id=principal.operator_id, schedule_id=schedule_id
        )
    )
