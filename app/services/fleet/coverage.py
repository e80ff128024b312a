"""Data coverage of the fleet: each tail's and each engine's last record, and the engines
whose data is overdue.

An engine is overdue when it is installed on a tail and its last record (or, without any,
its installation) is older than the overdue age (``data_overdue_days``): an installed engine
reports every flight, an engine in the shop does not. A tail's last data is its newest record
from any position. Each last record is one index look-up (snapshots are keyed by engine and
time, and indexed by tail, position and time), whatever the fleet's size.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime, timedelta

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.models import Aircraft, Engine, Snapshot
from app.models.base import utcnow
from app.models.fleet import MAX_POSITIONS
from app.services.fleet.service import current_placements


@dataclass(frozen=True)
class EngineCoverage:
    engine_id: int
    esn: str
    aircraft_id: int | None
    tail: str | None
    position: int | None
    installed_at: datetime | None
    last_data: datetime | None
    overdue: bool


@dataclass(frozen=True)
class TailCoverage:
    aircraft_id: int
    tail: str
    last_data: datetime | None
    engines_installed: int
    engines_overdue: int


@dataclass(frozen=True)
class Coverage:
    now: datetime
    overdue_after: timedelta
    tails: list[TailCoverage]
    engines: list[EngineCoverage]


def data_coverage(
    session: Session, operator_id: int, *, overdue_after: timedelta, now: datetime | None = None
) -> Coverage:
    """Tails by tail number, engines overdue first, then by their last data (oldest first);
    ages counted to ``now`` (default: the present)."""
    now = now or utcnow()
    last_of_engine = (
        select(func.max(Snapshot.recorded_at))
        .where(Snapshot.engine_id == Engine.id)
        .scalar_subquery()
    )
    installed = current_placements(session, operator_id)
    cutoff = now - overdue_after
    engines = []
    for engine_id, esn, last in session.execute(
        select(Engine.id, Engine.esn, last_of_engine).where(Engine.operator_id == operator_id)
    ).all():
        where = installed.get(engine_id)
        seen = last if last is not None else (None if where is None else where.installed_at)
        engines.append(EngineCoverage(
            engine_id=engine_id, esn=esn,
            aircraft_id=None if where is None else where.aircraft_id,
            tail=None if where is None else where.tail,
            position=None if where is None else where.position,
            installed_at=None if where is None else where.installed_at,
            last_data=last,
            overdue=where is not None and seen is not None and seen < cutoff,
        ))
    engines.sort(key=lambda e: (not e.overdue, e.last_data is not None,
                                e.last_data or now, e.esn))
    by_position = [
        select(func.max(Snapshot.recorded_at))
        .where(Snapshot.aircraft_id == Aircraft.id, Snapshot.position == p)
        .scalar_subquery()
        for p in range(1, MAX_POSITIONS + 1)
    ]
    tails = []
    for aircraft_id, tail, *lasts in session.execute(
        select(Aircraft.id, Aircraft.tail, *by_position)
        .where(Aircraft.operator_id == operator_id)
        .order_by(Aircraft.tail)
    ).all():
        found = [t for t in lasts if t is not None]
        on_tail = [e for e in engines if e.aircraft_id == aircraft_id]
        tails.append(TailCoverage(
            aircraft_id=aircraft_id, tail=tail, last_data=max(found) if found else None,
            engines_installed=len(on_tail), engines_overdue=sum(e.overdue for e in on_tail),
        ))
    return Coverage(now=now, overdue_after=overdue_after, tails=tails, engines=engines)
