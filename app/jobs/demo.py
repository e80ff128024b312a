"""The demo's first evaluations: every ready design of the demo operator gets a Monte Carlo
evaluation (theory next to experiment, confusion matrices), run by the job runner in the
background, so a newcomer's designs page shows its plots without a click."""

from __future__ import annotations

from sqlalchemy import select
from sqlalchemy.orm import Session

from app.jobs.kinds import load_kinds
from app.models import Operator
from app.models.designs import EstimatorDesign
from app.services.demo.operator import DEMO_OPERATOR
from app.services.designs.evaluation import JOB_KIND, latest_evaluation
from app.services.jobs.registry import JobRegistry
from app.services.jobs.store import submit


def queue_demo_evaluations(session: Session, registry: JobRegistry | None = None) -> list[int]:
    """Queue ``evaluate_design`` for each ready demo design never evaluated; the job ids.

    Idempotent: a design with a succeeded evaluation, or one queued or running, gets none.
    """
    registry = registry or load_kinds()
    operator_id = session.scalar(select(Operator.id).where(Operator.name == DEMO_OPERATOR))
    if operator_id is None:
        return []
    designs = session.scalars(
        select(EstimatorDesign.id)
        .where(EstimatorDesign.operator_id == operator_id, EstimatorDesign.status == "ready")
        .order_by(EstimatorDesign.id)
    )
    queued = []
    for design_id in designs:
        if latest_evaluation(session, operator_id=operator_id, design_id=design_id) is not None:
            continue
        job, _created = submit(
            session, operator_id=operator_id, kind=JOB_KIND,
            parameters={"design_id": design_id}, registry=registry,
        )
        queued.append(job.id)
    return queued
