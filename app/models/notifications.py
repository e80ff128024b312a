"""Notification channels of an operator (webhooks, e-mail) and the deliveries queued to them.

A delivery is written in the transaction that raised its event (the estimation job's) and sent
after that commits by the ``send_notifications`` job; each try is kept as a ``DeliveryAttempt``
(time, HTTP status or error, duration), so the delivery log shows why one failed.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

from sqlalchemy import (
    JSON,
    Boolean,
    CheckConstraint,
    Float,
    ForeignKey,
    Index,
    Integer,
    String,
    Text,
)
from sqlalchemy.orm import Mapped, mapped_column

from app.models.base import Base, UTCDateTime, utcnow

CHANNEL_KINDS = ("webhook", "email")
DELIVERY_STATUSES = ("pending", "sent", "failed")


class NotificationChannel(Base):
    """Where an operator's alerts go. A webhook has ``url`` and ``secret`` (HMAC-SHA256 key,
    shown once at creation); an e-mail channel has the SMTP settings. Secrets and the SMTP
    password are never returned by the API."""

    __tablename__ = "notification_channels"
    __table_args__ = (
        CheckConstraint("kind IN ('webhook', 'email')", name="kind"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    operator_id: Mapped[int] = mapped_column(
        ForeignKey("operators.id", ondelete="CASCADE"), index=True
    )
    kind: Mapped[str] = mapped_column(String(16))
    name: Mapped[str] = mapped_column(String(200))
    enabled: Mapped[bool] = mapped_column(Boolean, default=True)
    url: Mapped[str | None] = mapped_column(String(2000), default=None)
    secret: Mapped[str | None] = mapped_column(String(200), default=None)
    smtp_host: Mapped[str | None] = mapped_column(String(255), default=None)
    smtp_port: Mapped[int | None] = mapped_column(Integer, default=None)
    smtp_starttls: Mapped[bool] = mapped_column(Boolean, default=False)
    smtp_username: Mapped[str | None] = mapped_column(String(255), default=None)
    smtp_password: Mapped[str | None] = mapped_column(String(255), default=None)
    mail_from: Mapped[str | None] = mapped_column(String(320), default=None)
    mail_to: Mapped[str | None] = mapped_column(Text, default=None)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime(), default=utcnow)


class NotificationDelivery(Base):
    """One message to one channel: its payload, and where its sending stands."""

    __tablename__ = "notification_deliveries"
    __table_args__ = (
        CheckConstraint("status IN ('pending', 'sent', 'failed')", name="status"),
        Index("ix_notification_deliveries_operator_status", "operator_id", "status"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    operator_id: Mapped[int] = mapped_column(ForeignKey("operators.id", ondelete="CASCADE"))
    channel_id: Mapped[int] = mapped_column(
        ForeignKey("notification_channels.id", ondelete="CASCADE"), index=True
    )
    event_id: Mapped[int | None] = mapped_column(
        ForeignKey("events.id", ondelete="SET NULL"), index=True, default=None
    )
    subject: Mapped[str] = mapped_column(String(300))
    payload: Mapped[dict[str, Any]] = mapped_column(JSON)
    status: Mapped[str] = mapped_column(String(16), default="pending")
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    next_attempt_at: Mapped[datetime] = mapped_column(UTCDateTime(), default=utcnow)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime(), default=utcnow)
    sent_at: Mapped[datetime | None] = mapped_column(UTCDateTime(), default=None)


class DeliveryAttempt(Base):
    """One try at sending a delivery: when, the HTTP status (webhooks) or the error, and how
    long it took."""

    __tablename__ = "delivery_attempts"

    id: Mapped[int] = mapped_column(primary_key=True)
    delivery_id: Mapped[int] = mapped_column(
        ForeignKey("notification_deliveries.id", ondelete="CASCADE"), index=True
    )
    attempted_at: Mapped[datetime] = mapped_column(UTCDateTime(), default=utcnow)
    ok: Mapped[bool] = mapped_column(Boolean)
    status_code: Mapped[int | None] = mapped_column(Integer, default=None)
    error: Mapped[str | None] = mapped_column(Text, default=None)
    duration_ms: Mapped[float] = mapped_column(Float)


class EngineAlertLevel(Base):
    """An engine's severity when notifications last looked (``normal``, ``amber``, ``red``):
    an engine whose limit checks go red from another level is notified once, not at every
    estimation run while it stays red."""

    __tablename__ = "engine_alert_levels"
    __table_args__ = (CheckConstraint("level IN ('normal', 'amber', 'red')", name="level"),)

    engine_id: Mapped[int] = mapped_column(
        ForeignKey("engines.id", ondelete="CASCADE"), primary_key=True
    )
    operator_id: Mapped[int] = mapped_column(
        ForeignKey("operators.id", ondelete="CASCADE"), index=True
    )
    level: Mapped[str] = mapped_column(String(8))
    changed_at: Mapped[datetime] = mapped_column(UTCDateTime(), default=utcnow)
