"""The demo's background work after its first start, run by the job runner so that a newcomer
sees it without a click: every ready design of the demo operator gets a Monte Carlo evaluation
(theory next to experiment, confusion matrices), and the active design its stream calibration
(the recording page's honest bands; the first start calibrated its snapshots already)."""

from __future__ import annotations

from sqlalchemy import select
from sqlalchemy.orm import Session

from app.jobs.kinds import load_kinds
from app.models import EngineModel, Operator
from app.models.designs import EstimatorDesign
from app.services.demo.operator import DEMO_OPERATOR
from app.services.designs import calibration
from app.services.designs.evaluation import JOB_KIND, latest_evaluation
from app.services.jobs.registry import JobRegistry
from app.services.jobs.store import submit
from app.services.streams import calibration as stream_calibration


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


def queue_demo_stream_calibration(
    session: Session, registry: JobRegistry | None = None
) -> int | None:
    """Queue ``calibrate_design`` of the stream estimates alone (the snapshots keep theirs) for
    the demo's active design when it is of the built-in engine and has no current stream
    calibration (none, or one made before it followed an engine's recordings from one to the
    next); the job's id, or None.

    Idempotent: the same job while it is queued or running, none once it has stored one."""
    registry = registry or load_kinds()
    operator_id = session.scalar(select(Operator.id).where(Operator.name == DEMO_OPERATOR))
    if operator_id is None:
        return None
    design_id = session.scalar(
        select(EstimatorDesign.id)
        .join(EngineModel, EngineModel.id == EstimatorDesign.engine_model_id)
        .where(EstimatorDesign.operator_id == operator_id, EstimatorDesign.active,
               EngineModel.source == "builtin")
        .order_by(EstimatorDesign.id)
        .limit(1)
    )
    if design_id is None or stream_calibration.is_current(
            stream_calibration.design_calibration(session, design_id)):
        return None
    job, _created = submit(
        session, operator_id=operator_id, kind=calibration.JOB_KIND,
        parameters={"design_id": design_id, "snapshots": False}, registry=registry,
    )
    return job.id
