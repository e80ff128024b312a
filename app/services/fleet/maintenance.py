"""Maintenance actions (water wash, module change, shop visit, borescope finding) of an
operator's engines.

Each wash, module change and shop visit restarts the engine's detection baseline
(``baseline_resets`` gives the times the detection step starts a new baseline from); a
borescope finding is the record of an inspection and restarts nothing. Recording, moving or
deleting an action marks the engine in the estimation backlog from the action's time, so the
estimation job re-runs what the action changes.
"""

from __future__ import annotations

from collections.abc import Mapping
from datetime import datetime
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from app.models import Engine, MaintenanceAction
from app.models.fleet import BASELINE_RESET_KINDS
from app.services.common import apply_changes, delete_or_conflict, owned, paginate, referenced
from app.services.snapshots import backlog


def record_action(
    session: Session,
    *,
    operator_id: int,
    engine_id: int,
    kind: str,
    performed_at: datetime,
    notes: str = "",
) -> MaintenanceAction:
    referenced(session, Engine, operator_id, engine_id, "engine_id", "engine")
    row = MaintenanceAction(
        operator_id=operator_id,
        engine_id=engine_id,
        kind=kind,
        performed_at=performed_at,
        notes=notes,
    )
    session.add(row)
    session.flush()
    _mark(session, operator_id, (engine_id, performed_at))
    return row


def _mark(session: Session, operator_id: int, *at: tuple[int, datetime]) -> None:
    """Mark engines from the times of actions recorded, moved or deleted (no new records)."""
    earliest: dict[int, datetime] = {}
    for engine_id, performed_at in at:
        earliest[engine_id] = min(performed_at, earliest.get(engine_id, performed_at))
    backlog.mark(session, operator_id, {e: (t, 0) for e, t in earliest.items()})


def get_action(session: Session, *, operator_id: int, action_id: int) -> MaintenanceAction:
    return owned(session, MaintenanceAction, operator_id, action_id, "maintenance action")


def list_actions(
    session: Session,
    *,
    operator_id: int,
    limit: int,
    offset: int,
    engine_id: int | None = None,
    kind: str | None = None,
    since: datetime | None = None,
    until: datetime | None = None,
) -> tuple[list[MaintenanceAction], int]:
    """Actions, newest first, optionally of one engine, one kind, in [since, until)."""
    stmt = select(MaintenanceAction).where(MaintenanceAction.operator_id == operator_id)
    if engine_id is not None:
        stmt = stmt.where(MaintenanceAction.engine_id == engine_id)
    if kind is not None:
        stmt = stmt.where(MaintenanceAction.kind == kind)
    if since is not None:
        stmt = stmt.where(MaintenanceAction.performed_at >= since)
    if until is not None:
        stmt = stmt.where(MaintenanceAction.performed_at < until)
    stmt = stmt.order_by(MaintenanceAction.performed_at.desc(), MaintenanceAction.id.desc())
    return paginate(session, stmt, limit=limit, offset=offset)


def update_action(
    session: Session, *, operator_id: int, action_id: int, changes: Mapping[str, Any]
) -> MaintenanceAction:
    row = get_action(session, operator_id=operator_id, action_id=action_id)
    before = (row.engine_id, row.performed_at)
    apply_changes(row, changes)
    session.flush()
    _mark(session, operator_id, before, (row.engine_id, row.performed_at))
    return row


def delete_action(session: Session, *, operator_id: int, action_id: int) -> None:
    row = get_action(session, operator_id=operator_id, action_id=action_id)
    at = (row.engine_id, row.performed_at)
    delete_or_conflict(session, row, f"maintenance action {row.id} is still referenced")
    _mark(session, operator_id, at)


def baseline_resets(
    session: Session, *, operator_id: int, engine_id: int, since: datetime | None = None
) -> list[datetime]:
    """Times of the engine's maintenance actions that restart the detection baseline, oldest
    first: each starts a new baseline."""
    stmt = select(MaintenanceAction.performed_at).where(
        MaintenanceAction.operator_id == operator_id, MaintenanceAction.engine_id == engine_id,
        MaintenanceAction.kind.in_(BASELINE_RESET_KINDS),
    )
    if since is not None:
        stmt = stmt.where(MaintenanceAction.performed_at >= since)
    return list(session.scalars(stmt.order_by(MaintenanceAction.performed_at)))
