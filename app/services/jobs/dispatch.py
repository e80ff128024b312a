"""Telling a runner that a job was queued: wake the in-process runner or send a Celery message
(``app.jobs.celery_app.CeleryDispatch``).

Whichever dispatcher is used, the job row is the truth: a lost wake-up or message only delays a
job (runners poll; the Celery tick re-sends jobs left queued).
"""

from __future__ import annotations

from typing import Protocol


class Dispatcher(Protocol):
    def dispatch(self, job_id: int) -> None: ...


class NoDispatch:
    """No runner in this process: queued jobs wait for a worker or ``run_pending``."""

    def dispatch(self, job_id: int) -> None:
        return None
