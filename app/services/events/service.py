"""Events: list, assign, acknowledge, comment, close. The pipeline opens them
(app/services/snapshots/store.py). Each event read carries its confidence (posterior over the
fault hypotheses, ambiguity group, the design's confusion row: ``confidence``) and its history.

Status moves open -> acknowledged -> closed (open -> closed directly is allowed too); a closed
event cannot be acknowledged or assigned again, and acknowledging or closing twice is a no-op, so
a retried request does not fail. Acknowledging and closing take a reason. An event is assigned to
a person: an active analyst or admin API key of the operator (the identity every action is
recorded under, as ``acknowledged_by`` and ``closed_by`` are). Every step (assigned, unassigned,
acknowledged, commented, closed) is kept in ``event_history`` under the acting key's name. Every
action is scoped to the caller's operator: another operator's event is not found.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

from sqlalchemy import and_, func, or_, select
from sqlalchemy.orm import Session, selectinload

from app.errors import Conflict, InvalidInput, NotFound
from app.models import Aircraft, ApiKey, Engine, Installation
from app.models.base import utcnow
from app.models.estimates import Event, EventComment, EventHistory
from app.services.events.confidence import DesignEvidence, design_evidence, event_confidence
from app.services.tenancy.service import Principal


def get_event(session: Session, operator_id: int, event_id: int) -> Event:
    event = session.get(Event, event_id)
    if event is None or event.operator_id != operator_id:
        raise NotFound(f"event {event_id} not found")
    return event


def _installed(session: Session, events: list[Event]) -> dict[int, tuple[str, int]]:
    """event id -> (tail, position) of the engine at the time the event was detected."""
    if not events:
        return {}
    out: dict[int, tuple[str, int]] = {}
    engine_ids = {e.engine_id for e in events}
    rows = session.execute(
        select(Installation.engine_id, Installation.installed_at, Installation.removed_at,
               Installation.position, Aircraft.tail)
        .join(Aircraft, Aircraft.id == Installation.aircraft_id)
        .where(Installation.engine_id.in_(engine_ids))
    ).all()
    for event in events:
        for engine_id, installed, removed, position, tail in rows:
            if engine_id != event.engine_id:
                continue
            if installed <= event.detected_at and (removed is None or event.detected_at < removed):
                out[event.id] = (tail, position)
                break
    return out


def _evidence(
    session: Session, operator_id: int, events: list[Event]
) -> dict[int, DesignEvidence]:
    """design id -> its tuner count and measured confusion, once per design of the events."""
    return {d: design_evidence(session, operator_id, d) for d in {e.design_id for e in events}}


# Roles that can act on an event, so can be assigned one.
ASSIGNABLE_ROLES = ("analyst", "admin")


def assignees(session: Session, operator_id: int) -> list[dict[str, Any]]:
    """The people an event can be assigned to: active analyst and admin keys, by name."""
    rows = session.execute(
        select(ApiKey.id, ApiKey.name, ApiKey.role)
        .where(ApiKey.operator_id == operator_id, ApiKey.revoked_at.is_(None),
               ApiKey.role.in_(ASSIGNABLE_ROLES))
        .order_by(ApiKey.name, ApiKey.id)
    ).all()
    return [{"key_id": i, "name": n, "role": r} for i, n, r in rows]


def _keys(session: Session, key_ids: set[int]) -> dict[int, ApiKey]:
    if not key_ids:
        return {}
    rows = session.scalars(select(ApiKey).where(ApiKey.id.in_(key_ids))).all()
    return {k.id: k for k in rows}


def _last_reason(event: Event, action: str) -> str | None:
    reasons = [h.reason for h in event.history if h.action == action]
    return reasons[-1] if reasons else None


def event_out(
    event: Event, esn: str, where: tuple[str, int] | None,
    evidence: DesignEvidence | None = None, assignee: ApiKey | None = None,
) -> dict[str, Any]:
    shift = event.shift or {}
    return {
        "id": event.id,
        "engine_id": event.engine_id,
        "esn": esn,
        "tail": None if where is None else where[0],
        "position": None if where is None else where[1],
        "design_id": event.design_id,
        "seq": event.seq,
        "detected_at": event.detected_at,
        "kind": event.kind,
        "fault": event.fault,
        "magnitude": event.magnitude,
        "statistic": event.statistic,
        "wssr": event.wssr,
        "wssr_threshold": shift.get("wssr_threshold"),
        "tuner_shift": shift.get("tuners", {}),
        "health_shift": shift.get("health", {}),
        "fault_shift": shift.get("fault", {}),
        "status": event.status,
        "acknowledged_at": event.acknowledged_at,
        "acknowledged_by": event.acknowledged_by,
        "closed_at": event.closed_at,
        "closed_by": event.closed_by,
        "acknowledged_reason": _last_reason(event, "acknowledged"),
        "closed_reason": _last_reason(event, "closed"),
        "assignee": None if assignee is None else
        {"key_id": assignee.id, "name": assignee.name, "role": assignee.role},
        "comments": list(event.comments),
        "history": list(event.history),
        "confidence": None if evidence is None else event_confidence(event, evidence),
    }


# Events not closed: open or acknowledged. The fleet page counts these, and the events page lists
# them by default, so the two always agree.
ACTIVE = "active"


def list_events(
    session: Session,
    operator_id: int,
    *,
    status: str | None = None,
    engine_id: int | None = None,
    kind: str | None = None,
    since: datetime | None = None,
    until: datetime | None = None,
    limit: int = 100,
    offset: int = 0,
) -> dict[str, Any]:
    """Events newest first, filtered; a page of ``EventOut`` dicts."""
    conditions = [Event.operator_id == operator_id]
    if status == ACTIVE:
        conditions.append(Event.status != "closed")
    elif status is not None:
        conditions.append(Event.status == status)
    if engine_id is not None:
        conditions.append(Event.engine_id == engine_id)
    if kind is not None:
        conditions.append(Event.kind == kind)
    if since is not None:
        conditions.append(Event.detected_at >= since)
    if until is not None:
        conditions.append(Event.detected_at < until)
    total = session.scalar(select(func.count()).select_from(Event).where(*conditions)) or 0
    rows = session.execute(
        select(Event, Engine.esn)
        .join(Engine, Engine.id == Event.engine_id)
        .where(*conditions)
        .options(selectinload(Event.comments), selectinload(Event.history))
        .order_by(Event.detected_at.desc(), Event.id.desc())
        .limit(limit)
        .offset(offset)
    ).all()
    events = [e for e, _ in rows]
    where = _installed(session, events)
    evidence = _evidence(session, operator_id, events)
    keys = _keys(session, {e.assignee_key_id for e in events if e.assignee_key_id is not None})
    return {
        "items": [
            event_out(e, esn, where.get(e.id), evidence[e.design_id],
                      None if e.assignee_key_id is None else keys.get(e.assignee_key_id))
            for e, esn in rows
        ],
        "total": total,
        "limit": limit,
        "offset": offset,
    }


def show_event(session: Session, operator_id: int, event_id: int) -> dict[str, Any]:
    event = get_event(session, operator_id, event_id)
    engine = session.get(Engine, event.engine_id)
    assert engine is not None
    assignee = None if event.assignee_key_id is None else session.get(ApiKey, event.assignee_key_id)
    return event_out(
        event, engine.esn, _installed(session, [event]).get(event.id),
        design_evidence(session, operator_id, event.design_id), assignee,
    )


def _actor(session: Session, principal: Principal) -> str:
    key = session.get(ApiKey, principal.key_id)
    return key.name if key is not None else f"{principal.operator_name} (key {principal.key_id})"


def _record(
    session: Session, event: Event, principal: Principal, action: str, *,
    reason: str | None = None, assignee: ApiKey | None = None,
) -> None:
    session.add(
        EventHistory(
            event_id=event.id, action=action, actor_key_id=principal.key_id,
            actor=_actor(session, principal),
            assignee_key_id=None if assignee is None else assignee.id,
            assignee=None if assignee is None else assignee.name,
            reason=reason,
        )
    )


def _reread(session: Session, principal: Principal, event: Event) -> dict[str, Any]:
    session.flush()
    session.refresh(event, ["comments", "history"])
    return show_event(session, principal.operator_id, event.id)


def _reason(reason: str) -> str:
    text = reason.strip()
    if not text:
        raise InvalidInput("a reason is required")
    return text


def assign(
    session: Session, principal: Principal, event_id: int, assignee_key_id: int | None
) -> dict[str, Any]:
    """Assign the event to an active analyst or admin key of the operator, or (None) to no
    one. Assigning to whom it is assigned already is a no-op."""
    event = get_event(session, principal.operator_id, event_id)
    if event.status == "closed":
        raise Conflict(f"event {event_id} is closed; it cannot be assigned")
    if assignee_key_id is None:
        if event.assignee_key_id is not None:
            event.assignee_key_id = None
            _record(session, event, principal, "unassigned")
        return _reread(session, principal, event)
    key = session.get(ApiKey, assignee_key_id)
    if (key is None or key.operator_id != principal.operator_id or key.revoked_at is not None
            or key.role not in ASSIGNABLE_ROLES):
        raise InvalidInput(
            f"unknown assignee: key {assignee_key_id} is not an active analyst or admin key "
            "of your operator",
            details=[{"field": "assignee_key_id", "reason": "unknown assignee"}],
        )
    if event.assignee_key_id != key.id:
        event.assignee_key_id = key.id
        _record(session, event, principal, "assigned", assignee=key)
    return _reread(session, principal, event)


def _comment(session: Session, event: Event, principal: Principal, body: str) -> None:
    session.add(
        EventComment(
            event_id=event.id,
            author_key_id=principal.key_id,
            author=principal.operator_name + f" (key {principal.key_id})",
            body=body,
        )
    )


def add_comment(
    session: Session, principal: Principal, event_id: int, body: str
) -> dict[str, Any]:
    event = get_event(session, principal.operator_id, event_id)
    _comment(session, event, principal, body)
    _record(session, event, principal, "commented", reason=body)
    return _reread(session, principal, event)


def acknowledge(
    session: Session, principal: Principal, event_id: int, reason: str
) -> dict[str, Any]:
    """Acknowledge an open event with a reason; a repeat is a no-op and stores nothing."""
    text = _reason(reason)
    event = get_event(session, principal.operator_id, event_id)
    if event.status == "closed":
        raise Conflict(f"event {event_id} is closed; it cannot be acknowledged")
    if event.status == "open":
        event.status = "acknowledged"
        event.acknowledged_at = utcnow()
        event.acknowledged_by = principal.key_id
        _record(session, event, principal, "acknowledged", reason=text)
    return _reread(session, principal, event)


def close(
    session: Session, principal: Principal, event_id: int, reason: str
) -> dict[str, Any]:
    """Close an event with a reason; closing a closed event is a no-op and stores nothing."""
    text = _reason(reason)
    event = get_event(session, principal.operator_id, event_id)
    if event.status != "closed":
        if event.acknowledged_at is None:
            event.acknowledged_at = utcnow()
            event.acknowledged_by = principal.key_id
        event.status = "closed"
        event.closed_at = utcnow()
        event.closed_by = principal.key_id
        _record(session, event, principal, "closed", reason=text)
    return _reread(session, principal, event)


def open_event_counts(session: Session, operator_id: int) -> dict[int, int]:
    """engine id -> number of events not closed."""
    rows = session.connection().execute(
        select(Event.engine_id, func.count())
        .where(Event.operator_id == operator_id, Event.status != "closed")
        .group_by(Event.engine_id)
    ).all()
    return {engine_id: int(n) for engine_id, n in rows}


def latest_open_events(session: Session, operator_id: int) -> dict[int, Any]:
    """engine id -> its most recent event that is not closed: (id, engine_id, detected_at,
    kind, fault, magnitude, status), not its detection documents."""
    newest = (
        select(Event.engine_id, func.max(Event.detected_at).label("at"))
        .where(Event.operator_id == operator_id, Event.status != "closed")
        .group_by(Event.engine_id)
        .subquery()
    )
    rows = session.connection().execute(
        select(Event.id, Event.engine_id, Event.detected_at, Event.kind, Event.fault,
               Event.magnitude, Event.status).join(
            newest,
            and_(Event.engine_id == newest.c.engine_id, Event.detected_at == newest.c.at),
        ).where(or_(Event.status == "open", Event.status == "acknowledged"))
    ).all()
    return {e.engine_id: e for e in rows}
