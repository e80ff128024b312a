"""Fleet status and fleet-average deterioration."""

from __future__ import annotations

from typing import Literal

from fastapi import APIRouter, Response

from app.schemas.estimates import FleetDeterioration, FleetStatus
from app.security import CurrentPrincipal, DbSession
from app.services.fleet import status
from app.services.trends.service import to_json

router = APIRouter(prefix="/api/v1/fleet", tags=["fleet status"])


@router.get("/status", response_model=FleetStatus)
def fleet_status(session: DbSession, principal: CurrentPrincipal) -> object:
    """Every engine with its current tail and position, type, last data, latest health summary
    and open events."""
    return Response(
        to_json(status.fleet_status(session, principal.operator_id)),
        media_type="application/json",
    )


@router.get("/deterioration", response_model=FleetDeterioration)
def fleet_deterioration(
    session: DbSession, principal: CurrentPrincipal, bucket: Literal["week", "month"] = "month"
) -> object:
    """Fleet-average health-parameter and auxiliary estimates per week or month."""
    return status.fleet_deterioration(session, principal.operator_id, bucket)
