"""The demo's active design gets its stream estimates calibrated once, in the background, and
only they: the snapshot calibration stays as the first start stored it."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from sqlalchemy.orm import Session, sessionmaker

from app.jobs.demo import queue_demo_stream_calibration
from app.jobs.runner import run_pending
from app.models import EstimatorDesign, Job
from app.services.demo import fleet as demo
from app.services.demo.operator import DEMO_OPERATOR
from app.services.designs import calibration, engine_models
from app.services.designs import service as designs
from app.services.fleet import service as fleet_service
from app.services.snapshots import estimator
from app.services.streams import calibration as stream_calibration
from app.services.tenancy import service as tenancy
from estimation.uncertainty import Calibration
from tests.support.builtin_fleet import coarse_schedule
from tests.support.stream_uncertainty import simulate_once

pytestmark = pytest.mark.long(seconds=50)


def test_the_active_demo_design_gets_its_stream_calibration_once(
    session: Session, session_factory: sessionmaker[Session], monkeypatch: pytest.MonkeyPatch
) -> None:
    schedule = coarse_schedule()
    monkeypatch.setattr(estimator, "builtin_schedule", lambda: schedule)
    simulate_once(monkeypatch)  # one simulation for both databases
    operator = tenancy.create_operator(session, name=DEMO_OPERATOR)
    engine_type = fleet_service.create_engine_type(
        session, operator_id=operator.id, name=demo.ENGINE_TYPE, description="")
    model = schedule.model_at(*demo.DESIGN_POINT.values())
    row, _ = engine_models.register_builtin_model(
        session, operator_id=operator.id, engine_type_id=engine_type.id, name="cruise",
        model=model)
    spec = demo.design_spec("subset", 8, [n for n in model.sensor_names if n != "Wf"])
    for name, active in (("spare", False), ("active", True)):
        design = designs.run_design(session, designs.create_design(
            session, operator_id=operator.id, engine_model_id=row.id, name=name, spec=spec),
            designs.design_step)
        design.active = active
        session.flush()
    design_id = design.id
    # The snapshots' calibration the first start stored (its numbers do not matter here).
    one = {"names": ("fan_eff",), "level_std": np.ones(1), "change_std": np.zeros(1),
           "slope_error": np.zeros(1), "bias2": np.zeros(1), "drift": np.zeros(1),
           "observable": np.ones(1, bool)}
    snapshots = calibration.store_calibration(
        session, design, Calibration(**one, source={"seeds": [5]}))
    session.commit()

    job_id = queue_demo_stream_calibration(session)
    session.commit()
    job = session.get(Job, job_id)
    assert job is not None and job.operator_id == operator.id
    assert job.kind == calibration.JOB_KIND
    assert job.parameters["design_id"] == design_id and job.parameters["snapshots"] is False
    assert job.parameters["streams"] is True
    assert queue_demo_stream_calibration(session) == job_id  # still queued: the same job

    # The job as queued calibrates 32 aircraft over whole flights (minutes): shrunk here.
    job.parameters = {**job.parameters, "stream_aircraft": 2, "stream_duration_s": 300}
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
    assert isinstance(done.result["streams_observable"], list)
    assert queue_demo_stream_calibration(session) is None  # calibrated: nothing more
    # One made before the calibration carried an engine's tuners from flight to flight is
    # calibrated again.
    assert streams.source["carried"] is True
    design = session.get(EstimatorDesign, design_id)
    assert design is not None
    stream_calibration.store_calibration(session, design, replace(
        streams, source={k: v for k, v in streams.source.items() if k != "carried"}))
    session.commit()
    again = queue_demo_stream_calibration(session)
    assert again is not None and again != job_id


def test_no_demo_operator_no_stream_calibration(session: Session) -> None:
    assert queue_demo_stream_calibration(session) is None
