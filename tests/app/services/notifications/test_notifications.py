"""Alert notifications, on both databases: a webhook received by a local HTTP server with a
signature checked here from the secret alone, a failing endpoint retried with backoff and every
attempt logged, e-mail received by a local SMTP server with login, admin-only access, bad
settings refused with nothing stored, and an event raised by the estimation pipeline sent after
its job commits."""

from __future__ import annotations

import hashlib
import hmac
import json
import socket
import time

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import func, select
from sqlalchemy.orm import Session, sessionmaker

from app.jobs.kinds import load_kinds
from app.jobs.runner import run_pending
from app.models import Job, NotificationChannel, NotificationDelivery
from app.services.jobs import store as jobs_store
from app.services.notifications import channels, outbox
from app.services.notifications.mail import SmtpSettings
from app.services.snapshots import backlog
from tests.app.services.snapshots.test_pipeline import (
    N,
    _fleet_with_design,
    _records,
    _store_rows,
)
from tests.app.services.trends.test_trends import add_aircraft, add_engine
from tests.support.jobs import add_key, connection, make_operator
from tests.support.receivers import smtp_receiver, webhook_receiver

__all__ = ["connection"]  # the jobs' isolating connection: no other module's jobs run here

API = "/api/v1/notifications"


def _admin(session: Session, name: str) -> tuple[int, dict[str, str]]:
    operator, key = make_operator(session, name)
    session.commit()
    return operator.id, {"X-API-Key": key}


def _deliveries(client: TestClient, headers: dict[str, str]) -> list[dict]:
    response = client.get(f"{API}/deliveries", headers=headers)
    assert response.status_code == 200, response.text
    return response.json()["items"]


def _send_with(session: Session, operator_id: int, **parameters: float) -> None:
    jobs_store.submit(session, operator_id=operator_id, kind="send_notifications",
                      parameters=parameters, registry=load_kinds())
    session.commit()


def test_webhook_is_signed_with_the_secret_shown_once(
    client: TestClient, session: Session, session_factory: sessionmaker[Session]
) -> None:
    _operator_id, headers = _admin(session, "Hook Air")
    with webhook_receiver() as receiver:
        created = client.post(f"{API}/channels", headers=headers,
                              json={"kind": "webhook", "name": "ops", "url": receiver.url})
        assert created.status_code == 201, created.text
        secret = created.json()["secret"]
        assert secret and len(secret) > 30
        listed = client.get(f"{API}/channels", headers=headers).json()
        assert len(listed) == 1 and "secret" not in listed[0]
        assert secret not in json.dumps(listed)
        queued = client.post(f"{API}/channels/{listed[0]['id']}/test", headers=headers)
        assert queued.status_code == 202, queued.text
        run_pending(session_factory)
    assert len(receiver.requests) == 1
    request = receiver.requests[0]
    timestamp = int(request.headers["X-Fleethealth-Timestamp"])
    assert abs(time.time() - timestamp) < 60
    expected = hmac.new(secret.encode(), f"{timestamp}.".encode() + request.body,
                        hashlib.sha256).hexdigest()
    assert request.headers["X-Fleethealth-Signature"] == f"sha256={expected}"
    wrong = hmac.new(b"another secret", f"{timestamp}.".encode() + request.body,
                     hashlib.sha256).hexdigest()
    assert request.headers["X-Fleethealth-Signature"] != f"sha256={wrong}"
    body = json.loads(request.body)
    assert body["type"] == "test" and body["delivery_id"] == queued.json()["delivery_id"]
    [delivery] = _deliveries(client, headers)
    assert delivery["status"] == "sent" and delivery["attempts"] == 1
    [attempt] = delivery["log"]
    assert attempt["ok"] and attempt["status_code"] == 200 and attempt["error"] is None
    assert attempt["duration_ms"] > 0


