"""Snapshots follow the installation history: when an installation is recorded or corrected,
the snapshots stored for its tail position over its period go to the engine it puts there.

An upload resolves each record to the engine installed at the record's tail position and time.
When the history changes afterwards (an engine swap entered late, a wrong removal date put
right), records already stored over the changed period are resolved again: each one inside an
installation's period moves to that installation's engine; one that no installation covers
any more stays with the engine it had (its history is not dropped). Both engines of a move are
marked in the estimation backlog from the earliest record moved, so their trends are redone.
A move onto an engine that has a snapshot of its own at the same time is refused (409).
"""

from __future__ import annotations

from collections.abc import Iterable
from datetime import datetime

from sqlalchemy import func, select, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from app.errors import Conflict
from app.models import Installation, Snapshot
from app.services import fresh_records
from app.services.snapshots import backlog

Window = tuple[int, int, datetime, datetime | None]  # aircraft id, position, [start, end)


def follow_installations(session: Session, operator_id: int, windows: Iterable[Window]) -> int:
    """Give the snapshots of each window's tail position and period to the engines the
    installation history now puts there; returns how many moved."""
    moved_total = 0
    earliest: dict[int, datetime] = {}
    for aircraft_id, position, start, end in windows:
        overlapping = [Installation.aircraft_id == aircraft_id, Installation.position == position,
                       Installation.removed_at.is_(None) | (Installation.removed_at > start)]
        if end is not None:
            overlapping.append(Installation.installed_at < end)
        periods = session.execute(
            select(Installation.engine_id, Installation.installed_at, Installation.removed_at)
            .where(*overlapping)
        ).all()
        for engine_id, installed_at, removed_at in periods:
            lo = max(start, installed_at)
            his = [t for t in (end, removed_at) if t is not None]
            where = [Snapshot.aircraft_id == aircraft_id, Snapshot.position == position,
                     Snapshot.engine_id != engine_id, Snapshot.recorded_at >= lo]
            if his:
                where.append(Snapshot.recorded_at < min(his))
            movers = session.execute(
                select(Snapshot.engine_id, func.min(Snapshot.recorded_at), func.count())
                .where(*where).group_by(Snapshot.engine_id)
            ).all()
            if not movers:
                continue
            try:
                with session.begin_nested():
                    session.execute(
                        update(Snapshot).where(*where).values(engine_id=engine_id)
                        .execution_options(synchronize_session=False)
                    )
            except IntegrityError:
                raise Conflict(
                    "the change moves stored snapshots onto an engine that has snapshots of "
                    "its own at the same times; nothing was changed",
                    details=[{"engine_id": engine_id, "from_engines": [m[0] for m in movers]}],
                ) from None
            for old_engine, first, count in movers:
                moved_total += int(count)
                for e in (int(old_engine), int(engine_id)):
                    earliest[e] = min(first, earliest.get(e, first))
    if earliest:
        backlog.mark(session, operator_id, {e: (t, None) for e, t in earliest.items()})
        fresh_records.discard(session, earliest, moved=True)  # kept rows name the old engines
    return moved_total
