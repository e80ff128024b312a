"""The Celery tasks of a deployment: the same claim and run code as the in-process runner.

``run_job(job_id)`` claims the job with the atomic UPDATE and runs it with ``execute``; a
message for a job that is no longer queued (run already, cancelled, a duplicate message) does
nothing. ``tick`` (sent by beat) submits due schedules, requeues jobs whose worker stopped and
re-sends jobs whose message was lost.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from datetime import timedelta
from typing import Any

from celery.signals import worker_ready

from app.jobs.celery_app import (
    CELERY_QUEUE,
    ESTIMATE_GROUP_TASK,
    RUN_JOB_TASK,
    TICK_TASK,
    CeleryDispatch,
    CeleryGroups,
    make_celery,
)
from app.jobs.claim import (
    HEARTBEAT_SECONDS,
    STALE_AFTER,
    SessionFactory,
    claim_job,
    queued_before,
    requeue_orphans,
    requeue_stale,
    worker_name,
)
from app.jobs.kinds import load_kinds
from app.jobs.runner import execute
from app.jobs.scheduler import submit_due
from app.models.base import utcnow
from app.services.jobs.registry import JobRegistry
from app.services.snapshots import groups, store
from app.services.snapshots.drifts import FleetDrifts

log = logging.getLogger("fleethealth.jobs")

celery = make_celery()

# A queued job older than this without a worker taking it had its message lost (broker down
# at submission, a purged queue): the tick sends it again; duplicates are harmless.
RESEND_QUEUED_AFTER = timedelta(minutes=2)


@dataclass(frozen=True)
class WorkerContext:
    factory: SessionFactory
    registry: JobRegistry
    heartbeat_seconds: float = HEARTBEAT_SECONDS
    stale_after: timedelta = STALE_AFTER
    estimation_workers: int = 1  # processes an estimation job spreads engine groups over


_context: WorkerContext | None = None


def worker_context() -> WorkerContext:
    """The database and job kinds of this worker process, made on first use (after the fork)."""
    global _context
    if _context is None:
        from app.config import get_settings
        from app.db import make_engine, make_sessionmaker

        settings = get_settings()
        engine = make_engine(settings.resolved_database_url)
        _context = WorkerContext(
            factory=make_sessionmaker(engine),
            registry=load_kinds(),
            heartbeat_seconds=settings.job_heartbeat_seconds,
            stale_after=settings.job_stale_after,
            estimation_workers=settings.estimation_workers,
        )
    return _context


def configure(
    factory: SessionFactory, registry: JobRegistry, estimation_workers: int = 1
) -> None:
    """Use this database and registry instead of the settings' (a worker inside a test)."""
    global _context
    _context = WorkerContext(factory=factory, registry=registry,
                             estimation_workers=estimation_workers)


@celery.task(name=RUN_JOB_TASK, bind=True)
def run_job(self: Any, job_id: int) -> str:
    context = worker_context()
    claim = claim_job(context.factory, job_id, worker=worker_name("celery"),
                      serial_kinds=context.registry.serial_kinds())
    if claim is None:
        return "not queued"
    # Jobs this job queues go to the queue this worker took it from.
    queue = (self.request.delivery_info or {}).get("routing_key") or CELERY_QUEUE
    dispatcher = CeleryDispatch(queue, celery)
    # An estimation job sends its engine groups to the same queue (``estimate_group``).
    groups.configure(CeleryGroups(context.estimation_workers, queue, celery))
    return execute(
        context.factory, claim, context.registry, dispatcher=dispatcher,
        heartbeat_seconds=context.heartbeat_seconds,
    )


@celery.task(name=ESTIMATE_GROUP_TASK)
def estimate_group(operator_id: int, engine_ids: list[int],
                   drifts: list[list[Any]] | None = None) -> dict[str, Any]:
    """An engine group of an estimation job (``app.services.snapshots.groups``): whatever of
    it no other process holds, learning from the pass's wear drifts (``drifts.FleetDrifts``
    as a message; a message sent without them: as stored now). A redelivered or late message
    finds its engines done."""
    context = worker_context()
    with context.factory() as session:
        return store.run_group(session, operator_id, engine_ids,
                               None if drifts is None else FleetDrifts.from_message(drifts))


@celery.task(name=TICK_TASK)
def tick() -> dict[str, list[int]]:
    context = worker_context()
    requeued = requeue_stale(context.factory, stale_after=context.stale_after)
    lost = queued_before(context.factory, utcnow() - RESEND_QUEUED_AFTER)
    submitted = submit_due(context.factory, context.registry)
    dispatcher = CeleryDispatch(celery=celery)
    for job_id in sorted(set(requeued) | set(lost) | set(submitted)):
        dispatcher.dispatch(job_id)
    return {"requeued": requeued, "resent": lost, "submitted": submitted}


@worker_ready.connect
def _requeue_on_start(sender: Any = None, **_kwargs: Any) -> None:
    """A worker starting after a crash sends the jobs the crashed worker left running again:
    at once those of a stopped process of this host (orphans), the others once stale.

    This runs in the pool's parent process: its engine is thrown away afterwards, so pool
    processes forked later never inherit its connections.
    """
    from app.config import get_settings
    from app.db import make_engine, make_sessionmaker

    settings = get_settings()
    engine = make_engine(settings.resolved_database_url)
    try:
        queue = CeleryDispatch(_queue_of(sender), celery)
        factory = make_sessionmaker(engine)
        orphans = requeue_orphans(factory)
        stale = requeue_stale(factory, stale_after=settings.job_stale_after)
        for job_id in sorted(set(orphans) | set(stale)):
            queue.dispatch(job_id)
    except Exception:  # the worker must start even if the database is not there yet
        log.exception("requeueing stale jobs at worker start failed")
    finally:
        engine.dispose()


def _queue_of(sender: Any) -> str:
    try:
        queues = sender.app.amqp.queues.consume_from
        return str(next(iter(queues)))
    except Exception:
        return celery.conf.task_default_queue  # type: ignore[no-any-return]
