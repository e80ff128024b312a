"""Helpers for the fleet tests: tenants with keys, and a small fleet made through the API."""

from __future__ import annotations

import uuid
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

from fastapi.testclient import TestClient
from sqlalchemy.orm import Session

from app.services.tenancy import service as tenancy

T0 = datetime(2026, 1, 1, tzinfo=UTC)


@dataclass
class Tenant:
    operator_id: int
    keys: dict[str, str]
    ids: dict[str, int] = field(default_factory=dict)

    def headers(self, role: str = "analyst") -> dict[str, str]:
        return {"X-API-Key": self.keys[role]}


def make_tenant(session: Session, name: str) -> Tenant:
    """An operator with one key per role, committed so the API sees them.

    The name gets a random suffix: tests must not depend on being alone in the database.
    """
    operator = tenancy.create_operator(session, name=f"{name} {uuid.uuid4().hex[:8]}")
    keys = {
        role: tenancy.issue_api_key(session, operator=operator, role=role, name=role)[1]
        for role in ("viewer", "analyst", "admin")
    }
    session.commit()
    return Tenant(operator.id, keys)


def post(client: TestClient, tenant: Tenant, path: str, body: dict[str, Any]) -> dict[str, Any]:
    """POST that must succeed; returns the JSON body."""
    response = client.post(path, json=body, headers=tenant.headers("analyst"))
    assert response.status_code in (200, 201), (path, response.status_code, response.text)
    result: dict[str, Any] = response.json()
    return result


def error_of(response: Any) -> dict[str, Any]:
    body: dict[str, Any] = response.json()
    assert set(body) == {"error"}, body
    return body["error"]  # type: ignore[no-any-return]
