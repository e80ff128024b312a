"""Aircraft (tails) of the fleet, their installation history and engines at a time."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Annotated

from fastapi import APIRouter, Query, status

from app.schemas.fleet import (
    AircraftCreate,
    AircraftOut,
    AircraftUpdate,
    Deleted,
    EngineOut,
    InstallationOut,
    IsoAwareDatetime,
    Page,
    PageParams,
    PositionEngine,
)
from app.security import Analyst, CurrentPrincipal, DbSession
from app.services.fleet import service as fleet

router = APIRouter(prefix="/api/v1/aircraft", tags=["fleet"])


@router.get("", response_model=Page[AircraftOut])
def list_aircraft(
    session: DbSession,
    principal: CurrentPrincipal,
    page: Annotated[PageParams, Query()],
    tail: str | None = None,
) -> Page[AircraftOut]:
    rows, total = fleet.list_aircraft(
        session, operator_id=principal.operator_id, limit=page.limit, offset=page.offset, tail=tail
    )
    return Page.of([AircraftOut.model_validate(r) for r in rows], total, page)


@router.post("", response_model=AircraftOut, status_code=status.HTTP_201_CREATED)
def create_aircraft(body: AircraftCreate, session: DbSession, principal: Analyst) -> AircraftOut:
    row = fleet.create_aircraft(session, operator_id=principal.operator_id, **body.model_dump())
    return AircraftOut.model_validate(row)


@router.get("/{aircraft_id}", response_model=AircraftOut)
def get_aircraft(aircraft_id: int, session: DbSession, principal: CurrentPrincipal) -> AircraftOut:
    row = fleet.get_aircraft(session, operator_id=principal.operator_id, aircraft_id=aircraft_id)
    return AircraftOut.model_validate(row)


@router.patch("/{aircraft_id}", response_model=AircraftOut)
def update_aircraft(
    aircraft_id: int, body: AircraftUpdate, session: DbSession, principal: Analyst
) -> AircraftOut:
    row = fleet.update_aircraft(
        session,
        operator_id=principal.operator_id,
        aircraft_id=aircraft_id,
        changes=body.model_dump(exclude_unset=True),
    )
    return AircraftOut.model_validate(row)


@router.delete("/{aircraft_id}", response_model=Deleted)
def delete_aircraft(aircraft_id: int, session: DbSession, principal: Analyst) -> Deleted:
    fleet.delete_aircraft(session, operator_id=principal.operator_id, aircraft_id=aircraft_id)
    return Deleted(id=aircraft_id)


@router.get("/{aircraft_id}/installations", response_model=Page[InstallationOut])
def aircraft_installations(
    aircraft_id: int,
    session: DbSession,
    principal: CurrentPrincipal,
    page: Annotated[PageParams, Query()],
) -> Page[InstallationOut]:
    """The tail's installation history, newest first."""
    aircraft = fleet.get_aircraft(
        session, operator_id=principal.operator_id, aircraft_id=aircraft_id
    )
    rows, total = fleet.list_installations(
        session,
        operator_id=principal.operator_id,
        aircraft_id=aircraft.id,
        limit=page.limit,
        offset=page.offset,
    )
    return Page.of([InstallationOut.of(r) for r in rows], total, page)


@router.get("/{aircraft_id}/engines", response_model=list[PositionEngine])
def aircraft_engines(
    aircraft_id: int,
    session: DbSession,
    principal: CurrentPrincipal,
    at: IsoAwareDatetime | None = None,
) -> list[PositionEngine]:
    """The engine at each position of the tail at time ``at`` (default: now)."""
    when: datetime = at or datetime.now(UTC)
    slots = fleet.engines_on_aircraft(
        session, operator_id=principal.operator_id, aircraft_id=aircraft_id, at=when
    )
    return [
        PositionEngine(
            position=position,
            engine=EngineOut.model_validate(row.engine) if row else None,
            installation_id=row.id if row else None,
        )
        for position, row in slots
    ]
