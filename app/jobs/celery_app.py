"""The Celery application of a deployment: Redis broker, workers and beat from the same code."""

from __future__ import annotations

from celery import Celery

from app.config import get_settings
from app.jobs.dispatch import CELERY_QUEUE
from app.jobs.scheduler import TICK_SECONDS


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
            "fleethealth-job-schedules": {"task": "fleethealth.tick", "schedule": TICK_SECONDS}
        },
    )
    return celery
