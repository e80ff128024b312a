"""API keys of the caller's operator (admin only): list, create (shown once), revoke."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, status

from app.schemas.fleet import ApiKeyCreate, ApiKeyCreated, ApiKeyOut, Page, PageParams
from app.security import Admin, DbSession
from app.services.tenancy import keys

router = APIRouter(prefix="/api/v1/keys", tags=["identity"])


@router.get("", response_model=Page[ApiKeyOut])
def list_keys(
    session: DbSession,
    principal: Admin,
    page: Annotated[PageParams, Query()],
    include_revoked: bool = True,
) -> Page[ApiKeyOut]:
    rows, total = keys.list_keys(
        session,
        operator_id=principal.operator_id,
        limit=page.limit,
        offset=page.offset,
        include_revoked=include_revoked,
    )
    return Page.of([ApiKeyOut.model_validate(r) for r in rows], total, page)


@router.post("", response_model=ApiKeyCreated, status_code=status.HTTP_201_CREATED)
def create_key(body: ApiKeyCreate, session: DbSession, principal: Admin) -> ApiKeyCreated:
    """A new key for the operator; the ``key`` field is shown in this response only."""
    row, plain = keys.create_key(
        session, operator_id=principal.operator_id, role=body.role, name=body.name
    )
    return ApiKeyCreated(**ApiKeyOut.model_validate(row).model_dump(), key=plain)


@router.delete("/{key_id}", response_model=ApiKeyOut)
def revoke_key(key_id: int, session: DbSession, principal: Admin) -> ApiKeyOut:
    """Revoke a key: requests with it answer 401 from now on."""
    row = keys.revoke_key(session, operator_id=principal.operator_id, key_id=key_id)
    return ApiKeyOut.model_validate(row)
