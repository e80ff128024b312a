"""Alert notifications of the caller's operator (admin only): webhook and e-mail channels,
a test message, and the delivery log."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Body, Query, status

from app.schemas.fleet import Deleted, Page, PageParams
from app.schemas.notifications import (
    AttemptOut,
    ChannelCreate,
    ChannelCreated,
    ChannelOut,
    ChannelUpdate,
    DeliveryOut,
    TestQueued,
    WebhookCreate,
)
from app.security import Admin, DbSession
from app.services.jobs.queue import Jobs
from app.services.notifications import channels, deliveries, outbox
from app.services.notifications.mail import SmtpSettings

router = APIRouter(prefix="/api/v1/notifications", tags=["notifications"])


@router.get("/channels", response_model=list[ChannelOut])
def list_channels(session: DbSession, principal: Admin) -> list[ChannelOut]:
    rows = channels.list_channels(session, operator_id=principal.operator_id)
    return [ChannelOut.model_validate(r) for r in rows]


@router.post("/channels", response_model=ChannelCreated, status_code=status.HTTP_201_CREATED)
def create_channel(
    body: Annotated[ChannelCreate, Body()], session: DbSession, principal: Admin
) -> ChannelCreated:
    """A webhook (its signing ``secret`` is in this response only) or an e-mail channel."""
    if isinstance(body, WebhookCreate):
        row, secret = channels.create_webhook(
            session, operator_id=principal.operator_id,
            spec=channels.WebhookSpec(name=body.name, url=body.url),
        )
        return ChannelCreated(**ChannelOut.model_validate(row).model_dump(), secret=secret)
    row = channels.create_mail(
        session, operator_id=principal.operator_id,
        name=body.name,
        spec=SmtpSettings(
            host=body.smtp_host, port=body.smtp_port, mail_from=body.mail_from,
            mail_to=tuple(body.mail_to), starttls=body.starttls, username=body.username,
            password=body.password,
        ),
    )
    return ChannelCreated(**ChannelOut.model_validate(row).model_dump())


@router.patch("/channels/{channel_id}", response_model=ChannelOut)
def update_channel(
    channel_id: int, body: ChannelUpdate, session: DbSession, principal: Admin
) -> ChannelOut:
    row = channels.set_enabled(
        session, operator_id=principal.operator_id, channel_id=channel_id, enabled=body.enabled
    )
    return ChannelOut.model_validate(row)


@router.delete("/channels/{channel_id}", response_model=Deleted)
def delete_channel(channel_id: int, session: DbSession, principal: Admin) -> Deleted:
    """Delete the channel with its deliveries and their log."""
    channels.delete_channel(session, operator_id=principal.operator_id, channel_id=channel_id)
    return Deleted(id=channel_id)


@router.post("/channels/{channel_id}/test", response_model=TestQueued,
             status_code=status.HTTP_202_ACCEPTED)
def send_test(channel_id: int, session: DbSession, principal: Admin, jobs: Jobs) -> TestQueued:
    """Queue a test message to the channel; the delivery log shows how it went."""
    channel = channels.get_channel(
        session, operator_id=principal.operator_id, channel_id=channel_id
    )
    delivery = outbox.queue_test(session, channel=channel)
    job = jobs.notify(session, operator_id=principal.operator_id)
    return TestQueued(delivery_id=delivery.id, job_id=job.id)


@router.get("/deliveries", response_model=Page[DeliveryOut])
def list_deliveries(
    session: DbSession,
    principal: Admin,
    page: Annotated[PageParams, Query()],
    channel_id: int | None = None,
) -> Page[DeliveryOut]:
    """Deliveries, newest first, each with its log of attempts."""
    rows, total = deliveries.list_deliveries(
        session, operator_id=principal.operator_id, channel_id=channel_id, limit=page.limit,
        offset=page.offset,
    )
    items = [
        DeliveryOut(
            id=d.id, channel_id=d.channel_id, event_id=d.event_id, subject=d.subject,
            status=d.status, attempts=d.attempts, next_attempt_at=d.next_attempt_at,
            created_at=d.created_at, sent_at=d.sent_at,
            log=[AttemptOut.model_validate(a) for a in log],
        )
        for d, log in rows
    ]
    return Page.of(items, total, page)
