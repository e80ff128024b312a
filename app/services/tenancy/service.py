"""Operators and API keys: issue, authenticate, revoke."""

from __future__ import annotations

import hashlib
import secrets
from dataclasses import dataclass

from sqlalchemy import select
from sqlalchemy.orm import Session

from app.errors import Conflict, InvalidInput, NotFound
from app.models import ApiKey, Operator
from app.models.base import utcnow
from app.models.tenancy import ROLES

KEY_PREFIX = "fh"


@dataclass(frozen=True)
class Principal:
    """Who is calling: the operator every query is scoped to, and the key's role."""

    operator_id: int
    operator_name: str
    key_id: int
    role: str

    def can(self, role: str) -> bool:
        return ROLES.index(self.role) >= ROLES.index(role)


def digest(key: str) -> str:
    # Keys are 256-bit random strings, so a plain SHA-256 is a safe, fast lookup digest.
    return hashlib.sha256(key.encode()).hexdigest()


def create_operator(session: Session, *, name: str) -> Operator:
    if session.scalar(select(Operator).where(Operator.name == name)) is not None:
        raise Conflict(f"operator {name!r} exists already")
    operator = Operator(name=name)
    session.add(operator)
    session.flush()
    return operator


def issue_api_key(
    session: Session, *, operator: Operator, role: str, name: str, key: str | None = None
) -> tuple[ApiKey, str]:
    """Store a new key's digest and return the row and the plain key (shown once)."""
    if role not in ROLES:
        raise InvalidInput(f"role must be one of {', '.join(ROLES)}, not {role!r}")
    prefix = secrets.token_hex(4)
    plain = key or f"{KEY_PREFIX}_{prefix}_{secrets.token_urlsafe(32)}"
    row = ApiKey(operator=operator, name=name, prefix=plain[:16], digest=digest(plain), role=role)
    session.add(row)
    session.flush()
    return row, plain


def authenticate(session: Session, key: str) -> Principal | None:
    # One round trip per request: the key and its operator's name together.
    row = session.execute(
        select(ApiKey.id, ApiKey.operator_id, ApiKey.role, Operator.name)
        .join(Operator, Operator.id == ApiKey.operator_id)
        .where(ApiKey.digest == digest(key), ApiKey.revoked_at.is_(None))
    ).one_or_none()
    if row is None:
        return None
    return Principal(
        operator_id=row.operator_id, operator_name=row.name, key_id=row.id, role=row.role
    )


def revoke_api_key(session: Session, *, operator_id: int, key_id: int) -> ApiKey:
    row = session.get(ApiKey, key_id)
    if row is None or row.operator_id != operator_id:
        raise NotFound(f"API key {key_id} not found")
    if row.revoked_at is None:
        row.revoked_at = utcnow()
    return row
