"""Installations: which engine sat at which tail position when (no overlaps: 409)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, status

from app.schemas.fleet import (
    Deleted,
    InstallationCreate,
    InstallationOut,
    InstallationUpdate,
    IsoAwareDatetime,
    Page,
    PageParams,
)
from app.security import Analyst, CurrentPrincipal, DbSession
from app.services.fleet import service as fleet
from app.services.jobs.queue import Jobs

router = APIRouter(prefix="/api/v1/installations", tags=["fleet"])


@router.get("", response_model=Page[InstallationOut])
def list_installations(
    session: DbSession,
    principal: CurrentPrincipal,
    page: Annotated[PageParams, Query()],
    engine_id: int | None = None,
    aircraft_id: int | None = None,
    position: Annotated[int | None, Query(ge=1, le=4)] = None,
    at: IsoAwareDatetime | None = None,
) -> Page[InstallationOut]:
    """Installations, newest first; ``at`` keeps those in place at that time."""
    rows, total = fleet.list_installations(
        session,
        operator_id=principal.operator_id,
        limit=page.limit,
        offset=page.offset,
        engine_id=engine_id,
        aircraft_id=aircraft_id,
        position=position,
        at=at,
    )
    return Page.of([InstallationOut.of(r) for r in rows], total, page)


@router.post("", response_model=InstallationOut, status_code=status.HTTP_201_CREATED)
def create_installation(
    body: InstallationCreate, session: DbSession, principal: Analyst, jobs: Jobs
) -> InstallationOut:
    """Record an installation. Snapshots stored at that tail position over its period become
    this engine's, and the engines they came from and went to are estimated again in the
    background (an estimation job)."""
    row = fleet.install(session, operator_id=principal.operator_id, **body.model_dump())
    jobs.estimate(session, operator_id=principal.operator_id)
    return InstallationOut.of(row)


@router.get("/{installation_id}", response_model=InstallationOut)
def get_installation(
    installation_id: int, session: DbSession, principal: CurrentPrincipal
) -> InstallationOut:
    row = fleet.get_installation(
        session, operator_id=principal.operator_id, installation_id=installation_id
    )
    return InstallationOut.of(row)


@router.patch("/{installation_id}", response_model=InstallationOut)
def update_installation(
    installation_id: int, body: InstallationUpdate, session: DbSession, principal: Analyst,
    jobs: Jobs,
) -> InstallationOut:
    """Change the period or position; send ``removed_at`` when the engine comes off. Stored
    snapshots follow the corrected history, as on creation; those no installation covers any
    more stay with their engine."""
    row = fleet.update_installation(
        session,
        operator_id=principal.operator_id,
        installation_id=installation_id,
        changes=body.model_dump(exclude_unset=True),
    )
    jobs.estimate(session, operator_id=principal.operator_id)
    return InstallationOut.of(row)


@router.delete("/{installation_id}", response_model=Deleted)
def delete_installation(installation_id: int, session: DbSession, principal: Analyst) -> Deleted:
    fleet.delete_installation(
        session, operator_id=principal.operator_id, installation_id=installation_id
    )
    return Deleted(id=installation_id)
