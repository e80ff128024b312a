"""The embedded default's job host: the job runner and scheduler in a child process of the server.

Jobs are numerical work in Python (filters, detection, evaluations). In the server's own
process they would share its interpreter lock with the requests: every upload and every page
would wait on the job's compute, and one of the machine's cores would sit idle. ``fleethealth
serve`` therefore starts its runner and scheduler (``app.jobs.background``) in a child process
on the same database and wakes it through a pipe when a request queues a job.

On PostgreSQL the child also starts the pool of processes an estimation job spreads its engine
groups over (``app.jobs.engine_groups``, ``estimation_workers - 1`` of them).

The child lives only as long as the server: it stops when the server sends "stop" (finishing
its running jobs for a few seconds, as the in-process runner does) and exits at once when the
pipe breaks, i.e. when the server died. A job it was running then has a dead claimant, and the
next server to start on this host takes it over at once (``app.jobs.claim.requeue_orphans``).
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import threading
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess
from typing import Any

from app.config import Settings

log = logging.getLogger("fleethealth.jobs")

_BEGIN, _WAKE, _STOP = b"b", b"w", b"s"


class JobHost:
    """The server's handle on its job process: a dispatcher (``dispatch`` wakes the runner)."""

    def __init__(self, process: BaseProcess, pipe: Connection) -> None:
        self.process = process
        self._pipe = pipe
        self._lock = threading.Lock()

    def begin(self) -> None:
        """Let the runner start (once the database is migrated and the server is up)."""
        with self._lock:
            self._pipe.send_bytes(_BEGIN)

    def dispatch(self, job_id: int) -> None:
        """Wake the runner; a lost wake-up only delays the job (the runner polls)."""
        with self._lock:
            try:
                self._pipe.send_bytes(_WAKE)
            except OSError:
                log.warning("the job process is gone; job %s waits for the next start", job_id)

    def stop(self, timeout: float = 15.0) -> None:
        """Ask the runner to stop (it waits a few seconds for running jobs), then end it."""
        with self._lock:
            try:
                self._pipe.send_bytes(_STOP)
            except OSError:
                pass
            self._pipe.close()
        self.process.join(timeout)
        if self.process.is_alive():
            self.process.terminate()
            self.process.join(5.0)


def start_job_host(settings: Settings) -> JobHost:
    """Start the job process for ``settings``' database (a fresh interpreter: spawn). It
    imports the job kinds meanwhile, and starts running jobs at ``begin``: starting it first
    thing, the server's own start-up overlaps its own."""
    context = multiprocessing.get_context("spawn")
    ours, theirs = context.Pipe()
    process = context.Process(
        target=_serve_jobs, args=(settings.model_dump(mode="json"), theirs),
        name="fleethealth-jobs", daemon=True,
    )
    process.start()
    theirs.close()
    return JobHost(process, ours)


def _serve_jobs(settings_doc: dict[str, Any], pipe: Connection) -> None:
    """The child's main: the runner and scheduler until "stop" (graceful) or a broken pipe
    (the server died: exit at once, leaving running jobs to the next server's takeover)."""
    from app.db import make_engine, make_sessionmaker
    from app.jobs.background import start_background_jobs
    from app.jobs.engine_groups import PoolLauncher
    from app.jobs.kinds import load_kinds
    from app.log import configure_logging
    from app.services.snapshots import groups

    settings = Settings(**settings_doc)
    configure_logging(settings.log_level, settings.log_json)
    registry = load_kinds()
    from app.services import fresh_records

    # The server's uploads leave their rows for the estimation jobs in its spool.
    fresh_records.configure(enabled=True,
                            spool=fresh_records.spool_directory(settings.data_dir))

    def receive() -> bytes:
        try:
            return pipe.recv_bytes()
        except (EOFError, OSError):
            os._exit(0)  # the server is gone: so is this process, with its claims

    while (message := receive()) != _BEGIN:
        if message == _STOP:
            return
    engine = make_engine(settings.resolved_database_url)
    pool = None
    if settings.estimation_workers > 1 and engine.dialect.name == "postgresql":
        # The server ends this process with itself (``daemon``); its pool's processes end
        # with it in turn (``engine_groups``), which multiprocessing refuses to a daemon's
        # children unless told this process is not one.
        multiprocessing.current_process().daemon = False
        pool = PoolLauncher(settings)
        # Ready before the first job: a process still importing (seconds on a small machine)
        # would take a core from the job and its groups would wait behind that.
        try:
            pool.start(wait=True)
        except Exception as exc:  # a worker that died starting: the first launch starts anew
            log.warning("engine-group workers did not start (%s); jobs go on without them "
                        "until a launch starts them again", exc)
        groups.configure(pool)
    from app.services.snapshots import estimator

    estimator.prepare()  # the built-in engine's tables, before the first job rather than in it
    background = start_background_jobs(
        make_sessionmaker(engine), registry,
        heartbeat_seconds=settings.job_heartbeat_seconds, stale_after=settings.job_stale_after,
    )
    while (message := receive()) != _STOP:
        background.runner.dispatch(0)
    background.stop()
    if pool is not None:
        groups.configure(None)
        pool.stop()
    engine.dispose()
