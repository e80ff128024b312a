"""The Celery application of a deployment: Redis broker, workers and beat from the same code."""

from __future__ import annotations

import logging
from collections.abc import Sequence

from celery import Celery

from app.config import get_settings
from app.jobs.scheduler import TICK_SECONDS
from app.services.snapshots.drifts import FleetDrifts

log = logging.getLogger("fleethealth.jobs")

CELERY_QUEUE = "fleethealth"
RUN_JOB_TASK = "fleethealth.run_job"
TICK_TASK = "fleethealth.tick"
ESTIMATE_GROUP_TASK = "fleethealth.estimate_group"


def make_celery() -> Celery:
    settings = get_settings()
    celery = Celery(
        "fleethealth",
        broker=settings.redis_url,
        backend=settings.redis_url,
        include=["app.jobs.celery_tasks"],
    )
    celery.conf.update(
        task_acks_late=True,
        task_reject_on_worker_lost=True,
        worker_prefetch_multiplier=1,
        timezone="UTC",
        task_default_queue=CELERY_QUEUE,
        task_ignore_result=True,
        broker_connection_retry_on_startup=True,
        beat_schedule_filename=str(settings.data_dir / "celerybeat-schedule"),
        # Beat's one entry: the tick reads the job schedules table on a worker.
        beat_schedule={
            "fleethealth-job-schedules": {"task": TICK_TASK, "schedule": TICK_SECONDS}
        },
    )
    return celery


class CeleryDispatch:
    """Send ``run_job(job_id)`` (``app.jobs.celery_tasks``) to the Celery workers through the
    broker, by the task's name."""

    def __init__(self, queue: str = CELERY_QUEUE, celery: Celery | None = None) -> None:
        self.queue = queue
        self._celery = celery

    def dispatch(self, job_id: int) -> None:
        if self._celery is None:
            self._celery = make_celery()
        try:
            self._celery.send_task(RUN_JOB_TASK, args=[job_id], queue=self.queue)
        except Exception:  # broker down: the job stays queued and the next tick re-sends it
            log.exception("could not send job %s to the Celery broker", job_id)


class CeleryGroups:
    """A ``groups.Launcher`` for a deployment: each engine group is an ``estimate_group``
    task (``app.jobs.celery_tasks``) on the queue the estimation job came from, for whichever
    worker is free; ``workers``: the setting ``estimation_workers``."""

    def __init__(self, workers: int, queue: str = CELERY_QUEUE, celery: Celery | None = None
                 ) -> None:
        self.workers = workers
        self.queue = queue
        self._celery = celery

    def launch(self, operator_id: int, groups: Sequence[Sequence[int]],
               drifts: FleetDrifts) -> None:
        if self._celery is None:
            self._celery = make_celery()
        message = drifts.message()
        for group in groups:
            try:
                self._celery.send_task(ESTIMATE_GROUP_TASK,
                                       args=[operator_id, list(group), message],
                                       queue=self.queue)
            except Exception:  # broker down: the job estimates the group itself
                log.exception("could not send an engine group to the Celery broker")
