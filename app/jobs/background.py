"""The embedded default's background jobs: the in-process runner and scheduler, started together."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import timedelta

from app.jobs.claim import HEARTBEAT_SECONDS, STALE_AFTER, SessionFactory
from app.jobs.runner import Runner
from app.jobs.scheduler import Scheduler
from app.services.jobs.registry import JobRegistry


@dataclass
class BackgroundJobs:
    runner: Runner
    scheduler: Scheduler

    def stop(self) -> None:
        self.scheduler.stop()
        self.runner.stop()


def start_background_jobs(
    factory: SessionFactory,
    registry: JobRegistry,
    *,
    workers: int = 2,
    heartbeat_seconds: float = HEARTBEAT_SECONDS,
    stale_after: timedelta = STALE_AFTER,
) -> BackgroundJobs:
    """Start the runner's threads (requeueing jobs a stopped process left running) and the
    scheduler thread, which wakes the runner for each job it submits."""
    runner = Runner(
        factory, registry, workers=workers, heartbeat_seconds=heartbeat_seconds,
        stale_after=stale_after,
    )
    runner.start()
    scheduler = Scheduler(factory, registry, runner)
    scheduler.start()
    return BackgroundJobs(runner=runner, scheduler=scheduler)
