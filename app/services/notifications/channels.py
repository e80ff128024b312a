"""An operator's notification channels: create (a webhook's signing secret shown once), list,
enable or disable, delete. Callers pass the session and commit it."""

from __future__ import annotations

import secrets
from dataclasses import dataclass

from sqlalchemy import select
from sqlalchemy.orm import Session

from app.errors import NotFound
from app.models.notifications import NotificationChannel
from app.services.notifications.mail import SmtpSettings


@dataclass(frozen=True)
class WebhookSpec:
    name: str
    url: str



def new_secret() -> str:
    """A webhook signing secret: 256 random bits, URL-safe."""
    return "whsec_" + secrets.token_urlsafe(32)


def create_webhook(session: Session, *, operator_id: int, spec: WebhookSpec) -> tuple[
    NotificationChannel, str
]:
    """The new channel and its secret (stored to sign with; the API shows it only now)."""
    secret = new_secret()
    row = NotificationChannel(
        operator_id=operator_id, kind="webhook", name=spec.name, enabled=True, url=spec.url,
        secret=secret, smtp_starttls=False,
    )
    session.add(row)
    session.flush()
    return row, secret


def create_mail(
    session: Session, *, operator_id: int, name: str, spec: SmtpSettings
) -> NotificationChannel:
    row = NotificationChannel(
        operator_id=operator_id, kind="email", name=name, enabled=True,
        smtp_host=spec.host, smtp_port=spec.port, smtp_starttls=spec.starttls,
        smtp_username=spec.username, smtp_password=spec.password, mail_from=spec.mail_from,
        mail_to=", ".join(spec.mail_to),
    )
    session.add(row)
    session.flush()
    return row


def list_channels(session: Session, *, operator_id: int) -> list[NotificationChannel]:
    return list(
        session.scalars(
            select(NotificationChannel)
            .where(NotificationChannel.operator_id == operator_id)
            .order_by(NotificationChannel.id)
        )
    )


def get_channel(session: Session, *, operator_id: int, channel_id: int) -> NotificationChannel:
    """The operator's channel; another operator's is not found."""
    row = session.get(NotificationChannel, channel_id)
    if row is None or row.operator_id != operator_id:
        raise NotFound(f"notification channel {channel_id} not found")
    return row


def set_enabled(
    session: Session, *, operator_id: int, channel_id: int, enabled: bool
) -> NotificationChannel:
    row = get_channel(session, operator_id=operator_id, channel_id=channel_id)
    row.enabled = enabled
    session.flush()
    return row


def delete_channel(session: Session, *, operator_id: int, channel_id: int) -> None:
    """Delete a channel with its deliveries and their log."""
    row = get_channel(session, operator_id=operator_id, channel_id=channel_id)
    session.delete(row)
    session.flush()
