"""Engine groups: one operator's estimation backlog split into groups of engines that are
estimated in parallel, each engine by one process at a time.

An engine's estimation depends on nothing of another engine's, so the backlog splits by engine:
``split`` cuts it into ``GROUPS_PER_WORKER`` groups per worker, balanced by their new records.
The estimation job (``store.catch_up``) hands every group but the first to a ``Launcher`` (the
embedded default's process pool, a deployment's Celery workers: ``app.jobs.engine_groups``),
estimates the first itself, then takes from the last group backwards whatever no other process
has started, and at the end waits for the groups still running elsewhere. A group is run by
``store.estimate_group`` wherever it runs, as an ordinary pass over the engines' backlog marks: it
reads them, estimates, and settles exactly the marks it read with its estimates, committing
batch by batch.

One writer per engine: a process estimates an engine only under the engine's PostgreSQL
advisory lock (``ENGINE_LOCK``, taken on a connection of its own for the group's duration).
Other processes try the lock and leave an engine whose lock is taken; only the job waits for it.
An engine a worker finished has no marks left, so a group run twice (its message delivered
again, the job taking it first) estimates nothing twice. A worker that dies loses its
connection, hence its locks, and its uncommitted batch: the marks of what it did not commit
are still there, and the job, waiting on the locks, estimates them itself. Nothing of this runs
on SQLite, whose single writer leaves nothing to run in parallel: there the job estimates the
backlog alone, as it does when no launcher is configured (tests, one worker).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from typing import Protocol

from sqlalchemy import Engine, text
from sqlalchemy.orm import Session

from app.services.snapshots import backlog
from app.services.snapshots.drifts import FleetDrifts

# One group per worker: the snapshot filter steps through a group's engines together, so a
# group twice as wide costs little more per step, and half the steps (at 2,000,000 records of
# 58 engines, two groups took 14 % less of the estimation's CPU than four, in one process; the
# smaller groups' evening out at the end bought less than that).
GROUPS_PER_WORKER = 1
ENGINE_LOCK = 0x46480011  # first key of the engines' advisory locks (the second: the engine id)
_LOCKS = text("SELECT pg_advisory_lock(:key, e) FROM unnest(CAST(:ids AS integer[])) AS t(e)")
_TRY_LOCKS = text(
    "SELECT e FROM unnest(CAST(:ids AS integer[])) WITH ORDINALITY AS t(e, o) "
    "WHERE pg_try_advisory_lock(:key, e) ORDER BY o")
_UNLOCKS = text("SELECT pg_advisory_unlock(:key, e) FROM unnest(CAST(:ids AS integer[])) AS t(e)")


class Launcher(Protocol):
    """Where engine groups run besides the job's own process."""

    workers: int  # processes that estimate groups, the job's own included

    def launch(self, operator_id: int, groups: Sequence[Sequence[int]],
               drifts: FleetDrifts) -> None:
        """Start ``estimate_group`` on each group elsewhere (it may start late, or never:
        the job does what no one started), each learning from the pass's ``drifts``."""


_launcher: Launcher | None = None


def configure(launcher: Launcher | None) -> None:
    """Spread this process's estimation jobs over ``launcher`` (None: estimate alone)."""
    global _launcher
    _launcher = launcher


def launcher_for(session: Session) -> Launcher | None:
    """The configured launcher, if it has workers besides the job's own process and the
    database is PostgreSQL."""
    if _launcher is None or _launcher.workers < 2:
        return None
    return _launcher if session.get_bind().dialect.name == "postgresql" else None


def split(work: Mapping[int, backlog.Mark], n: int) -> list[list[int]]:
    """At most ``n`` groups of the backlog's engines, each engine in one, balanced by their
    new records (an engine whose count is unknown counts as the mean of the known): the
    largest engines first, each into the lightest group. Groups are in no particular order
    of size; each lists its engines by id."""
    known = [m.rows for m in work.values() if m.rows is not None]
    mean = sum(known) / len(known) if known else 1.0
    size = {e: float(m.rows if m.rows is not None else mean) for e, m in work.items()}
    groups: list[list[int]] = [[] for _ in range(max(1, min(n, len(work))))]
    loads = [0.0] * len(groups)
    for engine_id in sorted(work, key=lambda e: (-size[e], e)):
        lightest = loads.index(min(loads))
        groups[lightest].append(engine_id)
        loads[lightest] += size[engine_id]
    return [sorted(g) for g in groups]


@contextmanager
def engine_locks(bind: Engine, engine_ids: Sequence[int], *, wait: bool) -> Iterator[list[int]]:
    """Hold the advisory locks of ``engine_ids`` (on a connection of their own, so commits of
    the work do not end them): all of them, waiting for each (``wait``), or those free now.
    Yields the engines held; released at the end, or when the process dies."""
    connection = bind.connect().execution_options(isolation_level="AUTOCOMMIT")
    # One statement for all of them (in ascending order, as every process takes them) rather
    # than one each.
    wanted = sorted(int(e) for e in engine_ids)
    held: list[int] = []
    try:
        try:
            if wait and wanted:
                connection.execute(_LOCKS, {"key": ENGINE_LOCK, "ids": wanted})
                held = wanted
            elif wanted:  # those free now
                held = [int(e) for e in connection.execute(
                    _TRY_LOCKS, {"key": ENGINE_LOCK, "ids": wanted}).scalars()]
        except BaseException:
            # A statement cut short may hold some of the locks: the connection is dropped
            # (not pooled), and its session's locks end with it.
            connection.invalidate()
            raise
        yield held
    finally:
        try:
            if held:
                connection.execute(_UNLOCKS, {"key": ENGINE_LOCK, "ids": held})
        except BaseException:
            connection.invalidate()
            raise
        finally:
            connection.close()
