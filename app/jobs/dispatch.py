"""Telling a runner that a job was queued: wake the in-process runner or send a Celery message.

Whichever dispatcher is used, the job row is the truth: a lost wake-up or message only delays a
job (runners poll; the Celery tick re-sends jobs left queued).
"""

from __future__ import annotations

import logging
from typing import Protocol

log = logging.getLogger("fleethealth.jobs")

CELERY_QUEUE = "fleethealth"


class Dispatcher(Protocol):
    def dispatch(self, job_id: int) -> None: ...


class NoDispatch:
    """No runner in this process: queued jobs wait for a worker or ``run_pending``."""

    def dispatch(self, job_id: int) -> None:
        return None


class CeleryDispatch:
    """Send ``run_job(job_id)`` to the Celery workers through the broker."""

    def __init__(self, queue: str = CELERY_QUEUE) -> None:
        self.queue = queue

    def dispatch(self, job_id: int) -> None:
        from app.jobs.celery_tasks import run_job

        try:
            run_job.apply_async(args=[job_id], queue=self.queue)
        except Exception:  # broker down: the job stays queued and the next tick re-sends it
            log.exception("could not send job %s to the Celery broker", job_id)
