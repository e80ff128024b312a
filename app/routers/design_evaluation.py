"""A design's latest Monte Carlo evaluation (run it with the ``evaluate_design`` job)."""

from __future__ import annotations

from fastapi import APIRouter

from app.schemas.design_evaluation import DesignEvaluation
from app.security import CurrentPrincipal, DbSession
from app.services.designs import evaluation

router = APIRouter(prefix="/api/v1", tags=["designs"])


@router.get("/designs/{design_id}/evaluation", response_model=DesignEvaluation | None)
def latest_evaluation(
    design_id: int, session: DbSession, principal: CurrentPrincipal
) -> DesignEvaluation | None:
    """The newest succeeded evaluation of the design, or null when it was never evaluated.
    Submit ``{"kind": "evaluate_design", "parameters": {"design_id": ...}}`` to /api/v1/jobs."""
    job = evaluation.latest_evaluation(
        session, operator_id=principal.operator_id, design_id=design_id
    )
    if job is None or job.result is None:
        return None
    return DesignEvaluation(
        design_id=design_id, job_id=job.id, finished_at=job.finished_at,
        parameters=job.parameters, result=job.result,
    )
