"""The embedded default's engine-group workers: a pool of processes that estimate the engine
groups an estimation job hands out (``app.services.snapshots.groups``).

The job process (``app.jobs.host``) starts ``estimation_workers - 1`` pool processes (spawned:
fresh interpreters) on the same database; each keeps its engine and estimator caches between
groups, as the job process does. A group is sent and forgotten: the job waits on the engines'
locks, not on the pool, and estimates itself what a group left undone. A pool whose process died
is broken for further groups: the next launch starts a new one.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import threading
import time
from collections.abc import Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from sqlalchemy.orm import Session, sessionmaker

from app.config import Settings
from app.services.snapshots.drifts import FleetDrifts

log = logging.getLogger("fleethealth.jobs")


class PoolLauncher:
    """A ``groups.Launcher`` over a process pool of ``workers - 1`` processes."""

    def __init__(self, settings: Settings) -> None:
        self.workers = settings.estimation_workers
        self._settings = settings.model_dump(mode="json")
        self._pool: ProcessPoolExecutor | None = None
        self._lock = threading.Lock()

    def _executor(self) -> ProcessPoolExecutor:
        if self._pool is None:
            self._pool = ProcessPoolExecutor(
                max_workers=self.workers - 1, mp_context=multiprocessing.get_context("spawn"),
                initializer=_start_worker, initargs=(self._settings,),
            )
        return self._pool

    def start(self, *, wait: bool = False) -> None:
        """Start the pool's processes now (their imports take seconds), not at the first job;
        ``wait``: until they are ready."""
        with self._lock:
            ready = [self._executor().submit(_ready) for _ in range(self.workers - 1)]
        if wait:
            for future in ready:
                future.result()

    def launch(self, operator_id: int, groups: Sequence[Sequence[int]],
               drifts: FleetDrifts) -> None:
        with self._lock:
            for group in groups:
                try:
                    future = self._executor().submit(_run_group, operator_id, list(group),
                                                     drifts)
                except BrokenProcessPool:  # a process of it died: a new pool for the rest
                    self._pool = None
                    future = self._executor().submit(_run_group, operator_id, list(group),
                                                     drifts)
                future.add_done_callback(_report)

    def stop(self) -> None:
        with self._lock:
            if self._pool is not None:
                self._pool.shutdown(wait=True, cancel_futures=True)
                self._pool = None


def _report(future: Future[Any]) -> None:
    if not future.cancelled() and future.exception() is not None:
        log.error("an engine group failed (the job estimates what it left): %s",
                  future.exception())


_factory: sessionmaker[Session] | None = None


def _start_worker(settings_doc: dict[str, Any]) -> None:
    """A pool process's start: its logging and database."""
    global _factory
    from app.db import make_engine, make_sessionmaker
    from app.log import configure_logging
    from app.services import fresh_records

    settings = Settings(**settings_doc)
    configure_logging(settings.log_level, settings.log_json)
    _factory = make_sessionmaker(make_engine(settings.resolved_database_url))
    fresh_records.configure(enabled=True,
                            spool=fresh_records.spool_directory(settings.data_dir))
    threading.Thread(target=_exit_with_parent, args=(os.getppid(),), daemon=True,
                     name="fleethealth-pool-watch").start()


def _exit_with_parent(parent: int) -> None:
    """Exit when the job process is gone (killed: no pool shutdown told us), dropping an
    unfinished group: its engines' locks go with the connection, their marks stay."""
    while os.getppid() == parent:
        time.sleep(1.0)
    os._exit(0)


def _ready() -> None:
    from app.services.snapshots import estimator, store  # noqa: F401  (its imports, now)

    estimator.prepare()


def _run_group(operator_id: int, engine_ids: list[int], drifts: FleetDrifts) -> dict[str, Any]:
    from app.services.snapshots import store

    assert _factory is not None, "pool process not started"
    with _factory() as session:
        return store.run_group(session, operator_id, engine_ids, drifts)
