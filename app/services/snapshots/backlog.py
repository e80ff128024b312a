"""The estimation backlog: which engines have snapshots their estimates do not cover yet.

Whatever stores snapshots or changes what an engine's estimates depend on adds a mark for the
engine in its own transaction (``mark``): an upload with the earliest of its new records and
their count, a maintenance action from its time, a design activation or a change of engine
type to continue from the filter state. The estimation job reads an engine's marks
(``pending``), runs it, and deletes exactly the marks it read (``settle``) in the transaction
that stores its estimates; a mark added meanwhile stays for the next pass, with its own time.

An engine's marks combine (``Mark``): the earliest time wins (None, "continue from the filter
state", loses to any time), and counts add up, unknown once one of them is.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from datetime import datetime

from sqlalchemy import delete, insert, select
from sqlalchemy.orm import Session

from app.models import Engine, EstimatorDesign
from app.models.estimates import EstimationBacklog


@dataclass(frozen=True)
class Mark:
    """An engine's pending work, from its marks ``ids``: re-run from before ``earliest``
    (None: continue), ``rows`` new records (None: unknown)."""

    earliest: datetime | None
    rows: int | None
    ids: tuple[int, ...]


def mark(
    session: Session, operator_id: int, engines: Mapping[int, tuple[datetime | None, int | None]]
) -> None:
    """Mark engines: id -> (earliest record concerned or None, number of new records or None);
    one INSERT."""
    if not engines:
        return
    session.execute(insert(EstimationBacklog), [
        {"operator_id": operator_id, "engine_id": int(engine_id), "earliest": earliest,
         "rows": rows}
        for engine_id, (earliest, rows) in sorted(engines.items())
    ])


def mark_from_start(session: Session, operator_id: int, engine_ids: Iterable[int]) -> None:
    """Mark engines whose estimates must be brought up to date under what is now their
    design (a design activated, an engine type changed), with unknown counts."""
    mark(session, operator_id, {int(e): (None, None) for e in engine_ids})


def pending(
    session: Session, operator_id: int, engine_ids: Iterable[int] | None = None
) -> dict[int, Mark]:
    """The marked engines that have an active design to be estimated under, with their
    marks combined."""
    query = (
        select(EstimationBacklog.id, EstimationBacklog.engine_id, EstimationBacklog.earliest,
               EstimationBacklog.rows)
        .join(Engine, Engine.id == EstimationBacklog.engine_id)
        .join(EstimatorDesign, (EstimatorDesign.engine_type_id == Engine.engine_type_id)
              & EstimatorDesign.active.is_(True))
        .where(EstimationBacklog.operator_id == operator_id)
        .order_by(EstimationBacklog.engine_id, EstimationBacklog.id)
    )
    if engine_ids is not None:
        query = query.where(EstimationBacklog.engine_id.in_([int(e) for e in engine_ids]))
    out: dict[int, Mark] = {}
    for mark_id, engine_id, earliest, rows in session.execute(query).all():
        seen = out.get(engine_id)
        if seen is None:
            out[engine_id] = Mark(earliest, rows, (mark_id,))
            continue
        times = [t for t in (seen.earliest, earliest) if t is not None]
        out[engine_id] = Mark(
            min(times) if times else None,
            None if seen.rows is None or rows is None else seen.rows + rows,
            (*seen.ids, mark_id),
        )
    return out


def settle(session: Session, marks: Iterable[Mark]) -> None:
    """Delete the marks the job has done."""
    ids = [i for m in marks for i in m.ids]
    if ids:
        session.execute(
            delete(EstimationBacklog).where(EstimationBacklog.id.in_(ids))
            .execution_options(synchronize_session=False)
        )


def drop_undesigned(session: Session, operator_id: int) -> None:
    """Delete the marks of engines whose type has no active design: activating one (or moving
    the engine to a type that has one) marks them again from the start, so these would only
    pile up, one per upload, in front of every later read of the backlog."""
    designed = (
        select(EstimatorDesign.id)
        .where(EstimatorDesign.engine_type_id == Engine.engine_type_id,
               EstimatorDesign.active.is_(True))
        .exists()
    )
    undesigned = (
        select(EstimationBacklog.id)
        .join(Engine, Engine.id == EstimationBacklog.engine_id)
        .where(EstimationBacklog.operator_id == operator_id, ~designed)
    )
    session.execute(
        delete(EstimationBacklog).where(EstimationBacklog.id.in_(undesigned))
        .execution_options(synchronize_session=False)
    )
