"""Engines (ESN) of the fleet and their installation history."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Annotated, Any

from fastapi import APIRouter, Query, status

from app.schemas.fleet import (
    Deleted,
    EngineCreate,
    EngineOut,
    EngineUpdate,
    InstallationOut,
    Page,
    PageParams,
)
from app.security import Analyst, CurrentPrincipal, DbSession
from app.services.fleet import service as fleet
from app.services.jobs.queue import Jobs

router = APIRouter(prefix="/api/v1/engines", tags=["fleet"])


@router.get("", response_model=Page[EngineOut])
def list_engines(
    session: DbSession,
    principal: CurrentPrincipal,
    page: Annotated[PageParams, Query()],
    esn: str | None = None,
    engine_type_id: int | None = None,
) -> Page[EngineOut]:
    rows, total = fleet.list_engines(
        session,
        operator_id=principal.operator_id,
        limit=page.limit,
        offset=page.offset,
        esn=esn,
        engine_type_id=engine_type_id,
    )
    return Page.of(_placed(session, principal.operator_id, rows), total, page)


@router.post("", response_model=EngineOut, status_code=status.HTTP_201_CREATED)
def create_engine(body: EngineCreate, session: DbSession, principal: Analyst) -> EngineOut:
    row = fleet.create_engine(session, operator_id=principal.operator_id, **body.model_dump())
    return EngineOut.model_validate(row)


@router.get("/{engine_id}", response_model=EngineOut)
def get_engine(engine_id: int, session: DbSession, principal: CurrentPrincipal) -> EngineOut:
    row = fleet.get_engine(session, operator_id=principal.operator_id, engine_id=engine_id)
    return _placed(session, principal.operator_id, [row])[0]


@router.patch("/{engine_id}", response_model=EngineOut)
def update_engine(
    engine_id: int, body: EngineUpdate, session: DbSession, principal: Analyst, jobs: Jobs
) -> EngineOut:
    """Change an engine; a new engine type has its data estimated under that type's active
    design in the background (an estimation job)."""
    before = fleet.get_engine(session, operator_id=principal.operator_id, engine_id=engine_id)
    old_type = before.engine_type_id
    row = fleet.update_engine(
        session,
        operator_id=principal.operator_id,
        engine_id=engine_id,
        changes=body.model_dump(exclude_unset=True),
    )
    if row.engine_type_id != old_type:
        jobs.estimate(session, operator_id=principal.operator_id)
    return _placed(session, principal.operator_id, [row])[0]


@router.delete("/{engine_id}", response_model=Deleted)
def delete_engine(engine_id: int, session: DbSession, principal: Analyst) -> Deleted:
    fleet.delete_engine(session, operator_id=principal.operator_id, engine_id=engine_id)
    return Deleted(id=engine_id)


@router.get("/{engine_id}/installations", response_model=Page[InstallationOut])
def engine_installations(
    engine_id: int,
    session: DbSession,
    principal: CurrentPrincipal,
    page: Annotated[PageParams, Query()],
) -> Page[InstallationOut]:
    """Where the engine has been installed, newest first (its history follows it)."""
    engine = fleet.get_engine(session, operator_id=principal.operator_id, engine_id=engine_id)
    rows, total = fleet.list_installations(
        session,
        operator_id=principal.operator_id,
        engine_id=engine.id,
        limit=page.limit,
        offset=page.offset,
    )
    return Page.of([InstallationOut.of(r) for r in rows], total, page)


def _placed(session: DbSession, operator_id: int, rows: Sequence[Any]) -> list[EngineOut]:
    """The engines (the service's rows) as the API shows them, each with the tail and position
    it is on now."""
    where = fleet.current_placements(session, operator_id, [r.id for r in rows])
    out = []
    for row in rows:
        engine = EngineOut.model_validate(row)
        placed = where.get(row.id)
        if placed is not None:
            engine = engine.model_copy(update={"tail": placed.tail, "position": placed.position})
        out.append(engine)
    return out
