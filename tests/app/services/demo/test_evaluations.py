"""The demo's designs get their Monte Carlo evaluation queued once, and only theirs."""

from __future__ import annotations

from typing import Any

from fastapi.testclient import TestClient
from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from app.jobs.demo import queue_demo_evaluations
from app.jobs.runner import run_pending
from app.models import Job
from app.services.demo.operator import DEMO_OPERATOR
from app.services.tenancy import service as tenancy
from tests.estimation.models import reference_model
from tests.support.fleetkit import Tenant, make_tenant, post

API = "/api/v1"
SPEC: dict[str, Any] = {
    "format": "fleethealth.design-spec/1",
    "method": "subset",
    "tuners": 4,
    "noise": {"Q": [0.01, 0.01], "Qh": [0.1] * 10, "Ph": [2.0] * 10},
}


def _design(client: TestClient, tenant: Tenant) -> int:
    type_id = post(client, tenant, f"{API}/engine-types", {"name": "TF-2S"})["id"]
    body = {"engine_type_id": type_id, "name": "cruise", "model": reference_model().to_dict()}
    model_id = post(client, tenant, f"{API}/engine-models", body)["id"]
    body = {"engine_model_id": model_id, "name": "d", "spec": SPEC}
    return int(post(client, tenant, f"{API}/designs", body)["id"])


def test_each_ready_demo_design_is_evaluated_once(
    client: TestClient, session: Session, session_factory: sessionmaker[Session]
) -> None:
    operator = tenancy.create_operator(session, name=DEMO_OPERATOR)
    keys = {
        role: tenancy.issue_api_key(session, operator=operator, role=role, name=role)[1]
        for role in ("viewer", "analyst", "admin")
    }
    session.commit()
    demo = Tenant(operator.id, keys)
    design_id = _design(client, demo)
    other = make_tenant(session, "Elsewhere Air")
    _design(client, other)

    first = queue_demo_evaluations(session)
    session.commit()
    assert len(first) == 1
    job = session.get(Job, first[0])
    assert job is not None and job.operator_id == operator.id
    assert job.parameters["design_id"] == design_id
    assert queue_demo_evaluations(session) == first  # still queued: the same job

    assert run_pending(session_factory) == first
    session.expire_all()
    assert session.scalar(select(Job.status).where(Job.id == first[0])) == "succeeded"
    assert queue_demo_evaluations(session) == []  # evaluated: nothing more
    evaluation = client.get(
        f"{API}/designs/{design_id}/evaluation", headers=demo.headers("viewer")
    ).json()
    assert evaluation["job_id"] == first[0]


def test_no_demo_operator_no_jobs(session: Session) -> None:
    assert queue_demo_evaluations(session) == []