def test_a_failing_endpoint_is_retried_with_backoff_and_every_attempt_logged(
    client: TestClient, session: Session, session_factory: sessionmaker[Session]
) -> None:
    operator_id, headers = _admin(session, "Retry Air")
    with webhook_receiver(codes=[500, 503, 200]) as receiver:
        row, _secret = channels.create_webhook(
            session, operator_id=operator_id,
            spec=channels.WebhookSpec(name="flaky", url=receiver.url))
        outbox.queue_test(session, channel=row)
        _send_with(session, operator_id, backoff_seconds=0.2)
        start = time.monotonic()
        run_pending(session_factory)
        elapsed = time.monotonic() - start
    assert len(receiver.requests) == 3
    assert elapsed >= 0.2 + 0.4  # waited 0.2 s, then 0.4 s (doubled) before the retries
    # The same delivery each time (the receiver can deduplicate by it).
    assert len({json.loads(r.body)["delivery_id"] for r in receiver.requests}) == 1
    [delivery] = _deliveries(client, headers)
    assert delivery["status"] == "sent" and delivery["attempts"] == 3
    assert [a["status_code"] for a in delivery["log"]] == [500, 503, 200]
    assert [a["ok"] for a in delivery["log"]] == [False, False, True]
    assert delivery["log"][0]["error"].startswith("HTTP 500")


def test_an_unreachable_endpoint_fails_after_its_attempts(
    client: TestClient, session: Session, session_factory: sessionmaker[Session]
) -> None:
    operator_id, headers = _admin(session, "Down Air")
    with socket.socket() as s:  # a port with nothing listening
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    row, _secret = channels.create_webhook(
        session, operator_id=operator_id,
        spec=channels.WebhookSpec(name="down", url=f"http://127.0.0.1:{port}/x"))
    outbox.queue_test(session, channel=row)
    _send_with(session, operator_id, backoff_seconds=0.05, max_attempts=3)
    [job_id] = run_pending(session_factory)
    job = session.get(Job, job_id, populate_existing=True)
    assert job is not None and job.status == "succeeded"
    assert job.result == {"sent": 0, "failed": 1, "retries": 2}
    [delivery] = _deliveries(client, headers)
    assert delivery["status"] == "failed" and len(delivery["log"]) == 3
    assert all(a["status_code"] is None and "refused" in a["error"].lower()
               for a in delivery["log"])


def test_email_reaches_the_smtp_server_with_login(
    client: TestClient, session: Session, session_factory: sessionmaker[Session]
) -> None:
    _operator_id, headers = _admin(session, "Mail Air")
    with smtp_receiver(credentials=("ops", "s3cret")) as smtp:
        created = client.post(f"{API}/channels", headers=headers, json={
            "kind": "email", "name": "line maintenance", "smtp_host": "127.0.0.1",
            "smtp_port": smtp.port, "mail_from": "fleet@example.org",
            "mail_to": ["mx@example.org", "eng@example.org"], "username": "ops",
            "password": "s3cret"})
        assert created.status_code == 201, created.text
        out = created.json()
        assert out["has_password"] and "password" not in out and "s3cret" not in created.text
        assert client.post(f"{API}/channels/{out['id']}/test", headers=headers).status_code == 202
        run_pending(session_factory)
    [mail] = smtp.messages
    assert mail.login == "ops"
    assert mail.mail_from == "fleet@example.org"
    assert mail.rcpt_to == ["mx@example.org", "eng@example.org"]
    assert mail.message["Subject"] == "fleethealth test message to line maintenance"
    assert '"type": "test"' in mail.message.get_payload()
    [delivery] = _deliveries(client, headers)
    assert delivery["status"] == "sent"


def test_wrong_smtp_password_is_logged_as_the_servers_refusal(
    client: TestClient, session: Session, session_factory: sessionmaker[Session]
) -> None:
    operator_id, headers = _admin(session, "Bad Login Air")
    with smtp_receiver(credentials=("ops", "right")) as smtp:
        row = channels.create_mail(session, operator_id=operator_id, name="mx", spec=SmtpSettings(
            host="127.0.0.1", port=smtp.port, mail_from="a@example.org",
            mail_to=("b@example.org",), username="ops", password="wrong"))
        outbox.queue_test(session, channel=row)
        _send_with(session, operator_id, backoff_seconds=0.05, max_attempts=2)
        run_pending(session_factory)
    assert smtp.messages == []
    [delivery] = _deliveries(client, headers)
    assert delivery["status"] == "failed"
    assert [a["status_code"] for a in delivery["log"]] == [535, 535]


