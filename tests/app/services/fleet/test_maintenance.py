"""Maintenance actions: recorded per engine, listed by time, they mark the baseline resets."""

from __future__ import annotations

from datetime import timedelta

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.models import MaintenanceAction
from app.services.fleet import maintenance
from tests.support.fleetkit import (
    T0,
    Tenant,
    error_of,
    make_tenant,
    post,
)

API = "/api/v1/maintenance-actions"
KINDS = ("water_wash", "module_change", "shop_visit")


@pytest.fixture
def tenant(client: TestClient, session: Session) -> Tenant:
    tenant = make_tenant(session, "Wash Air")
    et = post(client, tenant, "/api/v1/engine-types", {"name": "TF-2S"})
    for esn in ("E1", "E2"):
        body = {"esn": esn, "engine_type_id": et["id"]}
        tenant.ids[esn] = post(client, tenant, "/api/v1/engines", body)["id"]
    return tenant


def _stored(session: Session, tenant: Tenant) -> int:
    stmt = select(func.count()).where(MaintenanceAction.operator_id == tenant.operator_id)
    return int(session.scalar(stmt) or 0)


def test_actions_list_newest_first_and_filter(
    client: TestClient, session: Session, tenant: Tenant
) -> None:
    rng = np.random.default_rng(3)
    made = []
    for _ in range(12):
        body = {
            "engine_id": tenant.ids[str(rng.choice(["E1", "E2"]))],
            "kind": str(rng.choice(KINDS)),
            "performed_at": (T0 + timedelta(hours=int(rng.integers(0, 5000)))).isoformat(),
            "notes": "borescope ok",
        }
        made.append(post(client, tenant, API, body))

    viewer = tenant.headers("viewer")
    since, until = T0 + timedelta(hours=1000), T0 + timedelta(hours=4000)
    params = {
        "engine_id": tenant.ids["E1"],
        "since": since.isoformat(),
        "until": until.isoformat(),
        "limit": 1000,
    }
    got = client.get(API, params=params, headers=viewer).json()
    expected = sorted(
        (
            m
            for m in made
            if m["engine_id"] == tenant.ids["E1"]
            and since.isoformat() <= m["performed_at"].replace("Z", "+00:00") < until.isoformat()
        ),
        key=lambda m: (m["performed_at"], m["id"]),
        reverse=True,
    )
    assert got["items"] == expected and got["total"] == len(expected)
    washes = client.get(API, params={"kind": "water_wash"}, headers=viewer).json()
    assert washes["total"] == sum(m["kind"] == "water_wash" for m in made)

    resets = maintenance.baseline_resets(
        session, operator_id=tenant.operator_id, engine_id=tenant.ids["E2"]
    )
    e2_times = sorted(m["performed_at"] for m in made if m["engine_id"] == tenant.ids["E2"])
    assert [t.isoformat().replace("+00:00", "Z") for t in resets] == e2_times


def test_update_and_delete(client: TestClient, session: Session, tenant: Tenant) -> None:
    body = {"engine_id": tenant.ids["E1"], "kind": "water_wash", "performed_at": T0.isoformat()}
    action = post(client, tenant, API, body)
    assert action["notes"] == ""
    changed = client.patch(
        f"{API}/{action['id']}",
        json={"kind": "shop_visit", "notes": "HPC module replaced"},
        headers=tenant.headers(),
    ).json()
    assert changed == {**action, "kind": "shop_visit", "notes": "HPC module replaced"}
    assert client.delete(f"{API}/{action['id']}", headers=tenant.headers()).status_code == 200
    assert _stored(session, tenant) == 0


@pytest.mark.parametrize(
    ("change", "field"),
    [
        ({"kind": "oil_change"}, "kind"),
        ({"kind": None}, "kind"),
        ({"performed_at": "2026-03-01T10:00:00"}, "performed_at"),
        ({"performed_at": "2026-13-01T00:00:00Z"}, "performed_at"),
        ({"engine_id": "E1"}, "engine_id"),
        ({"engine_id": 10**9}, "engine_id"),
        ({"notes": ["a"]}, "notes"),
        ({"done_by": "me"}, "done_by"),
    ],
)
def test_bad_actions_name_the_field_and_store_nothing(
    client: TestClient, session: Session, tenant: Tenant, change: dict[str, object], field: str
) -> None:
    body: dict[str, object] = {
        "engine_id": tenant.ids["E1"],
        "kind": "water_wash",
        "performed_at": T0.isoformat(),
        **change,
    }
    response = client.post(API, json=body, headers=tenant.headers())
    assert response.status_code == 422
    assert error_of(response)["details"][0]["location"][-1] == field
    assert _stored(session, tenant) == 0


def test_missing_fields_are_named(client: TestClient, session: Session, tenant: Tenant) -> None:
    full = {"engine_id": tenant.ids["E1"], "kind": "water_wash", "performed_at": T0.isoformat()}
    for field in full:
        body = {k: v for k, v in full.items() if k != field}
        response = client.post(API, json=body, headers=tenant.headers())
        assert response.status_code == 422
        assert error_of(response)["details"][0]["location"] == ["body", field]
    assert _stored(session, tenant) == 0
