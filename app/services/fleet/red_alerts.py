"""Engines whose limit checks turned red since notifications last looked, queued as
notifications (``app.services.notifications.outbox``).

After each estimation run the fleet status is judged (only for operators with an enabled
channel) and each engine's level compared with the one stored in ``engine_alert_levels``. An
engine going red through its limits (health change, EGT margin, thrust deficit, rate of change)
is notified once; one red only through an isolated fault is not, its event's notification
says it already. An engine that leaves red and comes back is notified again. The first look
for an operator notifies the engines red at that time.
"""

from __future__ import annotations

from sqlalchemy import select
from sqlalchemy.orm import Session

from app.db import read_phase
from app.models.base import utcnow
from app.models.notifications import EngineAlertLevel
from app.services.fleet.status import fleet_status
from app.services.notifications import outbox


def queue_turned_red(session: Session, operator_id: int, *, reads_apart: bool = False) -> int:
    """Queue the notifications of engines turned red; store every engine's level. Returns
    the number of engines turned red. ``reads_apart``: the caller (a job) owns the commits,
    and the fleet status is read before the write lock is taken (``app.db.read_phase``)."""
    with read_phase(session, reads_apart):
        if not outbox.has_channels(session, operator_id):
            return 0
        known = {
            row.engine_id: row
            for row in session.scalars(
                select(EngineAlertLevel).where(EngineAlertLevel.operator_id == operator_id)
            )
        }
        engines = fleet_status(session, operator_id)["engines"]
    now = utcnow()
    turned: list[outbox.TurnedRed] = []
    for engine in engines:
        level = engine["severity"] or "normal"
        row = known.get(engine["engine_id"])
        if row is not None and row.level == level:
            continue
        red_checks = tuple(c for c in engine["checks"] if c["level"] == "red")
        if level == "red" and red_checks:
            turned.append(outbox.TurnedRed(
                engine_id=engine["engine_id"], esn=engine["esn"], tail=engine["tail"],
                position=engine["position"], reason=engine["reason"], red_checks=red_checks,
            ))
        if row is None:
            session.add(EngineAlertLevel(engine_id=engine["engine_id"], operator_id=operator_id,
                                         level=level, changed_at=now))
        else:
            row.level, row.changed_at = level, now
    outbox.queue_turned_red(session, operator_id, turned)
    return len(turned)
