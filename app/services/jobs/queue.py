"""What routes and services use to start a job: submit, then dispatch once committed.

In a route::

    from app.services.jobs.queue import Jobs

    @router.post("/uploads", ...)
    def upload(..., session: DbSession, principal: Analyst, jobs: Jobs) -> ...:
        ...
        job, created = jobs.submit(
            session, operator_id=principal.operator_id, kind="estimate_upload",
            parameters={"upload_id": upload.id},
        )

The job is queued in the caller's transaction and handed to the runner (in-process threads or
Celery) only after that transaction commits, so a worker never looks for a row it cannot see.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Any

from fastapi import Depends, Request
from sqlalchemy.orm import Session

from app.models.jobs import Job
from app.services.jobs import store
from app.services.jobs.dispatch import Dispatcher
from app.services.jobs.registry import JobRegistry


@dataclass(frozen=True)
class JobQueue:
    registry: JobRegistry
    dispatcher: Dispatcher

    def submit(
        self,
        session: Session,
        *,
        operator_id: int,
        kind: str,
        parameters: dict[str, Any] | None = None,
        schedule_id: int | None = None,
    ) -> tuple[Job, bool]:
        """Queue a job (or get the same active one); ``(job, created)``. See ``store.submit``."""
        job, created = store.submit(
            session,
            operator_id=operator_id,
            kind=kind,
            parameters=parameters,
            registry=self.registry,
            schedule_id=schedule_id,
        )
        if created:
            store.dispatch_after_commit(session, self.dispatcher.dispatch, job.id)
        return job, created

    def estimate(self, session: Session, *, operator_id: int) -> Job:
        """Queue the estimation of the operator's snapshots that lack estimates under their
        active designs (after an upload, an activation); see
        ``store.queue_estimation``."""
        job = store.queue_estimation(session, operator_id=operator_id, job_registry=self.registry)
        store.dispatch_after_commit(session, self.dispatcher.dispatch, job.id)
        return job

    def notify(self, session: Session, *, operator_id: int) -> Job:
        """Queue the sending of the operator's pending notifications, dispatched once the
        caller's transaction commits; see ``store.queue_sending``."""
        job = store.queue_sending(session, operator_id=operator_id, job_registry=self.registry)
        store.dispatch_after_commit(session, self.dispatcher.dispatch, job.id)
        return job

    def estimate_recording(
        self, session: Session, *, operator_id: int, recording_id: int, through_sample: int
    ) -> Job:
        """Queue the stream filter over a recording's samples, dispatched when the upload
        commits (one job per sample count, so each live chunk gets its run)."""
        job, _created = store.submit(
            session, operator_id=operator_id, kind="estimate_recording",
            parameters={"recording_id": recording_id, "through_sample": through_sample},
            registry=self.registry,
        )
        store.dispatch_after_commit(session, self.dispatcher.dispatch, job.id)
        return job


def get_job_queue(request: Request) -> JobQueue:
    """The app's registry and dispatcher (the dispatcher is the runner once it started)."""
    state = request.app.state
    return JobQueue(registry=state.job_registry, dispatcher=state.job_dispatcher)


Jobs = Annotated[JobQueue, Depends(get_job_queue)]
