"""Reports of one engine and of the fleet, as PDF or as an Excel workbook, plots as images."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Query, Response

from app.security import CurrentPrincipal, DbSession
from app.services.reports import service as reports
from app.services.reports.service import MEDIA_TYPES, ReportFile, ReportFormat

router = APIRouter(prefix="/api/v1", tags=["reports"])

BINARY = {"schema": {"type": "string", "format": "binary"}}
FILE_RESPONSES: dict[int | str, dict[str, Any]] = {
    200: {
        "description": "the report: PDF with ?format=pdf, Excel (.xlsx) with ?format=xlsx",
        "content": {media_type: BINARY for media_type in MEDIA_TYPES.values()},
    },
    503: {"description": "the plots cannot be rendered (the message names what is missing), "
                         "or the database is unavailable (retry after Retry-After's seconds)",
          "headers": {"Retry-After": {"schema": {"type": "integer"},
                                      "description": "seconds to wait before retrying, sent "
                                                     "when the database is unavailable"}}},
}
Format = Annotated[ReportFormat, Query(description="pdf, or xlsx (an Excel workbook)")]


def _download(report: ReportFile) -> Response:
    return Response(
        report.body,
        media_type=report.media_type,
        headers={"Content-Disposition": f'attachment; filename="{report.filename}"'},
    )


@router.get("/engines/{engine_id}/report", response_class=Response, responses=FILE_RESPONSES)
def engine_report(
    engine_id: int, format: Format, session: DbSession, principal: CurrentPrincipal
) -> Response:
    """The engine's report: identity, state and severity with its limit checks, the current
    health change and engineering figures (dEGT, EGT margin, thrust deficit, stall margins)
    with their 1-sigma, active events with their isolation, maintenance actions, and the
    engine page's trend plots as images."""
    return _download(reports.engine_report(session, principal.operator_id, engine_id, format))


@router.get("/fleet/report", response_class=Response, responses=FILE_RESPONSES)
def fleet_report(format: Format, session: DbSession, principal: CurrentPrincipal) -> Response:
    """The fleet report: every engine ranked by severity with the counts per state, active
    alerts, and the fleet-average deterioration per month as images."""
    return _download(reports.fleet_report(session, principal.operator_id, format))
