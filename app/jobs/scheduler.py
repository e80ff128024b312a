"""Schedules submit jobs when due: one function both schedulers call.

The embedded default runs ``Scheduler`` (a thread next to the in-process runner); a deployment
runs Celery beat, whose only entry sends the ``tick`` task that calls ``submit_due`` on a worker.
Either way the schedules table is the schedule.
"""

from __future__ import annotations

import logging
import math
import threading
from datetime import datetime, timedelta

from sqlalchemy import select, update

from app.db import transaction
from app.errors import ServiceError
from app.jobs.claim import SessionFactory
from app.models.base import utcnow
from app.models.jobs import JobSchedule
from app.services.jobs.cron import next_cron_time
from app.services.jobs.dispatch import Dispatcher
from app.services.jobs.registry import JobRegistry
from app.services.jobs.store import submit

log = logging.getLogger("fleethealth.jobs")

TICK_SECONDS = 30.0


def next_run_after(previous: datetime, interval_seconds: int, now: datetime) -> datetime:
    """The first time ``previous + k * interval`` (k >= 1) later than ``now``.

    Runs missed while nothing was running are skipped, not made up in a burst; the phase of
    the schedule is kept.
    """
    interval = timedelta(seconds=interval_seconds)
    behind = max(0.0, (now - previous) / interval)
    steps = math.floor(behind) + 1
    return previous + steps * interval


def next_run(schedule: JobSchedule, now: datetime) -> datetime:
    """The schedule's run after the one due at ``now``: the cron expression's first time after
    ``now``, or the interval's next step (both skip runs missed while nothing ran)."""
    if schedule.cron is not None:
        return next_cron_time(schedule.cron, now)
    assert schedule.interval_seconds is not None  # the table's check: cron or interval
    return next_run_after(schedule.next_run_at, schedule.interval_seconds, now)


def submit_due(
    factory: SessionFactory, registry: JobRegistry, *, now: datetime | None = None
) -> list[int]:
    """Submit a job for every enabled schedule due at ``now``; return the new jobs' ids.

    Each schedule is advanced with a conditional UPDATE in the transaction that submits its
    job, so two schedulers running at once submit it once. A schedule whose parameters no
    longer validate is advanced and logged; a job of it already queued or running is reused.
    """
    now = now or utcnow()
    with transaction(factory) as session:
        due = session.scalars(
            select(JobSchedule.id)
            .where(JobSchedule.enabled.is_(True), JobSchedule.next_run_at <= now)
            .order_by(JobSchedule.next_run_at, JobSchedule.id)
        ).all()
    submitted: list[int] = []
    for schedule_id in due:
        with transaction(factory) as session:
            schedule = session.get(JobSchedule, schedule_id)
            if schedule is None:
                continue
            advanced = session.execute(
                update(JobSchedule)
                .where(
                    JobSchedule.id == schedule_id,
                    JobSchedule.next_run_at == schedule.next_run_at,
                    JobSchedule.enabled.is_(True),
                )
                .values(next_run_at=next_run(schedule, now), last_run_at=now),
                execution_options={"synchronize_session": False},
            ).rowcount  # type: ignore[attr-defined]
            if not advanced:
                continue  # another scheduler took this run
            try:
                job, created = submit(
                    session,
                    operator_id=schedule.operator_id,
                    kind=schedule.kind,
                    parameters=schedule.parameters,
                    registry=registry,
                    schedule_id=schedule.id,
                )
            except ServiceError as exc:
                log.warning("schedule %s submits nothing: %s", schedule_id, exc.message)
                continue
            if created:
                submitted.append(job.id)
    return submitted


class Scheduler:
    """The embedded default's scheduler thread: ``submit_due`` every ``tick_seconds``."""

    def __init__(
        self,
        factory: SessionFactory,
        registry: JobRegistry,
        dispatcher: Dispatcher,
        *,
        tick_seconds: float = TICK_SECONDS,
    ) -> None:
        self._factory = factory
        self._registry = registry
        self._dispatcher = dispatcher
        self._tick = tick_seconds
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="job-scheduler", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 5.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=timeout)
            self._thread = None

    def _run(self) -> None:
        while True:
            try:
                for job_id in submit_due(self._factory, self._registry):
                    self._dispatcher.dispatch(job_id)
            except Exception:  # a database hiccup must not stop the schedules for good
                log.exception("submitting due scheduled jobs failed")
            if self._stop.wait(self._tick):
                return
