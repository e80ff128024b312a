"""Engine model import: validated by the estimation core, versioned, immutable once used."""

from __future__ import annotations

import copy
import json
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.models import EngineModel
from app.services.designs import engine_models
from app.services.designs import service as designs
from estimation.model import LinearModel
from tests.estimation.models import random_model, reference_model
from tests.support.fleetkit import (
    Tenant,
    error_of,
    make_tenant,
    post,
)

API = "/api/v1/engine-models"


@pytest.fixture
def tenant(client: TestClient, session: Session) -> Tenant:
    tenant = make_tenant(session, "Model Air")
    tenant.ids["type"] = post(client, tenant, "/api/v1/engine-types", {"name": "TF-2S"})["id"]
    return tenant


def _import(client: TestClient, tenant: Tenant, model: Any, name: str = "cruise") -> Any:
    body = {"engine_type_id": tenant.ids["type"], "name": name, "model": model}
    return client.post(API, json=body, headers=tenant.headers())


def _stored(session: Session, tenant: Tenant) -> int:
    stmt = select(func.count()).where(EngineModel.operator_id == tenant.operator_id)
    return int(session.scalar(stmt) or 0)


def test_import_stores_the_model_the_core_reads_back(
    client: TestClient, session: Session, tenant: Tenant
) -> None:
    model = reference_model()
    response = _import(client, tenant, model.to_dict())
    assert response.status_code == 201
    out = response.json()
    assert (out["version"], out["source"], out["locked_at"]) == (1, "imported", None)
    assert out["sensor_names"] == model.sensor_names and out["health_names"] == model.health_names
    assert out["checksum"] == engine_models.checksum(model.to_dict())

    content = client.get(f"{API}/{out['id']}/content", headers=tenant.headers("viewer")).json()
    back = LinearModel.from_dict(content["model"])
    for name in ("A", "B", "C", "L", "M", "F", "N"):
        np.testing.assert_array_equal(getattr(back, name), getattr(model, name))
    np.testing.assert_array_equal(back.sensor_noise_std, model.sensor_noise_std)
    assert back.trim == model.trim


def test_versions_count_up_and_identical_content_stores_nothing(
    client: TestClient, session: Session, tenant: Tenant
) -> None:
    first = _import(client, tenant, reference_model().to_dict()).json()
    again = _import(client, tenant, json.loads(json.dumps(reference_model().to_dict())))
    assert again.status_code == 200 and again.json()["id"] == first["id"]
    changed = reference_model().to_dict()
    changed["sensor_noise_std"] = [2 * s for s in changed["sensor_noise_std"]]
    second = _import(client, tenant, changed).json()
    other_name = _import(client, tenant, changed, name="takeoff").json()
    assert (second["version"], other_name["version"]) == (2, 1)
    assert _stored(session, tenant) == 3
    listed = client.get(API, params={"name": "cruise"}, headers=tenant.headers("viewer")).json()
    assert [m["version"] for m in listed["items"]] == [2, 1]


def _without(d: dict[str, Any], key: str) -> dict[str, Any]:
    out = copy.deepcopy(d)
    del out[key]
    return out


def _with(d: dict[str, Any], path: tuple[str, ...], value: Any) -> dict[str, Any]:
    out = copy.deepcopy(d)
    target = out
    for part in path[:-1]:
        target = target[part]
    target[path[-1]] = value
    return out


GOOD = reference_model().to_dict()
BAD_MODELS = [
    ("not an object", [1, 2, 3], "model"),
    ("wrong format", _with(GOOD, ("format",), "other/1"), "format"),
    ("missing key", _without(GOOD, "matrices"), "matrices"),
    ("missing matrix", _with(GOOD, ("matrices",), _without(GOOD["matrices"], "A")), "matrices.A"),
    ("wrong shape", _with(GOOD, ("matrices", "C"), np.zeros((6, 3)).tolist()), "C matrix"),
    ("wrong shape L", _with(GOOD, ("matrices", "L"), np.zeros((2, 9)).tolist()), "L matrix"),
    ("ragged", _with(GOOD, ("matrices", "A"), [[1.0, 0.0], [0.0]]), "A matrix"),
    ("text in matrix", _with(GOOD, ("matrices", "A"), [["a", 0], [0, 1]]), "A matrix"),
    ("noise length", _with(GOOD, ("sensor_noise_std",), [1.0]), "sensor_noise_std"),
    ("negative noise", _with(GOOD, ("sensor_noise_std",), [-1.0] * 6), "sensor_noise_std"),
    ("bad dt", _with(GOOD, ("dt",), "fast"), "dt"),
    ("unknown trim", _with(GOOD, ("trim",), {"T99": 1.0}), "T99"),
    ("no sensors", _with(GOOD, ("signals", "sensors"), []), "sensor"),
]


