"""A design's Monte Carlo evaluation: submitted as a job, read back as the latest evaluation;
its theory terms are the design's own analytic errors, its Monte Carlo part is reproduced by
the estimation core with the same seed, another operator's design is not found."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy.orm import Session, sessionmaker

from app.jobs.runner import run_pending
from estimation import evaluate as ev
from estimation.design import design_from_result
from tests.estimation.models import reference_model
from tests.support.fleetkit import Tenant, make_tenant, post

API = "/api/v1"
SPEC: dict[str, Any] = {
    "format": "fleethealth.design-spec/1",
    "method": "subset",
    "tuners": 4,
    "noise": {"Q": [0.01, 0.01], "Qh": [0.1] * 10, "Ph": [2.0] * 10},
}
PARAMS = {"n_cases": 8, "duration_s": 3.0, "window_s": 1.0, "fault_duration_s": 3.0, "seed": 5}


@pytest.fixture
def tenant(client: TestClient, session: Session) -> Tenant:
    tenant = make_tenant(session, "Evaluation Air")
    type_id = post(client, tenant, f"{API}/engine-types", {"name": "TF-2S"})["id"]
    body = {"engine_type_id": type_id, "name": "cruise", "model": reference_model().to_dict()}
    model_id = post(client, tenant, f"{API}/engine-models", body)["id"]
    design = post(
        client, tenant, f"{API}/designs", {"engine_model_id": model_id, "name": "d", "spec": SPEC}
    )
    tenant.ids["design"] = design["id"]
    return tenant


def test_evaluation_job_result_is_the_latest_evaluation(
    client: TestClient, session_factory: sessionmaker[Session], tenant: Tenant
) -> None:
    design_id = tenant.ids["design"]
    url = f"{API}/designs/{design_id}/evaluation"
    assert client.get(url, headers=tenant.headers("viewer")).json() is None
    job = client.post(
        f"{API}/jobs",
        json={"kind": "evaluate_design", "parameters": {"design_id": design_id, **PARAMS}},
        headers=tenant.headers(),
    )
    assert job.status_code == 202, job.text
    assert run_pending(session_factory) == [job.json()["id"]]
    evaluation = client.get(url, headers=tenant.headers("viewer")).json()
    assert evaluation["job_id"] == job.json()["id"]
    result = evaluation["result"]

    design = client.get(f"{API}/designs/{design_id}", headers=tenant.headers()).json()
    theory = design["analytic_errors"]["health"]
    mc = result["monte_carlo"]["health"]
    assert mc["names"] == theory["names"]
    np.testing.assert_allclose(mc["theory_bias2"], theory["bias2"], rtol=1e-9)
    np.testing.assert_allclose(mc["theory_variance"], theory["variance"], rtol=1e-9)

    # The same experiment run directly by the estimation core with the same seed; by default
    # each case starts in the stationary regime the theory describes.
    assert result["monte_carlo_settings"]["start"] == "steady"
    direct = ev.ssee_monte_carlo(
        design_from_result(design["result"]), PARAMS["n_cases"],
        rng=np.random.default_rng(PARAMS["seed"]), duration=PARAMS["duration_s"],
        window=PARAMS["window_s"], start="steady",
    )
    np.testing.assert_allclose(mc["squared_error"], direct.squared_error, rtol=1e-9)
    for confusion in result.get("confusion", {}).values():
        percent = np.asarray(confusion["percent"])
        np.testing.assert_allclose(percent.sum(axis=1), 100.0, rtol=1e-9)


def test_another_operators_design_evaluation_is_not_found(
    client: TestClient, session: Session, tenant: Tenant
) -> None:
    other = make_tenant(session, "Other Air")
    response = client.get(
        f"{API}/designs/{tenant.ids['design']}/evaluation", headers=other.headers("viewer")
    )
    assert response.status_code == 404
    assert set(response.json()) == {"error"}
