"""Estimator designs: create from a spec on an engine model, list, read, activate."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, Response, status

from app.schemas.designs import DesignCreate, DesignDetail, DesignOut
from app.schemas.fleet import Page, PageParams
from app.schemas.jobs import JobOut
from app.schemas.stream_estimates import TransientBiasFit, TransientBiasOut
from app.security import Analyst, CurrentPrincipal, DbSession
from app.services.designs import service as designs
from app.services.fleet import service as fleet
from app.services.jobs.queue import Jobs
from app.services.streams import bias

router = APIRouter(prefix="/api/v1", tags=["designs"])


@router.get("/designs", response_model=Page[DesignOut])
def list_designs(
    session: DbSession,
    principal: CurrentPrincipal,
    page: Annotated[PageParams, Query()],
    engine_type_id: int | None = None,
    engine_model_id: int | None = None,
    active: bool | None = None,
) -> Page[DesignOut]:
    """Designs, newest first, with their analytic errors (SSEE of health and aux outputs)."""
    rows, total = designs.list_designs(
        session,
        operator_id=principal.operator_id,
        limit=page.limit,
        offset=page.offset,
        engine_type_id=engine_type_id,
        engine_model_id=engine_model_id,
        active=active,
    )
    return Page.of([DesignOut.model_validate(r) for r in rows], total, page)


@router.post(
    "/designs",
    response_model=DesignDetail,
    status_code=status.HTTP_201_CREATED,
    responses={202: {"model": DesignDetail, "description": "pending, made by a job"}},
)
def create_design(
    body: DesignCreate,
    response: Response,
    session: DbSession,
    principal: Analyst,
    jobs: Jobs,
    background: Annotated[
        bool, Query(description="make the design in a create_design job (202, pending)")
    ] = False,
) -> DesignDetail:
    """Run the estimation core's design step on the engine model and store the result (201);
    with ``background=true`` the spec is checked, the design stored pending and a
    ``create_design`` job queued (202; follow it at /api/v1/jobs/{job_id})."""
    design = designs.create_design(
        session,
        operator_id=principal.operator_id,
        engine_model_id=body.engine_model_id,
        name=body.name,
        spec=body.spec,
    )
    if not background:
        design = designs.run_design(session, design, designs.design_step)
        return DesignDetail.model_validate(design)
    designs.check_spec(session, design)
    job, _created = jobs.submit(
        session,
        operator_id=principal.operator_id,
        kind=designs.DESIGN_JOB,
        parameters={"design_id": design.id},
    )
    response.status_code = status.HTTP_202_ACCEPTED
    return DesignDetail.model_validate(design).model_copy(update={"job_id": job.id})


@router.get("/designs/{design_id}", response_model=DesignDetail)
def get_design(design_id: int, session: DbSession, principal: CurrentPrincipal) -> DesignDetail:
    row = designs.get_design(session, operator_id=principal.operator_id, design_id=design_id)
    return DesignDetail.model_validate(row)


@router.post("/designs/{design_id}/activate", response_model=DesignOut)
def activate_design(
    design_id: int, session: DbSession, principal: Analyst, jobs: Jobs
) -> DesignOut:
    """Put the design in service for its engine type; the previously active one retires. The
    type's engines are then estimated under it in the background (an estimation job)."""
    row = designs.activate_design(
        session, operator_id=principal.operator_id, design_id=design_id
    )
    jobs.estimate(session, operator_id=principal.operator_id)
    return DesignOut.model_validate(row)


@router.post("/designs/{design_id}/deactivate", response_model=DesignOut)
def deactivate_design(design_id: int, session: DbSession, principal: Analyst) -> DesignOut:
    row = designs.deactivate_design(
        session, operator_id=principal.operator_id, design_id=design_id
    )
    return DesignOut.model_validate(row)


@router.get("/engine-types/{engine_type_id}/active-design", response_model=DesignOut | None)
def active_design(
    engine_type_id: int, session: DbSession, principal: CurrentPrincipal
) -> DesignOut | None:
    """The engine type's design in service, or null when none is active."""
    engine_type = fleet.get_engine_type(
        session, operator_id=principal.operator_id, engine_type_id=engine_type_id
    )
    row = designs.active_design(
        session, operator_id=principal.operator_id, engine_type_id=engine_type.id
    )
    return DesignOut.model_validate(row) if row else None


@router.post("/designs/{design_id}/transient-bias", response_model=JobOut,
             status_code=status.HTTP_202_ACCEPTED)
def fit_transient_bias(
    design_id: int, body: TransientBiasFit, session: DbSession, principal: Analyst, jobs: Jobs,
) -> JobOut:
    """Queue a ``fit_transient_bias`` job: the design's bias model (seed 004) from the
    recordings, stored with the design and applied by stream estimation (202; follow it at
    /api/v1/jobs/{job_id})."""
    bias.check_request(session, operator_id=principal.operator_id, design_id=design_id,
                       recording_ids=body.recording_ids)
    job, _created = jobs.submit(
        session, operator_id=principal.operator_id, kind=bias.JOB_KIND,
        parameters={"design_id": design_id, **body.model_dump()},
    )
    return JobOut.model_validate(job)


@router.get("/designs/{design_id}/transient-bias", response_model=TransientBiasOut)
def transient_bias(
    design_id: int, session: DbSession, principal: CurrentPrincipal
) -> TransientBiasOut:
    """The design's stored transient bias model (``model`` null while none is fitted)."""
    document = bias.stored_bias(session, operator_id=principal.operator_id, design_id=design_id)
    return TransientBiasOut(design_id=design_id, model=document)
