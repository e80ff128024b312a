"""Trend routes: per engine serial number and per tail, as JSON or CSV (``?format=csv``)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, Query, Response

from app.schemas.estimates import AircraftTrend, EngineTrend
from app.schemas.fleet import IsoDatetime
from app.security import CurrentPrincipal, DbSession
from app.services.trends import service as trends

router = APIRouter(prefix="/api/v1", tags=["trends"])

CSV_RESPONSE: dict[int | str, dict[str, Any]] = {
    200: {"content": {"text/csv": {}}, "description": "JSON, or CSV with ?format=csv"}
}
MaxPoints = Query(
    trends.DEFAULT_MAX_POINTS,
    ge=0,
    # A plot shows a few thousand points; 20,000 buckets bound a read's cost (JSON of every
    # series for each bucket). 0 keeps every record, for exports of one engine's history.
    le=20_000,
    description="decimate into at most this many buckets (mean, min, max), at most 20,000; "
    "0 keeps every record",
)


def _csv(body: str, filename: str) -> Response:
    return Response(
        body,
        media_type="text/csv",
        headers={"Content-Disposition": f'attachment; filename="{filename}"'},
    )


@router.get("/engines/{engine_id}/trend", response_model=EngineTrend, responses=CSV_RESPONSE)
def engine_trend(
    engine_id: int,
    session: DbSession,
    principal: CurrentPrincipal,
    start: Annotated[IsoDatetime | None, Query(description="from this time, ISO 8601")] = None,
    end: Annotated[IsoDatetime | None, Query(description="before this time")] = None,
    design_id: Annotated[
        int | None, Query(description="default: the engine type's active design")
    ] = None,
    max_points: int = MaxPoints,
    format: Literal["json", "csv"] = "json",
    health: Annotated[
        Literal["level", "change"],
        Query(description="health group: levels, or the change since the engine's baseline"),
    ] = "level",
) -> object:
    """Tuners, health parameters with 1-sigma, thrust and margins, residuals and WSSR over time,
    with installation changes, maintenance actions and events as markers."""
    options: dict[str, Any] = {
        "design_id": design_id, "start": start, "end": end, "max_points": max_points,
        "health": health,
    }
    if format == "csv":
        trend = trends.engine_trend(session, principal.operator_id, engine_id, **options)
        return _csv(trends.engine_trend_csv(trend), f"trend-{trend['esn']}.csv")
    body = trends.engine_trend_json(session, principal.operator_id, engine_id, **options)
    return Response(body, media_type="application/json")


@router.get(
    "/aircraft/{aircraft_id}/trend", response_model=AircraftTrend, responses=CSV_RESPONSE
)
def aircraft_trend(
    aircraft_id: int,
    session: DbSession,
    principal: CurrentPrincipal,
    start: Annotated[IsoDatetime | None, Query(description="from this time, ISO 8601")] = None,
    end: Annotated[IsoDatetime | None, Query(description="before this time")] = None,
    max_points: int = MaxPoints,
    format: Literal["json", "csv"] = "json",
) -> object:
    """The union over the tail's installations: each engine's trend while it sat on the tail."""
    options: dict[str, Any] = {"start": start, "end": end, "max_points": max_points}
    if format == "csv":
        trend = trends.aircraft_trend(session, principal.operator_id, aircraft_id, **options)
        return _csv(trends.aircraft_trend_csv(trend), f"trend-{trend['tail']}.csv")
    body = trends.aircraft_trend_json(session, principal.operator_id, aircraft_id, **options)
    return Response(body, media_type="application/json")
