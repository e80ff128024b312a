"""Engine models: import a fleethealth.linear-model/1 document, list, read, delete unused."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, Response, status

from app.schemas.designs import (
    BuiltinModelCreate,
    EngineModelContent,
    EngineModelImport,
    EngineModelOut,
)
from app.schemas.fleet import Deleted, Page, PageParams
from app.security import Analyst, CurrentPrincipal, DbSession
from app.services.designs import engine_models

router = APIRouter(prefix="/api/v1/engine-models", tags=["engine models"])


@router.get("", response_model=Page[EngineModelOut])
def list_engine_models(
    session: DbSession,
    principal: CurrentPrincipal,
    page: Annotated[PageParams, Query()],
    engine_type_id: int | None = None,
    name: str | None = None,
) -> Page[EngineModelOut]:
    rows, total = engine_models.list_engine_models(
        session,
        operator_id=principal.operator_id,
        limit=page.limit,
        offset=page.offset,
        engine_type_id=engine_type_id,
        name=name,
    )
    return Page.of([EngineModelOut.model_validate(r) for r in rows], total, page)


@router.post(
    "",
    response_model=EngineModelOut,
    status_code=status.HTTP_201_CREATED,
    responses={200: {"model": EngineModelOut, "description": "identical version exists"}},
)
def import_engine_model(
    body: EngineModelImport, response: Response, session: DbSession, principal: Analyst
) -> EngineModelOut:
    """Validate and store a model or a model schedule as the next version of ``name`` (201);
    identical content to a stored version returns that version (200) and stores nothing.
    Several model files (``models``) are stored as one schedule over ``variables``."""
    schedule = None
    if body.models is not None:
        schedule = engine_models.schedule_from_files(
            body.models, body.variables or [], body.corrections, body.design_point)
    row, created = engine_models.import_engine_model(
        session,
        operator_id=principal.operator_id,
        engine_type_id=body.engine_type_id,
        name=body.name,
        content=body.model,
        schedule=schedule,
    )
    if not created:
        response.status_code = status.HTTP_200_OK
    return EngineModelOut.model_validate(row)


@router.post(
    "/builtin",
    response_model=EngineModelOut,
    status_code=status.HTTP_201_CREATED,
    responses={200: {"model": EngineModelOut, "description": "identical version exists"}},
)
def build_builtin_model(
    body: BuiltinModelCreate, response: Response, session: DbSession, principal: Analyst
) -> EngineModelOut:
    """Linearise the built-in engine at the operating condition and store the model as the
    next version of ``name`` (201; an identical stored version answers 200)."""
    row, created = engine_models.build_builtin_model(
        session, operator_id=principal.operator_id, **body.model_dump()
    )
    if not created:
        response.status_code = status.HTTP_200_OK
    return EngineModelOut.model_validate(row)


@router.get("/{engine_model_id}", response_model=EngineModelOut)
def get_engine_model(
    engine_model_id: int, session: DbSession, principal: CurrentPrincipal
) -> EngineModelOut:
    row = engine_models.get_engine_model(
        session, operator_id=principal.operator_id, engine_model_id=engine_model_id
    )
    return EngineModelOut.model_validate(row)


@router.get("/{engine_model_id}/content", response_model=EngineModelContent)
def get_engine_model_content(
    engine_model_id: int, session: DbSession, principal: CurrentPrincipal
) -> EngineModelContent:
    """The stored fleethealth.linear-model/1 document."""
    row = engine_models.get_engine_model(
        session, operator_id=principal.operator_id, engine_model_id=engine_model_id
    )
    return EngineModelContent(id=row.id, version=row.version, model=row.content)


@router.delete("/{engine_model_id}", response_model=Deleted)
def delete_engine_model(engine_model_id: int, session: DbSession, principal: Analyst) -> Deleted:
    """Delete a model no design uses (409 once used: it is immutable from then on)."""
    engine_models.delete_engine_model(
        session, operator_id=principal.operator_id, engine_model_id=engine_model_id
    )
    return Deleted(id=engine_model_id)
