"""Who am I: the dashboard's sign-in check."""

from __future__ import annotations

from fastapi import APIRouter
from pydantic import BaseModel

from app.security import CurrentPrincipal

router = APIRouter(prefix="/api/v1", tags=["identity"])


class Me(BaseModel):
    operator_id: int
    operator: str
    role: str


@router.get("/me", response_model=Me)
def me(principal: CurrentPrincipal) -> Me:
    """The operator and role of the API key sent in ``X-API-Key``."""
    return Me(
        operator_id=principal.operator_id, operator=principal.operator_name, role=principal.role
    )
