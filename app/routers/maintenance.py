"""Maintenance actions (water wash, module change, shop visit: they reset detection baselines;
borescope finding) and the recovery measured after one."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, status

from app.schemas.fleet import (
    Deleted,
    IsoAwareDatetime,
    MaintenanceCreate,
    MaintenanceKind,
    MaintenanceOut,
    MaintenanceRecoveryOut,
    MaintenanceUpdate,
    Page,
    PageParams,
)
from app.security import Analyst, CurrentPrincipal, DbSession
from app.services.fleet import maintenance
from app.services.jobs.queue import Jobs
from app.services.trends import recovery

router = APIRouter(prefix="/api/v1/maintenance-actions", tags=["maintenance"])


@router.get("", response_model=Page[MaintenanceOut])
def list_actions(
    session: DbSession,
    principal: CurrentPrincipal,
    page: Annotated[PageParams, Query()],
    engine_id: int | None = None,
    kind: MaintenanceKind | None = None,
    since: IsoAwareDatetime | None = None,
    until: IsoAwareDatetime | None = None,
) -> Page[MaintenanceOut]:
    """Actions, newest first; filter by engine, kind and [since, until)."""
    rows, total = maintenance.list_actions(
        session,
        operator_id=principal.operator_id,
        limit=page.limit,
        offset=page.offset,
        engine_id=engine_id,
        kind=kind,
        since=since,
        until=until,
    )
    return Page.of([MaintenanceOut.model_validate(r) for r in rows], total, page)


@router.post("", response_model=MaintenanceOut, status_code=status.HTTP_201_CREATED)
def record_action(
    body: MaintenanceCreate, session: DbSession, principal: Analyst, jobs: Jobs
) -> MaintenanceOut:
    """Record an action; the engine's estimates from its time on are redone in the
    background (an estimation job), with the detection baseline restarted there."""
    row = maintenance.record_action(session, operator_id=principal.operator_id, **body.model_dump())
    jobs.estimate(session, operator_id=principal.operator_id)
    return MaintenanceOut.model_validate(row)


@router.get("/{maintenance_action_id}", response_model=MaintenanceOut)
def get_action(
    maintenance_action_id: int, session: DbSession, principal: CurrentPrincipal
) -> MaintenanceOut:
    row = maintenance.get_action(
        session, operator_id=principal.operator_id, action_id=maintenance_action_id
    )
    return MaintenanceOut.model_validate(row)


@router.get("/{maintenance_action_id}/recovery", response_model=MaintenanceRecoveryOut)
def get_recovery(
    maintenance_action_id: int, session: DbSession, principal: CurrentPrincipal,
    design_id: int | None = None,
) -> MaintenanceRecoveryOut:
    """The change of the engine's health parameters and EGT margin across the action: the mean
    of the settled records after it minus the mean of the records before it (a wash's
    recovery), with its standard error."""
    measured = recovery.recovery(
        session, principal.operator_id, maintenance_action_id, design_id=design_id
    )
    return MaintenanceRecoveryOut.model_validate(measured)


@router.patch("/{maintenance_action_id}", response_model=MaintenanceOut)
def update_action(
    maintenance_action_id: int, body: MaintenanceUpdate, session: DbSession, principal: Analyst,
    jobs: Jobs,
) -> MaintenanceOut:
    """Change an action; estimates are redone from the earlier of its old and new time."""
    row = maintenance.update_action(
        session,
        operator_id=principal.operator_id,
        action_id=maintenance_action_id,
        changes=body.model_dump(exclude_unset=True),
    )
    jobs.estimate(session, operator_id=principal.operator_id)
    return MaintenanceOut.model_validate(row)


@router.delete("/{maintenance_action_id}", response_model=Deleted)
def delete_action(
    maintenance_action_id: int, session: DbSession, principal: Analyst, jobs: Jobs
) -> Deleted:
    """Delete an action; estimates are redone from its time without its baseline restart."""
    maintenance.delete_action(
        session, operator_id=principal.operator_id, action_id=maintenance_action_id
    )
    jobs.estimate(session, operator_id=principal.operator_id)
    return Deleted(id=maintenance_action_id)
