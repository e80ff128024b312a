"""A job or schedule naming another operator's design is refused at submission (404), and
nothing is stored; the operator's own design is accepted."""

from __future__ import annotations

from fastapi.testclient import TestClient
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.models import Job, JobSchedule
from tests.app.services.trends.test_trends import make_fleet


def stored(session: Session, model: type, operator_id: int) -> int:
    return int(
        session.scalar(
            select(func.count()).select_from(model).where(model.operator_id == operator_id)
        ) or 0
    )


def test_jobs_and_schedules_refuse_another_operators_design(
    client: TestClient, session: Session
) -> None:
    mine = make_fleet(session, "Mine Air")
    theirs = make_fleet(session, "Their Air")
    session.commit()
    headers = {"X-API-Key": mine.key}
    job = {"kind": "evaluate_design", "parameters": {"n_cases": 2}}
    schedule = {**job, "interval_seconds": 3600}
    for design_id in (theirs.design.id, 2**31 - 1):
        job["parameters"]["design_id"] = design_id
        refused = client.post("/api/v1/jobs", json=job, headers=headers)
        assert refused.status_code == 404, refused.text
        assert refused.json()["error"]["details"][0]["column"] == "parameters.design_id"
        refused = client.post("/api/v1/schedules", json=schedule, headers=headers)
        assert refused.status_code == 404, refused.text
    assert stored(session, Job, mine.operator_id) == 0
    assert stored(session, JobSchedule, mine.operator_id) == 0

    job["parameters"]["design_id"] = mine.design.id
    accepted = client.post("/api/v1/jobs", json=job, headers=headers)
    assert accepted.status_code == 202, accepted.text
    created = client.post("/api/v1/schedules", json=schedule, headers=headers)
    assert created.status_code == 201, created.text
    # Changing a schedule's parameters to a foreign design is refused the same way.
    url = f"/api/v1/schedules/{created.json()['id']}"
    foreign = {"parameters": {"design_id": theirs.design.id, "n_cases": 2}}
    assert client.patch(url, json=foreign, headers=headers).status_code == 404
    assert client.get(url, headers=headers).json()["parameters"]["design_id"] == mine.design.id
