"""Estimator designs: made by the estimation core's design step, stored with analytic errors,
one active per engine type."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import func, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from app.models import EngineModel, EstimatorDesign, Job
from app.services.designs import service as designs
from estimation import tuners
from tests.estimation.models import reference_model
from tests.support.fleetkit import (
    Tenant,
    error_of,
    make_tenant,
    post,
)

API = "/api/v1"
SPEC: dict[str, Any] = {
    "format": "fleethealth.design-spec/1",
    "method": "subset",
    "tuners": 4,
    "noise": {"Q": [0.01, 0.01], "Qh": [0.1] * 10, "Ph": [2.0] * 10},
}


@pytest.fixture
def tenant(client: TestClient, session: Session) -> Tenant:
    tenant = make_tenant(session, "Design Air")
    tenant.ids["type"] = post(client, tenant, f"{API}/engine-types", {"name": "TF-2S"})["id"]
    body = {
        "engine_type_id": tenant.ids["type"],
        "name": "cruise",
        "model": reference_model().to_dict(),
    }
    tenant.ids["model"] = post(client, tenant, f"{API}/engine-models", body)["id"]
    return tenant


def _design(client: TestClient, tenant: Tenant, spec: Any = SPEC, name: str = "d") -> Any:
    body = {"engine_model_id": tenant.ids["model"], "name": name, "spec": spec}
    return client.post(f"{API}/designs", json=body, headers=tenant.headers())


def _designs(session: Session, tenant: Tenant) -> int:
    stmt = select(func.count()).where(EstimatorDesign.operator_id == tenant.operator_id)
    return int(session.scalar(stmt) or 0)


def test_design_is_stored_with_the_analytic_errors_of_a_direct_design(
    client: TestClient, session: Session, tenant: Tenant
) -> None:
    response = _design(client, tenant)
    assert response.status_code == 201
    out = response.json()
    assert out["status"] == "ready" and out["result"]["format"] == "fleethealth.design/1"

    # The same design made directly by the tuner module (Q, Qh, Ph as standard deviations).
    direct = tuners.subset_tuners(
        reference_model(), 4, np.eye(2) * 1e-4, np.eye(10) * 0.01, np.eye(10) * 4.0
    )
    assert out["ssee_health"] == pytest.approx(direct.theory.ssee_health, rel=1e-9)
    assert out["ssee_aux"] == pytest.approx(direct.theory.ssee_aux, rel=1e-9)
    health = out["analytic_errors"]["health"]
    np.testing.assert_allclose(health["bias2"], direct.theory.health_bias2, rtol=1e-9)
    np.testing.assert_allclose(health["variance"], direct.theory.health_variance, rtol=1e-9)

    listed = client.get(f"{API}/designs", headers=tenant.headers("viewer")).json()
    assert [d["id"] for d in listed["items"]] == [out["id"]] and "result" not in listed["items"][0]
    model = session.get(EngineModel, tenant.ids["model"])
    assert model is not None and model.locked_at is not None


@pytest.mark.parametrize(
    ("spec", "named"),
    [
        ({**SPEC, "tuners": 11}, "tuners"),
        ({**SPEC, "method": "magic"}, "method"),
        ({**SPEC, "format": "x"}, "format"),
        ({k: v for k, v in SPEC.items() if k != "noise"}, "noise"),
        ({**SPEC, "noise": {**SPEC["noise"], "Ph": [2.0] * 3}}, "Ph"),
        ({**SPEC, "sensors": ["Nf", "EGT"]}, "EGT"),
        ({**SPEC, "tuners": 8}, "sensors"),  # more tuners than the six sensors can estimate
        ({**SPEC, "stream_filter": "ekf"}, "stream_filter"),
    ],
)
def test_bad_specs_are_422_naming_the_problem_and_store_nothing(
    client: TestClient, session: Session, tenant: Tenant, spec: dict[str, Any], named: str
) -> None:
    response = _design(client, tenant, spec)
    assert response.status_code == 422
    error = error_of(response)
    assert named in error["message"] and error["details"][0]["location"] == ["body", "spec"]
    session.expire_all()
    assert _designs(session, tenant) == 0
    model = session.get(EngineModel, tenant.ids["model"])
    assert model is not None and model.locked_at is None  # the failed design left no lock


def test_the_design_result_records_the_stream_filter_chosen(
    client: TestClient, tenant: Tenant
) -> None:
    default = _design(client, tenant, name="default").json()
    chosen = _design(client, tenant, {**SPEC, "stream_filter": "cgekf"}, name="cgekf").json()
    assert default["result"]["stream_filter"] == "scheduled_linear"
    assert chosen["result"]["stream_filter"] == "cgekf"


def test_missing_fields_and_unknown_model(client: TestClient, tenant: Tenant) -> None:
    for body, field in (
        ({"name": "d", "spec": SPEC}, "engine_model_id"),
        ({"engine_model_id": tenant.ids["model"], "spec": SPEC}, "name"),
        ({"engine_model_id": tenant.ids["model"], "name": "d"}, "spec"),
        ({"engine_model_id": tenant.ids["model"], "name": "d", "spec": "optimal"}, "spec"),
        ({"engine_model_id": 10**9, "name": "d", "spec": SPEC}, "engine_model_id"),
    ):
        response = client.post(f"{API}/designs", json=body, headers=tenant.headers())
        assert response.status_code == 422
        assert error_of(response)["details"][0]["location"] == ["body", field]


def test_one_active_design_per_engine_type(
    client: TestClient, session: Session, tenant: Tenant
) -> None:
    first = _design(client, tenant, name="first").json()
    second = _design(client, tenant, {**SPEC, "method": "svd"}, name="second").json()
    url = f"{API}/engine-types/{tenant.ids['type']}/active-design"
    assert client.get(url, headers=tenant.headers("viewer")).json() is None

    for design in (first, second, second):
        response = client.post(f"{API}/designs/{design['id']}/activate", headers=tenant.headers())
        assert response.status_code == 200 and response.json()["active"]
        active = client.get(
            f"{API}/designs", params={"active": True}, headers=tenant.headers("viewer")
        ).json()
        assert [d["id"] for d in active["items"]] == [design["id"]]
        assert client.get(url, headers=tenant.headers()).json()["id"] == design["id"]

    off = client.post(f"{API}/designs/{second['id']}/deactivate", headers=tenant.headers())
    assert off.json()["active"] is False
    assert client.get(url, headers=tenant.headers()).json() is None
    # Each activation queued the estimation of the type's engines under it (one job: the later
    # activations found it queued).
    queued = session.scalars(
        select(Job.status).where(Job.operator_id == tenant.operator_id,
                                 Job.kind == "estimate_engines")
    ).all()
    assert queued == ["queued"]


def test_only_a_ready_design_can_be_active(
    client: TestClient, session: Session, tenant: Tenant
) -> None:
    pending = designs.create_design(
        session,
        operator_id=tenant.operator_id,
        engine_model_id=tenant.ids["model"],
        name="p",
        spec=SPEC,
    )
    session.commit()
    response = client.post(f"{API}/designs/{pending.id}/activate", headers=tenant.headers())
    assert response.status_code == 409 and "pending" in error_of(response)["message"]
    assert session.scalar(
        select(func.count()).select_from(Job).where(Job.operator_id == tenant.operator_id)
    ) == 0  # a refused activation queues nothing


def test_database_allows_one_active_design_per_engine_type(
    client: TestClient, session: Session, tenant: Tenant
) -> None:
    ids = [_design(client, tenant, name=n).json()["id"] for n in ("a", "b")]
    session.expire_all()
    rows = [session.get(EstimatorDesign, i) for i in ids]
    rows[0].active = True  # type: ignore[union-attr]
    session.flush()
    with pytest.raises(IntegrityError), session.begin_nested():
        rows[1].active = True  # type: ignore[union-attr]
        session.flush()


def test_background_design_is_made_by_a_job(
    client: TestClient, session: Session, session_factory: Any, tenant: Tenant
) -> None:
    from app.jobs.runner import run_pending

    body = {"engine_model_id": tenant.ids["model"], "name": "bg", "spec": SPEC}
    queued = client.post(
        f"{API}/designs", params={"background": True}, json=body, headers=tenant.headers()
    )
    assert queued.status_code == 202
    pending = queued.json()
    assert pending["status"] == "pending" and pending["result"] is None and pending["job_id"]
    assert pending["job_id"] in run_pending(session_factory)

    done = client.get(f"{API}/designs/{pending['id']}", headers=tenant.headers()).json()
    direct = _design(client, tenant, name="now").json()  # the same spec, made in the request
    assert done["status"] == "ready"
    assert done["ssee_health"] == pytest.approx(direct["ssee_health"], rel=1e-12)
    job = client.get(f"/api/v1/jobs/{pending['job_id']}", headers=tenant.headers()).json()
    assert job["status"] == "succeeded" and job["result"]["status"] == "ready"

    # A spec that parses but cannot be designed (8 tuners from 6 sensors) fails the design.
    body = {"engine_model_id": tenant.ids["model"], "name": "bad", "spec": {**SPEC, "tuners": 8}}
    queued = client.post(
        f"{API}/designs", params={"background": True}, json=body, headers=tenant.headers()
    ).json()
    run_pending(session_factory)
    failed = client.get(f"{API}/designs/{queued['id']}", headers=tenant.headers()).json()
    assert failed["status"] == "failed" and "sensors" in failed["failure"]


def test_background_design_checks_the_spec_first(
    client: TestClient, session: Session, tenant: Tenant
) -> None:
    body = {"engine_model_id": tenant.ids["model"], "name": "bg", "spec": {**SPEC, "tuners": 11}}
    response = client.post(
        f"{API}/designs", params={"background": True}, json=body, headers=tenant.headers()
    )
    assert response.status_code == 422 and "tuners" in error_of(response)["message"]
    assert _designs(session, tenant) == 0