@pytest.mark.parametrize("role", ["viewer", "analyst"])
def test_only_admins_reach_notifications(client: TestClient, session: Session, role: str) -> None:
    operator, _admin_key = make_operator(session, f"Roles Air {role}")
    key = add_key(session, operator, role)
    session.commit()
    headers = {"X-API-Key": key}
    hook = {"kind": "webhook", "name": "x", "url": "http://127.0.0.1:9/x"}
    assert client.get(f"{API}/channels", headers=headers).status_code == 403
    assert client.post(f"{API}/channels", headers=headers, json=hook).status_code == 403
    assert client.get(f"{API}/deliveries", headers=headers).status_code == 403
    assert client.get(f"{API}/channels").status_code == 401
    assert session.scalar(select(func.count()).select_from(NotificationChannel)) == 0


BAD = [
    ({"kind": "webhook", "name": "x", "url": "ftp://example.org/hook"}, "url"),
    ({"kind": "webhook", "name": "x", "url": "not a url"}, "url"),
    ({"kind": "webhook", "name": "", "url": "https://example.org/h"}, "name"),
    ({"kind": "webhook", "name": "x", "url": "https://example.org/h", "secret": "mine"},
     "secret"),
    ({"kind": "pager", "name": "x"}, "kind"),
    ({"kind": "email", "name": "x", "smtp_host": "mail.example.org", "smtp_port": 70000,
      "mail_from": "a@example.org", "mail_to": ["b@example.org"]}, "smtp_port"),
    ({"kind": "email", "name": "x", "smtp_host": "mail.example.org",
      "mail_from": "nobody", "mail_to": ["b@example.org"]}, "mail_from"),
    ({"kind": "email", "name": "x", "smtp_host": "mail.example.org",
      "mail_from": "a@example.org", "mail_to": []}, "mail_to"),
    ({"kind": "email", "name": "x", "smtp_host": "mail.example.org",
      "mail_from": "a@example.org", "mail_to": ["b@example.org"], "username": "u"},
     "password"),
    ({"kind": "email", "name": "x", "smtp_host": "bad host;rm",
      "mail_from": "a@example.org", "mail_to": ["b@example.org"]}, "smtp_host"),
]


def test_bad_settings_are_refused_clearly_and_store_nothing(
    client: TestClient, session: Session
) -> None:
    _operator_id, headers = _admin(session, "Strict Air")
    for body, field in BAD:
        response = client.post(f"{API}/channels", headers=headers, json=body)
        assert response.status_code == 422, (body, response.text)
        assert field in response.text, (field, response.text)
    assert session.scalar(select(func.count()).select_from(NotificationChannel)) == 0
    assert client.post(f"{API}/channels/999999/test", headers=headers).status_code == 404


def test_an_event_raised_by_the_estimation_job_is_sent_after_it_commits(
    session: Session, session_factory: sessionmaker[Session]
) -> None:
    fleet = _fleet_with_design(session)
    aircraft = add_aircraft(session, fleet, "F-NTF")
    engine = add_engine(session, fleet, "E-NOTIFY")
    times, y = _records(seed=11, fault="HPC", at=450)
    with webhook_receiver() as receiver:
        _row, secret = channels.create_webhook(
            session, operator_id=fleet.operator_id,
            spec=channels.WebhookSpec(name="ops", url=receiver.url))
        earliest = _store_rows(session, fleet, engine.id, aircraft.id, times, y, range(N))
        backlog.mark(session, fleet.operator_id, {engine.id: (earliest, N)})
        jobs_store.queue_estimation(session, operator_id=fleet.operator_id,
                                    job_registry=load_kinds())
        session.commit()
        ran = run_pending(session_factory)
    kinds = [session.get(Job, job_id, populate_existing=True).kind for job_id in ran]  # type: ignore[union-attr]
    assert kinds == ["estimate_engines", "send_notifications"]
    deliveries = session.scalars(select(NotificationDelivery)).all()
    assert deliveries and all(d.status == "sent" for d in deliveries)
    bodies = [json.loads(r.body) for r in receiver.requests]
    assert len(bodies) == len(deliveries)
    faults = [b["event"] for b in bodies if b["event"]["kind"] == "isolated_fault"]
    assert len(faults) == 1
    assert faults[0]["fault"] == "HPC" and faults[0]["severity"] == "red"
    assert faults[0]["esn"] == "E-NOTIFY"
    for request in receiver.requests:
        timestamp = request.headers["X-Fleethealth-Timestamp"]
        digest = hmac.new(secret.encode(), f"{timestamp}.".encode() + request.body,
                          hashlib.sha256).hexdigest()
        assert request.headers["X-Fleethealth-Signature"] == f"sha256={digest}"


