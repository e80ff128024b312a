"""``create_design``: run the estimation core's design step for a design stored pending
(``POST /api/v1/designs?background=true``)."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict
from sqlalchemy.orm import Session

from app.services.designs import service as designs
from app.services.jobs.registry import Progress, registry


class CreateDesign(BaseModel):
    model_config = ConfigDict(extra="forbid")

    design_id: int


@registry.job(
    designs.DESIGN_JOB,
    parameters=CreateDesign,
    description="Design the tuners and steady-state gain of a pending estimator design.",
    role="analyst",
)
def create_design(
    session: Session, parameters: CreateDesign, progress: Progress, *, operator_id: int
) -> dict[str, Any]:
    progress(0.0, "designing")
    design = designs.run_pending_design(
        session, operator_id=operator_id, design_id=parameters.design_id
    )
    return {
        "design_id": design.id,
        "status": design.status,
        "ssee_health": design.ssee_health,
        "failure": design.failure,
    }
