"""Sending pending deliveries, with retries and backoff, each attempt logged.

A failed attempt is retried after ``backoff * 2**(attempts - 1)`` seconds, until
``max_attempts``; then the delivery is ``failed``. Each delivery's outcome is committed on its
own (``commit``), so a restart never sends a delivered message again.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime, timedelta

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.models.base import utcnow
from app.models.notifications import DeliveryAttempt, NotificationChannel, NotificationDelivery
from app.services.notifications import mail, webhook
from app.services.notifications.outcome import Outcome


@dataclass(frozen=True)
class RetryPolicy:
    backoff_seconds: float = 30.0
    max_attempts: int = 5

    def delay(self, attempts: int) -> timedelta:
        """The wait after the ``attempts``-th failed attempt."""
        return timedelta(seconds=self.backoff_seconds * 2 ** (attempts - 1))


@dataclass
class SendCounts:
    sent: int = 0
    retrying: int = 0
    failed: int = 0


def body(delivery: NotificationDelivery) -> bytes:
    return json.dumps(
        {"delivery_id": delivery.id, **delivery.payload}, sort_keys=True, separators=(",", ":")
    ).encode()


def mail_text(delivery: NotificationDelivery) -> str:
    return delivery.subject + "\n\n" + json.dumps(delivery.payload, indent=2, sort_keys=True)


def attempt(channel: NotificationChannel, delivery: NotificationDelivery, now: datetime) -> Outcome:
    """One try at sending ``delivery`` over ``channel``."""
    if channel.kind == "webhook":
        assert channel.url is not None and channel.secret is not None
        return webhook.post(channel.url, channel.secret, body(delivery), int(now.timestamp()))
    assert channel.smtp_host is not None and channel.smtp_port is not None
    assert channel.mail_from is not None and channel.mail_to is not None
    settings = mail.SmtpSettings(
        host=channel.smtp_host, port=channel.smtp_port, mail_from=channel.mail_from,
        mail_to=tuple(a.strip() for a in channel.mail_to.split(",") if a.strip()),
        starttls=channel.smtp_starttls, username=channel.smtp_username,
        password=channel.smtp_password,
    )
    return mail.send(settings, delivery.subject, mail_text(delivery))


def send_due(
    session: Session, operator_id: int, policy: RetryPolicy, commit: Callable[[], None],
) -> SendCounts:
    """Try every pending delivery of the operator that is due now, once."""
    counts = SendCounts()
    due = session.execute(
        select(NotificationDelivery, NotificationChannel)
        .join(NotificationChannel, NotificationChannel.id == NotificationDelivery.channel_id)
        .where(
            NotificationDelivery.operator_id == operator_id,
            NotificationDelivery.status == "pending",
            NotificationDelivery.next_attempt_at <= utcnow(),
        )
        .order_by(NotificationDelivery.id)
    ).tuples().all()
    for delivery, channel in due:
        now = utcnow()
        outcome = attempt(channel, delivery, now)
        session.add(DeliveryAttempt(
            delivery_id=delivery.id, attempted_at=now, ok=outcome.ok,
            status_code=outcome.status_code, error=outcome.error,
            duration_ms=outcome.duration_ms,
        ))
        delivery.attempts += 1
        if outcome.ok:
            delivery.status, delivery.sent_at = "sent", utcnow()
            counts.sent += 1
        elif delivery.attempts >= policy.max_attempts:
            delivery.status = "failed"
            counts.failed += 1
        else:
            delivery.next_attempt_at = utcnow() + policy.delay(delivery.attempts)
            counts.retrying += 1
        commit()
    return counts


def next_due(session: Session, operator_id: int) -> datetime | None:
    """When the operator's next pending delivery is due, or None when none is pending."""
    return session.scalar(
        select(func.min(NotificationDelivery.next_attempt_at)).where(
            NotificationDelivery.operator_id == operator_id,
            NotificationDelivery.status == "pending",
        )
    )
