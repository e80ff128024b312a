"""API key management of an operator's admin: list, create (the key shown once), revoke."""

from __future__ import annotations

from sqlalchemy import select
from sqlalchemy.orm import Session

from app.models import ApiKey, Operator
from app.services.common import paginate
from app.services.tenancy.service import issue_api_key, revoke_api_key


def list_keys(
    session: Session, *, operator_id: int, limit: int, offset: int, include_revoked: bool = True
) -> tuple[list[ApiKey], int]:
    stmt = select(ApiKey).where(ApiKey.operator_id == operator_id)
    if not include_revoked:
        stmt = stmt.where(ApiKey.revoked_at.is_(None))
    return paginate(session, stmt.order_by(ApiKey.id), limit=limit, offset=offset)


def create_key(session: Session, *, operator_id: int, role: str, name: str) -> tuple[ApiKey, str]:
    """The new key's row and its plain text, which is not stored and cannot be shown again."""
    operator = session.get(Operator, operator_id)
    assert operator is not None, "the principal's operator exists"
    return issue_api_key(session, operator=operator, role=role, name=name)


def revoke_key(session: Session, *, operator_id: int, key_id: int) -> ApiKey:
    row = revoke_api_key(session, operator_id=operator_id, key_id=key_id)
    session.flush()
    return row
