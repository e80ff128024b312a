"""The Celery application of a deployment: Redis broker, workers and beat from the same code."""

from __future__ import annotations

import logging

from celery import Celery

from app.config import get_settings
from app.jobs.scheduler import TICK_SECONDS

log = logging.getLogger("fleethealth.jobs")

CELERY_QUEUE = "fleethealth"
RUN_JOB_TASK = "fleethealth.run_job"
TICK_TASK = "fleethealth.tick"


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