def test_the_daily_diagnostics_job_sends_deliveries_left_pending(
    session: Session, session_factory: sessionmaker[Session]
) -> None:
    operator_id, _headers = _admin(session, "Leftover Air")
    with webhook_receiver() as receiver:
        row, _secret = channels.create_webhook(
            session, operator_id=operator_id,
            spec=channels.WebhookSpec(name="ops", url=receiver.url))
        outbox.queue_test(session, channel=row)  # as if its sending had never been queued
        jobs_store.submit(session, operator_id=operator_id, kind="fleet_diagnostics",
                          parameters={}, registry=load_kinds())
        session.commit()
        ran = run_pending(session_factory)
    kinds = [session.get(Job, job_id, populate_existing=True).kind for job_id in ran]  # type: ignore[union-attr]
    assert kinds == ["fleet_diagnostics", "send_notifications"]
    assert len(receiver.requests) == 1


def test_an_engine_whose_limits_turn_red_is_notified_once(
    session: Session, session_factory: sessionmaker[Session]
) -> None:
    fleet = _fleet_with_design(session)
    aircraft = add_aircraft(session, fleet, "F-RED")
    engine = add_engine(session, fleet, "E-RED")
    times, y = _records(seed=13)  # slow deterioration only: no shift event
    fleet.engine_type.limits = {"health_change": {"amber": 50.0, "red": 80.0}}

    def estimate() -> list[dict]:
        jobs_store.queue_estimation(session, operator_id=fleet.operator_id,
                                    job_registry=load_kinds())
        session.commit()
        run_pending(session_factory)
        return [json.loads(r.body) for r in receiver.requests
                if json.loads(r.body)["type"] == "engine.turned_red"]

    with webhook_receiver() as receiver:
        channels.create_webhook(session, operator_id=fleet.operator_id,
                                spec=channels.WebhookSpec(name="ops", url=receiver.url))
        earliest = _store_rows(session, fleet, engine.id, aircraft.id, times, y, range(N))
        backlog.mark(session, fleet.operator_id, {engine.id: (earliest, N)})
        assert estimate() == []  # within its limits: nothing
        # The type's health-change limits tightened below the engine's change: it turns red.
        fleet.engine_type.limits = {"health_change": {"amber": 1e-7, "red": 1e-6}}
        [turned] = estimate()
        assert turned["engine"]["esn"] == "E-RED" and turned["engine"]["severity"] == "red"
        assert [c["limit"] for c in turned["engine"]["checks"]] == ["health_change"]
        assert turned["engine"]["tail"] is None or turned["engine"]["tail"] == "F-RED"
        assert len(estimate()) == 1  # still red: not notified again


def test_channels_are_the_operators_own_and_can_be_disabled_and_deleted(
    client: TestClient, session: Session
) -> None:
    operator_id, headers = _admin(session, "Own Air")
    _other_id, other = _admin(session, "Other Air")
    created = client.post(f"{API}/channels", headers=headers,
                          json={"kind": "webhook", "name": "ops", "url": "https://example.org/h"})
    channel_id = created.json()["id"]
    assert client.get(f"{API}/channels", headers=other).json() == []
    assert client.patch(f"{API}/channels/{channel_id}", headers=other,
                        json={"enabled": False}).status_code == 404
    assert client.post(f"{API}/channels/{channel_id}/test", headers=other).status_code == 404
    assert client.delete(f"{API}/channels/{channel_id}", headers=other).status_code == 404
    assert outbox.has_channels(session, operator_id)
    patched = client.patch(f"{API}/channels/{channel_id}", headers=headers,
                           json={"enabled": False})
    assert patched.status_code == 200 and patched.json()["enabled"] is False
    assert not outbox.has_channels(session, operator_id)  # disabled: no deliveries queued
    assert client.delete(f"{API}/channels/{channel_id}", headers=headers).status_code == 200
    assert client.get(f"{API}/channels", headers=headers).json() == []
