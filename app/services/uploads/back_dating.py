"""Late or back-dated uploads, and the events they caused.

An upload is back-dated when, for an engine it affects, its earliest new record is older than
the engine's last estimated record at upload time (``estimated_until``: the latest
``FilterState.last_recorded_at`` under the engine type's active design). The estimation job
then re-runs the engine from that earliest record (``snapshots.store`` restart points) and
redoes the estimates and events after it.

The events an upload caused, for each engine it affects: those an estimation run created
after the upload was stored (``Event.created_at``), detected at or after the upload's
earliest record for the engine, and detected either at one of the upload's own records or,
when back-dated, at a record already estimated when it arrived (up to ``estimated_until``).
Events on later uploads' records are theirs; an event a later back-dated upload redid over
the same records is linked to both, as both re-runs produced it.

An upload is late when records arrive long after they were recorded: ``late_rows`` counts its
new records recorded more than the lateness (``upload_lateness_days``, default ``LATENESS``)
before it arrived, stored as ``Upload.rows_late``.
"""

from __future__ import annotations

from collections.abc import Iterable
from datetime import datetime, timedelta

import pyarrow as pa
import pyarrow.compute as pc
from sqlalchemy import ColumnElement, and_, func, or_, select
from sqlalchemy.orm import Session

from app.models import Engine, EstimatorDesign, Event, FilterState, Snapshot, Upload
from app.services import common

LATENESS = timedelta(days=7)


def late_rows(fresh: pa.Table, arrived_at: datetime, lateness: timedelta) -> int:
    """How many of the records were recorded more than ``lateness`` before ``arrived_at``."""
    if fresh.num_rows == 0:
        return 0
    recorded = fresh["recorded_at"]
    cutoff = pa.scalar(arrived_at - lateness, recorded.type)
    return int(pc.sum(pc.less(recorded, cutoff)).as_py() or 0)


def estimated_until(session: Session, engine_ids: Iterable[int]) -> dict[int, datetime]:
    """Each engine's last estimated record under its type's active design (engines with no
    estimates are left out)."""
    ids = [int(e) for e in engine_ids]
    if not ids:
        return {}
    rows = session.execute(
        select(FilterState.engine_id, func.max(FilterState.last_recorded_at))
        .join(Engine, Engine.id == FilterState.engine_id)
        .join(EstimatorDesign, (EstimatorDesign.id == FilterState.design_id)
              & (EstimatorDesign.engine_type_id == Engine.engine_type_id)
              & EstimatorDesign.active.is_(True))
        .where(FilterState.engine_id.in_(ids), FilterState.last_recorded_at.is_not(None))
        .group_by(FilterState.engine_id)
    ).all()
    return {int(engine_id): until for engine_id, until in rows if until is not None}


def caused_events(session: Session, upload: Upload) -> list[Event]:
    """The events the upload caused (module docstring), oldest first."""
    if upload.status != "stored" or not upload.affected:
        return []
    own = select(Snapshot.recorded_at).where(
        Snapshot.engine_id == Event.engine_id,
        Snapshot.recorded_at == Event.detected_at,
        Snapshot.upload_id == upload.id,
    ).exists()
    per_engine = []
    for a in upload.affected:
        earliest = datetime.fromisoformat(a["earliest"])
        until = a.get("estimated_until")
        reached: ColumnElement[bool] = own
        if upload.back_dated and until is not None:
            reached = or_(own, Event.detected_at <= datetime.fromisoformat(until))
        per_engine.append(and_(Event.engine_id == int(a["engine_id"]),
                               Event.detected_at >= earliest, reached))
    return list(session.scalars(
        select(Event)
        .where(Event.operator_id == upload.operator_id,
               Event.created_at >= upload.created_at, or_(*per_engine))
        .order_by(Event.detected_at, Event.id)
    ))


def uploads_of_event(session: Session, operator_id: int, event_id: int) -> list[Upload]:
    """The uploads that caused the event (the inverse of ``caused_events``), oldest first:
    the upload of the record it was detected at, and the back-dated uploads whose re-run
    reached it."""
    event = common.owned(session, Event, operator_id, event_id, "event")
    found: dict[int, Upload] = {}
    own = session.scalar(
        select(Upload).join(Snapshot, Snapshot.upload_id == Upload.id).where(
            Snapshot.engine_id == event.engine_id, Snapshot.recorded_at == event.detected_at,
            Upload.operator_id == operator_id, Upload.created_at <= event.created_at,
        )
    )
    if own is not None:
        found[own.id] = own
    back_dated = session.scalars(
        select(Upload).where(
            Upload.operator_id == operator_id, Upload.status == "stored",
            Upload.back_dated.is_(True), Upload.created_at <= event.created_at,
        )
    )
    for upload in back_dated:
        for a in upload.affected:
            until = a.get("estimated_until")
            if (int(a["engine_id"]) == event.engine_id and until is not None
                    and datetime.fromisoformat(a["earliest"]) <= event.detected_at
                    <= datetime.fromisoformat(until)):
                found[upload.id] = upload
    return [found[k] for k in sorted(found)]
