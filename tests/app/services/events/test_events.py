"""Events API: list and filter, acknowledge (idempotent), comment, close; another operator's
event is not found and a viewer cannot act."""

from __future__ import annotations

from datetime import timedelta

from fastapi.testclient import TestClient
from sqlalchemy.orm import Session

from app.models import ApiKey, Operator
from app.models.estimates import Event
from app.services.tenancy.service import issue_api_key
from tests.app.services.trends.test_trends import T0, Fleet, add_engine, make_fleet


def _event(session: Session, fleet: Fleet, engine_id: int, seq: int, **kw: object) -> Event:
    fields = dict(
        operator_id=fleet.operator_id, engine_id=engine_id, design_id=fleet.design.id, seq=seq,
        detected_at=T0 + timedelta(days=seq), kind="isolated_fault", fault="HPC",
        magnitude=1.1, statistic=42.0, wssr={"HPC": 1.5, "Fan": 30.0},
        shift={"tuners": {"q1": -1.0}, "health": {"hpc_eff": -2.2}, "fault": {"hpc_eff": -2.2},
               "wssr_threshold": 20.5, "wssr_dof": 4, "wssr_scale": 1.0},
    )
    fields.update(kw)
    event = Event(**fields)
    session.add(event)
    session.flush()
    return event


def test_list_filter_acknowledge_comment_close(client: TestClient, session: Session) -> None:
    fleet = make_fleet(session, "Event Air")
    engine = add_engine(session, fleet, "EV1")
    first = _event(session, fleet, engine.id, 1)
    second = _event(session, fleet, engine.id, 2, kind="shift", fault=None, magnitude=None)
    session.commit()
    h = {"X-API-Key": fleet.key}

    page = client.get("/api/v1/events", headers=h).json()
    assert [e["id"] for e in page["items"]] == [second.id, first.id]  # newest first
    assert page["total"] == 2
    only = client.get("/api/v1/events", params={"kind": "isolated_fault"}, headers=h).json()
    assert [e["id"] for e in only["items"]] == [first.id]
    shown = client.get(f"/api/v1/events/{first.id}", headers=h).json()
    assert shown["wssr"] == {"HPC": 1.5, "Fan": 30.0} and shown["fault_shift"] == {"hpc_eff": -2.2}
    assert min(shown["wssr"], key=shown["wssr"].get) == shown["fault"]

    acked = client.post(f"/api/v1/events/{first.id}/ack", json={"reason": "borescope"},
                        headers=h)
    assert acked.status_code == 200 and acked.json()["status"] == "acknowledged"
    again = client.post(f"/api/v1/events/{first.id}/ack", json={"reason": "again"},
                        headers=h).json()
    assert again["acknowledged_at"] == acked.json()["acknowledged_at"]  # a repeat is a no-op
    commented = client.post(f"/api/v1/events/{first.id}/comments", json={"body": "HPC wash"},
                            headers=h)
    assert commented.status_code == 201
    assert [c["body"] for c in commented.json()["comments"]] == ["HPC wash"]
    assert commented.json()["acknowledged_reason"] == "borescope"
    closed = client.post(f"/api/v1/events/{first.id}/close", json={"reason": "washed"},
                         headers=h).json()
    assert closed["status"] == "closed" and closed["closed_at"] is not None
    assert closed["closed_reason"] == "washed"
    assert client.post(f"/api/v1/events/{first.id}/ack", json={"reason": "x"},
                       headers=h).status_code == 409
    open_now = client.get("/api/v1/events", params={"status": "open"}, headers=h).json()
    assert [e["id"] for e in open_now["items"]] == [second.id]


def test_tenancy_and_roles(client: TestClient, session: Session) -> None:
    mine, theirs = make_fleet(session, "Mine"), make_fleet(session, "Theirs")
    event = _event(session, theirs, add_engine(session, theirs, "T1").id, 1)
    operator = session.get(Operator, theirs.operator_id)
    assert operator is not None
    _row, viewer = issue_api_key(session, operator=operator, role="viewer", name="viewer")
    session.commit()
    assert client.get(f"/api/v1/events/{event.id}", headers={"X-API-Key": mine.key}
                      ).status_code == 404
    for action, body in (("ack", {"reason": "r"}), ("close", {"reason": "r"}),
                         ("assign", {"assignee_key_id": None})):
        assert client.post(f"/api/v1/events/{event.id}/{action}", json=body,
                           headers={"X-API-Key": mine.key}).status_code == 404
    assert client.get("/api/v1/events", headers={"X-API-Key": mine.key}).json()["total"] == 0
    v = {"X-API-Key": viewer}
    assert client.get(f"/api/v1/events/{event.id}", headers=v).status_code == 200
    assert client.post(f"/api/v1/events/{event.id}/ack", json={"reason": "r"},
                       headers=v).status_code == 403
    assert client.post(f"/api/v1/events/{event.id}/comments", json={"body": "x"},
                       headers=v).status_code == 403
    assert session.query(ApiKey).filter_by(operator_id=theirs.operator_id).count() == 2


def test_fleet_and_events_pages_count_the_same_events_after_ack_and_close(
    client: TestClient, session: Session
) -> None:
    """The fleet page's active-event count (total and per engine) is what the events page lists
    by default (status=active), before and after an acknowledgement and a close."""
    fleet = make_fleet(session, "Count Air")
    one, two = add_engine(session, fleet, "C1"), add_engine(session, fleet, "C2")
    a = _event(session, fleet, one.id, 1)
    _event(session, fleet, one.id, 2, kind="shift", fault=None, magnitude=None)
    c = _event(session, fleet, two.id, 3)
    session.commit()
    h = {"X-API-Key": fleet.key}

    def counts() -> tuple[int, dict[str, int], int, dict[str, int]]:
        status = client.get("/api/v1/fleet/status", headers=h).json()
        per_engine = {e["esn"]: e["open_events"] for e in status["engines"] if e["open_events"]}
        listed = client.get("/api/v1/events", params={"status": "active"}, headers=h).json()
        by_esn: dict[str, int] = {}
        for e in listed["items"]:
            by_esn[e["esn"]] = by_esn.get(e["esn"], 0) + 1
        return status["n_open_events"], per_engine, listed["total"], by_esn

    def act(event_id: int, action: str) -> int:
        return client.post(f"/api/v1/events/{event_id}/{action}", json={"reason": "r"},
                           headers=h).status_code

    assert counts() == (3, {"C1": 2, "C2": 1}, 3, {"C1": 2, "C2": 1})
    assert act(a.id, "ack") == 200
    assert counts() == (3, {"C1": 2, "C2": 1}, 3, {"C1": 2, "C2": 1})
    assert act(c.id, "close") == 200
    assert counts() == (2, {"C1": 2}, 2, {"C1": 2})
    assert act(a.id, "close") == 200
    assert counts() == (1, {"C1": 1}, 1, {"C1": 1})
    # The plain statuses still filter exactly.
    acked = client.get("/api/v1/events", params={"status": "acknowledged"}, headers=h).json()
    assert acked["total"] == 0
    bad = client.get("/api/v1/events", params={"status": "pending"}, headers=h)
    assert bad.status_code == 422