@pytest.mark.parametrize(("case", "model", "named"), BAD_MODELS, ids=[c[0] for c in BAD_MODELS])
def test_malformed_models_are_422_naming_the_problem_and_store_nothing(
    client: TestClient, session: Session, tenant: Tenant, case: str, model: Any, named: str
) -> None:
    response = _import(client, tenant, model)
    assert response.status_code == 422, case
    error = error_of(response)
    assert named in error["message"], error
    assert error["details"][0]["location"][-1] == "model"
    assert _stored(session, tenant) == 0


def test_nan_in_a_matrix_is_refused(client: TestClient, session: Session, tenant: Tenant) -> None:
    text = json.dumps({"engine_type_id": tenant.ids["type"], "name": "x", "model": GOOD})
    text = text.replace(json.dumps(GOOD["matrices"]["A"][0][0]), "NaN", 1)
    response = client.post(
        API, content=text, headers={**tenant.headers(), "content-type": "application/json"}
    )
    assert response.status_code == 422
    assert _stored(session, tenant) == 0


def test_unknown_engine_type_and_missing_fields(
    client: TestClient, session: Session, tenant: Tenant
) -> None:
    body = {"engine_type_id": 10**9, "name": "x", "model": GOOD}
    response = client.post(API, json=body, headers=tenant.headers())
    assert response.status_code == 422
    assert error_of(response)["details"][0]["location"] == ["body", "engine_type_id"]
    for missing in ("engine_type_id", "name", "model"):
        body = {"engine_type_id": tenant.ids["type"], "name": "x", "model": GOOD}
        del body[missing]
        response = client.post(API, json=body, headers=tenant.headers())
        detail = error_of(response)["details"][0]
        if missing == "model":  # a model file or several (a schedule): the body names both
            assert detail["location"] == ["body"]
            assert "either model (one file) or models (several files)" in detail["reason"]
        else:
            assert detail["location"] == ["body", missing]
    assert _stored(session, tenant) == 0


def test_a_model_used_by_a_design_cannot_be_deleted(
    client: TestClient, session: Session, tenant: Tenant
) -> None:
    unused = _import(client, tenant, random_model(np.random.default_rng(1)).to_dict()).json()
    used = _import(client, tenant, GOOD, name="used").json()
    designs.create_design(
        session, operator_id=tenant.operator_id, engine_model_id=used["id"], name="d", spec={}
    )
    session.commit()
    response = client.delete(f"{API}/{used['id']}", headers=tenant.headers())
    assert response.status_code == 409
    assert client.get(f"{API}/{used['id']}", headers=tenant.headers()).json()["locked_at"]
    assert client.delete(f"{API}/{unused['id']}", headers=tenant.headers()).status_code == 200
    assert client.get(f"{API}/{unused['id']}", headers=tenant.headers()).status_code == 404
    # No route changes a stored model: it is immutable.
    methods = {
        m
        for route in client.app.routes  # type: ignore[attr-defined]
        if getattr(route, "path", "").startswith(API)
        for m in getattr(route, "methods", ())
    }
    assert methods <= {"GET", "POST", "DELETE"}


def test_builtin_model_is_the_core_linearisation_at_the_condition(
    client: TestClient, session: Session, tenant: Tenant
) -> None:
    from estimation.engine.linearize import linearize

    body = {
        "engine_type_id": tenant.ids["type"],
        "name": "builtin takeoff",
        "alt_ft": 0.0,
        "mach": 0.0,
        "power_pct": 100.0,
    }
    response = client.post(f"{API}/builtin", json=body, headers=tenant.headers())
    assert response.status_code == 201
    out = response.json()
    assert out["source"] == "builtin"
    stored = client.get(f"{API}/{out['id']}/content", headers=tenant.headers()).json()["model"]
    direct = linearize(0.0, 0.0, 100.0)
    np.testing.assert_allclose(stored["matrices"]["A"], direct.A, rtol=1e-12)
    np.testing.assert_allclose(stored["matrices"]["M"], direct.M, rtol=1e-12)
    assert out["sensor_names"] == direct.sensor_names
    again = client.post(f"{API}/builtin", json=body, headers=tenant.headers())
    assert again.status_code == 200 and again.json()["id"] == out["id"]

    for change, field in (({"mach": 1.5}, "mach"), ({"power_pct": "full"}, "power_pct")):
        bad = client.post(f"{API}/builtin", json={**body, **change}, headers=tenant.headers())
        assert bad.status_code == 422
        assert error_of(bad)["details"][0]["location"][-1] == field
    assert _stored(session, tenant) == 1
