"""Fleet status and fleet-average deterioration."""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Query, Response

from app.schemas.estimates import EngineState, FleetDeterioration, FleetStatus
from app.schemas.fleet import MAX_PAGE
from app.security import CurrentPrincipal, DbSession
from app.services.fleet import status
from app.services.trends.service import to_json

router = APIRouter(prefix="/api/v1/fleet", tags=["fleet status"])


@router.get("/status", response_model=FleetStatus)
def fleet_status(
    session: DbSession,
    principal: CurrentPrincipal,
    state: Annotated[EngineState | None, Query(description="only engines in this state")] = None,
    limit: Annotated[int, Query(ge=1, le=MAX_PAGE)] = MAX_PAGE,
    offset: Annotated[int, Query(ge=0, le=2**31 - 1)] = 0,
) -> object:
    """The engines ranked by severity, a page at a time, each with its current tail and
    position, type, last data, latest health summary and open events; with the fleet's
    counts per state."""
    return Response(
        to_json(status.fleet_status(session, principal.operator_id, in_state=state, limit=limit,
                                    offset=offset)),
        media_type="application/json",
    )


@router.get("/deterioration", response_model=FleetDeterioration)
def fleet_deterioration(
    session: DbSession, principal: CurrentPrincipal, bucket: Literal["week", "month"] = "month"
) -> object:
    """Fleet-average health-parameter and auxiliary estimates per week or month."""
    return status.fleet_deterioration(session, principal.operator_id, bucket)
