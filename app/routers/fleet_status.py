"""Fleet status and fleet-average deterioration."""

from __future__ import annotations

from datetime import timedelta
from typing import Annotated, Literal

from fastapi import APIRouter, Query, Request, Response

from app.schemas.estimates import (
    DataCoverage,
    EngineCoverageOut,
    EngineState,
    FleetDeterioration,
    FleetDeteriorationSlopes,
    FleetStatus,
    TailCoverageOut,
)
from app.schemas.fleet import MAX_PAGE
from app.security import CurrentPrincipal, DbSession
from app.services.fleet import coverage, status
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


@router.get("/deterioration/slopes", response_model=FleetDeteriorationSlopes)
def fleet_deterioration_slopes(session: DbSession, principal: CurrentPrincipal) -> object:
    """Fleet-average deterioration slope of each health parameter per active design (percent
    per year, with its 1-sigma; null where the design cannot observe it)."""
    return status.fleet_deterioration_slopes(session, principal.operator_id)


@router.get("/data-coverage", response_model=DataCoverage)
def data_coverage(
    request: Request,
    session: DbSession,
    principal: CurrentPrincipal,
    overdue_days: Annotated[
        float | None,
        Query(gt=0, le=3650, description="overdue age in days; default "
              "FLEETHEALTH_DATA_OVERDUE_DAYS (7)"),
    ] = None,
) -> DataCoverage:
    """Each tail's and each engine's last data, and the installed engines whose data is
    overdue (no record for longer than ``overdue_days``)."""
    days = overdue_days if overdue_days is not None else (
        request.app.state.settings.data_overdue_days
    )
    found = coverage.data_coverage(
        session, principal.operator_id, overdue_after=timedelta(days=days)
    )
    return DataCoverage(
        now=found.now, overdue_days=days, n_overdue=sum(e.overdue for e in found.engines),
        tails=[TailCoverageOut.model_validate(t) for t in found.tails],
        engines=[EngineCoverageOut.model_validate(e) for e in found.engines],
    )
