"""Deliveries queued in the caller's transaction: one per enabled channel for each event the
estimation pipeline raises, and a test message on demand. Nothing is sent here; the
``send_notifications`` job sends them once the transaction commits, so sending never slows or
breaks the pipeline."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from sqlalchemy import exists, select
from sqlalchemy.orm import Session

from app.models import Engine
from app.models.base import utcnow
from app.models.estimates import EVENT_LEVEL, Event
from app.models.notifications import NotificationChannel, NotificationDelivery

KIND_TEXT = {"isolated_fault": "isolated fault", "shift": "shift", "wear": "wear alert"}


def event_payload(event: Event, esn: str) -> dict[str, Any]:
    """The JSON a channel receives for a raised event."""
    return {
        "type": "event.raised",
        "event": {
            "id": event.id, "engine_id": event.engine_id, "esn": esn, "kind": event.kind,
            "severity": EVENT_LEVEL.get(event.kind, "amber"), "fault": event.fault,
            "magnitude": event.magnitude, "statistic": event.statistic,
            "detected_at": event.detected_at.isoformat(), "design_id": event.design_id,
        },
    }


def event_subject(event: Event, esn: str) -> str:
    what = KIND_TEXT.get(event.kind, event.kind)
    fault = f" ({event.fault})" if event.fault else ""
    level = EVENT_LEVEL.get(event.kind, "amber")
    return f"[{level}] engine {esn}: {what}{fault} at {event.detected_at:%Y-%m-%d %H:%M} UTC"


@dataclass(frozen=True)
class TurnedRed:
    """An engine whose limit checks went red: what a channel is told."""

    engine_id: int
    esn: str
    tail: str | None
    position: int | None
    reason: str | None
    red_checks: tuple[dict[str, Any], ...]


def has_channels(session: Session, operator_id: int) -> bool:
    """Whether the operator has an enabled channel (else nothing needs judging)."""
    return bool(session.scalar(select(exists().where(
        NotificationChannel.operator_id == operator_id,
        NotificationChannel.enabled.is_(True),
    ))))


def queue_turned_red(session: Session, operator_id: int, engines: Sequence[TurnedRed]) -> int:
    """A pending delivery per enabled channel for each engine turned red; how many."""
    channels = _enabled(session, operator_id) if engines else []
    now = utcnow()
    rows = [
        NotificationDelivery(
            operator_id=operator_id, channel_id=channel.id, event_id=None,
            subject=f"[red] engine {e.esn}"
            + (f" on {e.tail} position {e.position}" if e.tail else "")
            + f": {e.reason or 'limits exceeded'}"[:250],
            payload={"type": "engine.turned_red", "engine": {
                "id": e.engine_id, "esn": e.esn, "tail": e.tail, "position": e.position,
                "severity": "red", "reason": e.reason, "checks": list(e.red_checks)}},
            status="pending", attempts=0, next_attempt_at=now, created_at=now,
        )
        for e in engines
        for channel in channels
    ]
    session.add_all(rows)
    session.flush()
    return len(rows)


def _enabled(session: Session, operator_id: int) -> list[NotificationChannel]:
    return list(session.scalars(
        select(NotificationChannel).where(
            NotificationChannel.operator_id == operator_id,
            NotificationChannel.enabled.is_(True),
        ).order_by(NotificationChannel.id)
    ))


def queue_events(session: Session, operator_id: int, events: Sequence[Event]) -> int:
    """A pending delivery per enabled channel for each of ``events`` (flushed, with ids);
    how many were queued."""
    if not events:
        return 0
    channels = _enabled(session, operator_id)
    if not channels:
        return 0
    esn = dict(session.execute(
        select(Engine.id, Engine.esn).where(Engine.id.in_({e.engine_id for e in events}))
    ).tuples().all())
    now = utcnow()
    rows = [
        NotificationDelivery(
            operator_id=operator_id, channel_id=channel.id, event_id=event.id,
            subject=event_subject(event, esn[event.engine_id]),
            payload=event_payload(event, esn[event.engine_id]), status="pending", attempts=0,
            next_attempt_at=now, created_at=now,
        )
        for event in events
        for channel in channels
    ]
    session.add_all(rows)
    session.flush()
    return len(rows)


def queue_test(session: Session, *, channel: NotificationChannel) -> NotificationDelivery:
    """A test message to one channel (enabled or not)."""
    now = utcnow()
    row = NotificationDelivery(
        operator_id=channel.operator_id, channel_id=channel.id, event_id=None,
        subject=f"fleethealth test message to {channel.name}",
        payload={"type": "test", "channel": channel.name, "sent_for": now.isoformat()},
        status="pending", attempts=0, next_attempt_at=now, created_at=now,
    )
    session.add(row)
    session.flush()
    return row


def has_pending(session: Session, operator_id: int) -> bool:
    return bool(session.scalar(select(exists().where(
        NotificationDelivery.operator_id == operator_id,
        NotificationDelivery.status == "pending",
    ))))
