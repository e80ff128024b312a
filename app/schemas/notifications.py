"""Notification channels and the delivery log as the API shows them. Secrets (a webhook's
signing secret, the SMTP password) are write-only: a webhook's secret is in its creation
response only, the password never."""

from __future__ import annotations

import re
from typing import Annotated, Any, Literal
from urllib.parse import urlsplit

from pydantic import AwareDatetime, BaseModel, Field, field_validator, model_validator

from app.schemas.fleet import Row, StrictInput

_ADDRESS = re.compile(r"^[^@\s,<>]+@[^@\s,<>]+\.[^@\s,<>]+$")


def _address(value: str) -> str:
    if not _ADDRESS.match(value):
        raise ValueError(f"{value!r} is not an e-mail address (name@domain)")
    return value


class WebhookCreate(StrictInput):
    kind: Literal["webhook"]
    name: str = Field(min_length=1, max_length=200)
    url: str = Field(min_length=1, max_length=2000,
                     description="http(s) URL that receives a signed POST per alert")

    @field_validator("url")
    @classmethod
    def _http_url(cls, value: str) -> str:
        parts = urlsplit(value)
        if parts.scheme not in ("http", "https") or not parts.hostname:
            raise ValueError("must be an http:// or https:// URL with a host")
        return value


class EmailCreate(StrictInput):
    kind: Literal["email"]
    name: str = Field(min_length=1, max_length=200)
    smtp_host: str = Field(min_length=1, max_length=255, pattern=r"^[A-Za-z0-9.\-\[\]:]+$")
    smtp_port: int = Field(587, ge=1, le=65535)
    starttls: bool = Field(False, description="upgrade the connection with STARTTLS")
    username: str | None = Field(None, min_length=1, max_length=255)
    password: str | None = Field(None, min_length=1, max_length=255,
                                 description="write-only; never returned")
    mail_from: str = Field(max_length=320)
    mail_to: list[str] = Field(min_length=1, max_length=20)

    _from = field_validator("mail_from")(classmethod(lambda cls, v: _address(v)))

    @field_validator("mail_to")
    @classmethod
    def _recipients(cls, value: list[str]) -> list[str]:
        return [_address(v.strip()) for v in value]

    @model_validator(mode="after")
    def _login_pair(self) -> EmailCreate:
        if (self.username is None) != (self.password is None):
            raise ValueError("username and password go together: give both or neither")
        return self


ChannelCreate = Annotated[WebhookCreate | EmailCreate, Field(discriminator="kind")]


class ChannelUpdate(StrictInput):
    enabled: bool


class ChannelOut(Row):
    id: int
    kind: str
    name: str
    enabled: bool
    url: str | None
    smtp_host: str | None
    smtp_port: int | None
    starttls: bool
    username: str | None
    has_password: bool = False
    mail_from: str | None
    mail_to: list[str] | None
    created_at: AwareDatetime

    @model_validator(mode="before")
    @classmethod
    def _from_row(cls, data: Any) -> Any:
        if isinstance(data, dict):
            return data
        return {
            "id": data.id, "kind": data.kind, "name": data.name, "enabled": data.enabled,
            "url": data.url, "smtp_host": data.smtp_host, "smtp_port": data.smtp_port,
            "starttls": data.smtp_starttls, "username": data.smtp_username,
            "has_password": data.smtp_password is not None, "mail_from": data.mail_from,
            "mail_to": None if data.mail_to is None
            else [a.strip() for a in data.mail_to.split(",") if a.strip()],
            "created_at": data.created_at,
        }


class ChannelCreated(ChannelOut):
    secret: str | None = Field(
        None, description="a webhook's HMAC-SHA256 signing secret; shown only in this response"
    )


class AttemptOut(Row):
    attempted_at: AwareDatetime
    ok: bool
    status_code: int | None
    error: str | None
    duration_ms: float


class DeliveryOut(BaseModel):
    id: int
    channel_id: int
    event_id: int | None
    subject: str
    status: str
    attempts: int
    next_attempt_at: AwareDatetime
    created_at: AwareDatetime
    sent_at: AwareDatetime | None
    log: list[AttemptOut]


class TestQueued(BaseModel):
    delivery_id: int
    job_id: int
