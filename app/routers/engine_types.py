"""Engine types of the fleet: viewers read, analysts write."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, status

from app.schemas.fleet import (
    Deleted,
    EngineTypeCreate,
    EngineTypeOut,
    EngineTypeUpdate,
    Page,
    PageParams,
    ParameterSetOut,
    SignalOut,
)
from app.security import Analyst, CurrentPrincipal, DbSession
from app.services.fleet import service as fleet
from app.services.fleet.parameter_sets import parameter_sets

router = APIRouter(prefix="/api/v1/engine-types", tags=["fleet"])


@router.get("", response_model=Page[EngineTypeOut])
def list_engine_types(
    session: DbSession, principal: CurrentPrincipal, page: Annotated[PageParams, Query()]
) -> Page[EngineTypeOut]:
    rows, total = fleet.list_engine_types(
        session, operator_id=principal.operator_id, limit=page.limit, offset=page.offset
    )
    return Page.of([EngineTypeOut.model_validate(r) for r in rows], total, page)


@router.post("", response_model=EngineTypeOut, status_code=status.HTTP_201_CREATED)
def create_engine_type(
    body: EngineTypeCreate, session: DbSession, principal: Analyst
) -> EngineTypeOut:
    row = fleet.create_engine_type(
        session, operator_id=principal.operator_id, name=body.name, description=body.description,
        limits=None if body.limits is None else body.limits.model_dump(exclude_none=True),
    )
    return EngineTypeOut.model_validate(row)


@router.get("/{engine_type_id}", response_model=EngineTypeOut)
def get_engine_type(
    engine_type_id: int, session: DbSession, principal: CurrentPrincipal
) -> EngineTypeOut:
    row = fleet.get_engine_type(
        session, operator_id=principal.operator_id, engine_type_id=engine_type_id
    )
    return EngineTypeOut.model_validate(row)


@router.get("/{engine_type_id}/parameters", response_model=ParameterSetOut)
def get_parameter_set(
    engine_type_id: int, session: DbSession, principal: CurrentPrincipal
) -> ParameterSetOut:
    """The type's parameter set: the signals its snapshots carry with their names and units,
    and the operating-condition columns they need, read from the type's models."""
    row = fleet.get_engine_type(
        session, operator_id=principal.operator_id, engine_type_id=engine_type_id
    )
    params = parameter_sets(session, [row.id])[row.id]
    return ParameterSetOut(
        engine_type_id=row.id, engine_type=row.name, from_models=params.from_models,
        signals=[SignalOut(name=s.name, unit=s.unit, quantity=s.quantity)
                 for s in params.signals],
        scheduled_on=list(params.scheduled_on), phase_required=params.phase_required,
    )


@router.patch("/{engine_type_id}", response_model=EngineTypeOut)
def update_engine_type(
    engine_type_id: int, body: EngineTypeUpdate, session: DbSession, principal: Analyst
) -> EngineTypeOut:
    row = fleet.update_engine_type(
        session,
        operator_id=principal.operator_id,
        engine_type_id=engine_type_id,
        changes=body.model_dump(exclude_unset=True, exclude_none=True),
    )
    return EngineTypeOut.model_validate(row)


@router.delete("/{engine_type_id}", response_model=Deleted)
def delete_engine_type(engine_type_id: int, session: DbSession, principal: Analyst) -> Deleted:
    fleet.delete_engine_type(
        session, operator_id=principal.operator_id, engine_type_id=engine_type_id
    )
    return Deleted(id=engine_type_id)
