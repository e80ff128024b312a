"""API key management by an operator's admin: list, create (shown once), revoke."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.models import ApiKey
from app.services.tenancy.service import digest
from tests.support.fleetkit import (
    Tenant,
    error_of,
    make_tenant,
)

API = "/api/v1/keys"


@pytest.fixture
def tenant(session: Session) -> Tenant:
    return make_tenant(session, "Key Air")


def test_created_key_is_shown_once_and_works_with_its_role(
    client: TestClient, session: Session, tenant: Tenant
) -> None:
    admin = tenant.headers("admin")
    for role in ("viewer", "analyst", "admin"):
        response = client.post(API, json={"name": f"{role} bot", "role": role}, headers=admin)
        assert response.status_code == 201
        created = response.json()
        stored = session.scalar(select(ApiKey).where(ApiKey.id == created["id"]))
        assert stored is not None and stored.digest == digest(created["key"])
        assert created["key"] not in stored.digest
        me = client.get("/api/v1/me", headers={"X-API-Key": created["key"]}).json()
        assert (me["operator_id"], me["role"]) == (tenant.operator_id, role)

    listed = client.get(API, headers=admin).json()
    stored_ids = session.scalars(
        select(ApiKey.id).where(ApiKey.operator_id == tenant.operator_id).order_by(ApiKey.id)
    ).all()
    assert [k["id"] for k in listed["items"]] == list(stored_ids)
    assert all("key" not in k for k in listed["items"])


def test_revoked_key_is_refused(client: TestClient, session: Session, tenant: Tenant) -> None:
    admin = tenant.headers("admin")
    created = client.post(API, json={"name": "temp", "role": "analyst"}, headers=admin).json()
    key = {"X-API-Key": created["key"]}
    assert client.get("/api/v1/me", headers=key).status_code == 200
    revoked = client.delete(f"{API}/{created['id']}", headers=admin)
    assert revoked.status_code == 200 and revoked.json()["revoked_at"] is not None
    assert client.get("/api/v1/me", headers=key).status_code == 401
    active = client.get(API, params={"include_revoked": False}, headers=admin).json()
    assert created["id"] not in [k["id"] for k in active["items"]]


def test_only_admins_manage_keys(client: TestClient, tenant: Tenant) -> None:
    target = client.get(API, headers=tenant.headers("admin")).json()["items"][0]["id"]
    for role in ("viewer", "analyst"):
        headers = tenant.headers(role)
        assert client.get(API, headers=headers).status_code == 403
        body = {"name": "x", "role": "admin"}
        assert client.post(API, json=body, headers=headers).status_code == 403
        assert client.delete(f"{API}/{target}", headers=headers).status_code == 403


def test_bad_key_requests_name_the_field(
    client: TestClient, session: Session, tenant: Tenant
) -> None:
    admin = tenant.headers("admin")
    before = len(client.get(API, headers=admin).json()["items"])
    for body, field in (
        ({"name": "x", "role": "owner"}, "role"),
        ({"name": "x"}, "role"),
        ({"role": "viewer"}, "name"),
        ({"name": "", "role": "viewer"}, "name"),
        ({"name": "x", "role": "viewer", "operator_id": 1}, "operator_id"),
    ):
        response = client.post(API, json=body, headers=admin)
        assert response.status_code == 422
        assert error_of(response)["details"][0]["location"] == ["body", field]
    assert len(client.get(API, headers=admin).json()["items"]) == before


def test_another_operators_key_cannot_be_revoked(
    client: TestClient, session: Session, tenant: Tenant
) -> None:
    other = make_tenant(session, "Other Key Air")
    theirs = client.get(API, headers=other.headers("admin")).json()["items"][0]
    response = client.delete(f"{API}/{theirs['id']}", headers=tenant.headers("admin"))
    assert response.status_code == 404
    assert client.get("/api/v1/me", headers=other.headers("admin")).status_code == 200
