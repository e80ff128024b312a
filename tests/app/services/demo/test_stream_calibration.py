"""The demo's active design gets its stream estimates calibrated once, in the background, and
only they: the snapshot calibration stays as the first start stored it."""

from __future__ import annotations

import pytest
from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from app.jobs.demo import queue_demo_stream_calibration
from app.jobs.runner import run_pending
from app.models import EstimatorDesign, Job
from app.services.demo import fleet as demo
from app.services.demo.operator import DEMO_OPERATOR
from app.services.designs import calibration
from app.services.snapshots import estimator
from app.services.streams import calibration as stream_calibration
from app.services.tenancy import service as tenancy
from tests.support.builtin_fleet import coarse_schedule


def test_the_active_demo_design_gets_its_stream_calibration_once(
    session: Session, session_factory: sessionmaker[Session], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(estimator, "builtin_schedule", coarse_schedule)
    operator = tenancy.create_operator(session, name=DEMO_OPERATOR)
    _type_id, design_id = demo._designs(session, operator.id, lambda _m: None)
    snapshots = calibration.calibrate_design(
        session, operator_id=operator.id, design_id=design_id, seeds=(5,), aircraft=1,
        flights=200)
    session.commit()
    assert session.scalars(select(EstimatorDesign.id).where(
        EstimatorDesign.operator_id == operator.id, EstimatorDesign.active)).all() == [design_id]

    job_id = queue_demo_stream_calibration(session)
    session.commit()
    job = session.get(Job, job_id)
    assert job is not None and job.operator_id == operator.id
    assert job.kind == calibration.JOB_KIND
    assert job.parameters["design_id"] == design_id and job.parameters["snapshots"] is False
    assert job.parameters["streams"] is True
    assert queue_demo_stream_calibration(session) == job_id  # still queued: the same job

    # The job as queued calibrates 32 aircraft over whole flights (minutes): shrunk here.
    job.parameters = {**job.parameters, "stream_aircraft": 2, "stream_duration_s": 400}
    session.commit()
    assert run_pending(session_factory) == [job_id]
    session.expire_all()
    done = session.get(Job, job_id)
    assert done is not None and done.status == "succeeded", done.error if done else None
    streams = stream_calibration.design_calibration(session, design_id)
    assert streams is not None and streams.source["flights"] == 16
    # The snapshots' calibration is the one stored before, untouched.
    back = calibration.design_calibration(session, design_id)
    assert back is not None and back.to_dict() == snapshots
    assert done.result is not None and "observable" not in done.result
    assert done.result["streams_observable"]
    assert queue_demo_stream_calibration(session) is None  # calibrated: nothing more


def test_no_demo_operator_no_stream_calibration(session: Session) -> None:
    assert queue_demo_stream_calibration(session) is None
