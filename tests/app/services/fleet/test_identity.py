"""API keys: stored hashed, resolve to their operator and role, revocable."""

from __future__ import annotations

from fastapi.testclient import TestClient
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.models import ApiKey
from app.services.tenancy import service as tenancy


def test_key_is_stored_only_as_digest_and_resolves_to_its_operator(session: Session) -> None:
    operator = tenancy.create_operator(session, name="North Air")
    row, key = tenancy.issue_api_key(session, operator=operator, role="viewer", name="ops")
    stored = session.scalar(select(ApiKey).where(ApiKey.id == row.id))
    assert stored is not None and key not in (stored.digest, stored.prefix + stored.digest)
    principal = tenancy.authenticate(session, key)
    assert principal is not None
    assert (principal.operator_id, principal.role) == (operator.id, "viewer")
    assert tenancy.authenticate(session, key + "x") is None


def test_me_needs_a_valid_unrevoked_key(client: TestClient, session: Session) -> None:
    operator = tenancy.create_operator(session, name="South Air")
    row, key = tenancy.issue_api_key(session, operator=operator, role="analyst", name="eng")
    session.commit()
    assert client.get("/api/v1/me").status_code == 401
    assert client.get("/api/v1/me", headers={"X-API-Key": "fh_nope"}).status_code == 401
    response = client.get("/api/v1/me", headers={"X-API-Key": key})
    assert response.status_code == 200
    assert response.json() == {
        "operator_id": operator.id,
        "operator": "South Air",
        "role": "analyst",
    }

    tenancy.revoke_api_key(session, operator_id=operator.id, key_id=row.id)
    session.commit()
    assert client.get("/api/v1/me", headers={"X-API-Key": key}).status_code == 401


def test_roles_are_ordered() -> None:
    analyst = tenancy.Principal(operator_id=1, operator_name="x", key_id=1, role="analyst")
    assert analyst.can("viewer") and analyst.can("analyst") and not analyst.can("admin")
