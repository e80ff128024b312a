"""Alert handling: assignment to a person (an analyst or admin key of the operator), a reason
to acknowledge or close, and the history of who did what. Bad input answers a clear 4xx and
stores nothing."""

from __future__ import annotations

from fastapi.testclient import TestClient
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.models import Operator
from app.models.base import utcnow
from app.models.estimates import Event, EventHistory
from app.services.tenancy.service import issue_api_key
from tests.app.services.events.test_events import _event
from tests.app.services.trends.test_trends import add_engine, make_fleet


def _history_rows(session: Session, event_id: int) -> int:
    session.expire_all()
    return session.scalar(
        select(func.count()).select_from(EventHistory).where(EventHistory.event_id == event_id)
    ) or 0


def test_assign_acknowledge_comment_close_is_kept_as_history(
    client: TestClient, session: Session
) -> None:
    fleet = make_fleet(session, "Alert Air")
    event = _event(session, fleet, add_engine(session, fleet, "AL1").id, 1)
    operator = session.get(Operator, fleet.operator_id)
    assert operator is not None
    maria, _ = issue_api_key(session, operator=operator, role="analyst", name="Maria Lopez")
    issue_api_key(session, operator=operator, role="viewer", name="Kiosk")
    session.commit()
    h = {"X-API-Key": fleet.key}
    url = f"/api/v1/events/{event.id}"

    people = client.get("/api/v1/events/assignees", headers=h).json()
    assert [p["name"] for p in people] == ["Maria Lopez", "test"]  # viewers cannot act

    assigned = client.post(f"{url}/assign", json={"assignee_key_id": maria.id}, headers=h)
    assert assigned.status_code == 200
    assert assigned.json()["assignee"] == {"key_id": maria.id, "name": "Maria Lopez",
                                           "role": "analyst"}
    again = client.post(f"{url}/assign", json={"assignee_key_id": maria.id}, headers=h).json()
    assert len(again["history"]) == 1  # the same assignment again adds nothing
    acked = client.post(f"{url}/ack", json={"reason": "  HPC signature, borescope booked  "},
                        headers=h).json()
    assert acked["status"] == "acknowledged"
    assert acked["acknowledged_reason"] == "HPC signature, borescope booked"
    client.post(f"{url}/comments", json={"body": "borescope: blade tip rub"}, headers=h)
    closed = client.post(f"{url}/close", json={"reason": "HPC washed, margin back"},
                         headers=h).json()
    assert closed["closed_reason"] == "HPC washed, margin back"
    assert closed["assignee"]["name"] == "Maria Lopez"

    history = closed["history"]
    assert [s["action"] for s in history] == ["assigned", "acknowledged", "commented", "closed"]
    assert {s["actor"] for s in history} == {"test"}
    assert history[0]["assignee"] == "Maria Lopez" and history[0]["assignee_key_id"] == maria.id
    assert [s["reason"] for s in history[1:]] == [
        "HPC signature, borescope booked", "borescope: blade tip rub", "HPC washed, margin back"]
    times = [s["created_at"] for s in history]
    assert times == sorted(times)
    listed = client.get("/api/v1/events", headers=h).json()["items"][0]
    assert listed["assignee"]["key_id"] == maria.id and len(listed["history"]) == 4
    # A closed alert is not assigned any more, and a repeat close stores nothing.
    assert client.post(f"{url}/assign", json={"assignee_key_id": None},
                       headers=h).status_code == 409
    client.post(f"{url}/close", json={"reason": "again"}, headers=h)
    assert _history_rows(session, event.id) == 4


def test_unassign_is_recorded(client: TestClient, session: Session) -> None:
    fleet = make_fleet(session, "Unassign Air")
    event = _event(session, fleet, add_engine(session, fleet, "UN1").id, 1)
    session.commit()
    h = {"X-API-Key": fleet.key}
    me = client.get("/api/v1/events/assignees", headers=h).json()[0]["key_id"]
    client.post(f"/api/v1/events/{event.id}/assign", json={"assignee_key_id": me}, headers=h)
    out = client.post(f"/api/v1/events/{event.id}/assign", json={"assignee_key_id": None},
                      headers=h).json()
    assert out["assignee"] is None
    assert [(s["action"], s["assignee"]) for s in out["history"]] == [
        ("assigned", "test"), ("unassigned", None)]


def test_bad_input_is_refused_and_stores_nothing(client: TestClient, session: Session) -> None:
    fleet, other = make_fleet(session, "Strict Air"), make_fleet(session, "Other Air")
    event = _event(session, fleet, add_engine(session, fleet, "ST1").id, 1)
    foreign = _event(session, other, add_engine(session, other, "OT1").id, 1)
    operator = session.get(Operator, fleet.operator_id)
    other_operator = session.get(Operator, other.operator_id)
    assert operator is not None and other_operator is not None
    viewer, _ = issue_api_key(session, operator=operator, role="viewer", name="Kiosk")
    revoked, _ = issue_api_key(session, operator=operator, role="analyst", name="Gone")
    revoked.revoked_at = utcnow()
    outsider, _ = issue_api_key(session, operator=other_operator, role="admin", name="Outsider")
    session.commit()
    h = {"X-API-Key": fleet.key}
    url = f"/api/v1/events/{event.id}"

    for key_id in (viewer.id, revoked.id, outsider.id, 999_999):
        bad = client.post(f"{url}/assign", json={"assignee_key_id": key_id}, headers=h)
        assert bad.status_code == 422, key_id
        assert "unknown assignee" in bad.json()["error"]["message"]
    for body in ({"reason": ""}, {"reason": "   "}, {}, {"comment": "old field"}):
        for action in ("ack", "close"):
            bad = client.post(f"{url}/{action}", json=body, headers=h)
            assert bad.status_code == 422, (action, body)
    assert client.post(f"{url}/ack", headers=h).status_code == 422  # no body at all
    for action, body in (("assign", {"assignee_key_id": None}), ("ack", {"reason": "r"}),
                         ("close", {"reason": "r"})):
        missing = client.post(f"/api/v1/events/{foreign.id}/{action}", json=body, headers=h)
        assert missing.status_code == 404 and "not found" in missing.json()["error"]["message"]

    session.expire_all()
    stored = session.get(Event, event.id)
    theirs = session.get(Event, foreign.id)
    assert stored is not None and theirs is not None
    assert (stored.status, stored.assignee_key_id, stored.acknowledged_at) == ("open", None, None)
    assert theirs.status == "open"
    assert _history_rows(session, event.id) == 0 and _history_rows(session, foreign.id) == 0
