"""API-key authentication: the tenant comes from the key, never from the request body."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Annotated

from fastapi import Depends, Request, Security
from fastapi.security import APIKeyHeader
from sqlalchemy.orm import Session

from app.db import transaction
from app.errors import Forbidden, Unauthorized
from app.services.tenancy.service import Principal, authenticate

api_key_header = APIKeyHeader(
    name="X-API-Key", auto_error=False, description="Your operator's API key"
)


READ_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})


def get_session(request: Request) -> Iterator[Session]:
    """A session per request, committed when the route returns without error."""
    write = request.method not in READ_METHODS
    with transaction(request.app.state.sessionmaker, write=write) as session:
        yield session


# scope="function": the session commits before the response is sent, so a 2xx means
# committed (with the default "request" scope the commit ran after the client had its answer).
DbSession = Annotated[Session, Depends(get_session, scope="function")]


def get_principal(session: DbSession, key: str | None = Security(api_key_header)) -> Principal:
    if not key:
        raise Unauthorized("missing API key: send it in the X-API-Key header")
    principal = authenticate(session, key)
    if principal is None:
        raise Unauthorized("unknown or revoked API key")
    return principal


def require(role: str) -> Callable[[Principal], Principal]:
    """Dependency factory: the caller's key must have at least ``role``."""

    def check(principal: Annotated[Principal, Depends(get_principal)]) -> Principal:
        if not principal.can(role):
            raise Forbidden(f"this action needs the {role} role; your key is {principal.role}")
        return principal

    return check


CurrentPrincipal = Annotated[Principal, Depends(get_principal)]
Analyst = Annotated[Principal, Depends(require("analyst"))]
Admin = Annotated[Principal, Depends(require("admin"))]
