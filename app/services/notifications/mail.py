"""E-mail deliveries over SMTP: optional STARTTLS, optional login."""

from __future__ import annotations

import smtplib
import ssl
from dataclasses import dataclass
from email.message import EmailMessage

from app.services.notifications.outcome import Outcome, timed

TIMEOUT_SECONDS = 10.0


@dataclass(frozen=True)
class SmtpSettings:
    host: str
    port: int
    mail_from: str
    mail_to: tuple[str, ...]
    starttls: bool = False
    username: str | None = None
    password: str | None = None


def message(settings: SmtpSettings, subject: str, text: str) -> EmailMessage:
    msg = EmailMessage()
    msg["From"] = settings.mail_from
    msg["To"] = ", ".join(settings.mail_to)
    msg["Subject"] = subject
    msg.set_content(text)
    return msg


def send(settings: SmtpSettings, subject: str, text: str) -> Outcome:
    """Send one message; never raises: failures are the outcome (SMTP code when refused)."""
    with timed() as clock:
        code: int | None = None
        error: str | None = None
        try:
            with smtplib.SMTP(settings.host, settings.port, timeout=TIMEOUT_SECONDS) as smtp:
                if settings.starttls:
                    smtp.starttls(context=ssl.create_default_context())
                if settings.username:
                    smtp.login(settings.username, settings.password or "")
                smtp.send_message(message(settings, subject, text))
        except smtplib.SMTPResponseException as exc:
            code, error = int(exc.smtp_code), f"SMTP {exc.smtp_code}: {exc.smtp_error!r}"
        except smtplib.SMTPRecipientsRefused as exc:
            error = f"recipients refused: {sorted(exc.recipients)}"
        except (smtplib.SMTPException, OSError) as exc:
            error = f"{type(exc).__name__}: {exc}"
    return Outcome(ok=error is None, status_code=code, error=error, duration_ms=clock.ms)
