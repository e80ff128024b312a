"""The delivery log: an operator's deliveries, newest first, each with its attempts."""

from __future__ import annotations

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.models.notifications import DeliveryAttempt, NotificationDelivery


def list_deliveries(
    session: Session, *, operator_id: int, channel_id: int | None = None, limit: int = 50,
    offset: int = 0,
) -> tuple[list[tuple[NotificationDelivery, list[DeliveryAttempt]]], int]:
    """The page of deliveries with their attempts (oldest attempt first), and the total."""
    conditions = [NotificationDelivery.operator_id == operator_id]
    if channel_id is not None:
        conditions.append(NotificationDelivery.channel_id == channel_id)
    total = session.scalar(
        select(func.count()).select_from(NotificationDelivery).where(*conditions)
    ) or 0
    rows = list(session.scalars(
        select(NotificationDelivery).where(*conditions)
        .order_by(NotificationDelivery.id.desc()).limit(limit).offset(offset)
    ))
    attempts: dict[int, list[DeliveryAttempt]] = {r.id: [] for r in rows}
    if rows:
        for a in session.scalars(
            select(DeliveryAttempt).where(DeliveryAttempt.delivery_id.in_(list(attempts)))
            .order_by(DeliveryAttempt.id)
        ):
            attempts[a.delivery_id].append(a)
    return [(r, attempts[r.id]) for r in rows], total
