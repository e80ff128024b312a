"""Calibration of a stored built-in engine design: stored in the design's result and read back
by the trend; a design of an imported model is refused (no simulator of that engine)."""

from __future__ import annotations

import uuid
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from app.errors import Conflict
from app.jobs.runner import run_pending
from app.models import EngineModel, EstimatorDesign, Job
from app.services.demo import fleet as demo_fleet
from app.services.designs import calibration, engine_models
from app.services.designs import service as designs
from app.services.fleet import service as fleet_service
from app.services.snapshots import estimator
from app.services.streams import calibration as stream_calibration
from app.services.tenancy.service import create_operator
from estimation.engine.schedule import EngineSchedule, build_schedule
from estimation.uncertainty import Calibration
from tests.support.fleetkit import make_tenant
from tests.support.stream_uncertainty import simulate_once

pytestmark = pytest.mark.long(seconds=60)


@pytest.fixture(scope="module")
def coarse_schedule() -> EngineSchedule:
    return build_schedule({"alt": (0.0, 40000.0), "mach": (0.0, 0.85), "power": (40.0, 100.0)})


def _design(
    session: Session, schedule: EngineSchedule, operator_id: int | None = None
) -> EstimatorDesign:
    if operator_id is None:
        operator_id = create_operator(session, name=f"Calibration Air {uuid.uuid4().hex[:8]}").id
    engine_type = fleet_service.create_engine_type(
        session, operator_id=operator_id, name="built-in", description=""
    )
    model = schedule.model_at(*demo_fleet.DESIGN_POINT.values())
    row, _ = engine_models.register_builtin_model(
        session, operator_id=operator_id, engine_type_id=engine_type.id, name="cruise",
        model=model,
    )
    sensors = [n for n in model.sensor_names if n != "Wf"]
    design = designs.create_design(
        session, operator_id=operator_id, engine_model_id=row.id, name="svd 6",
        spec=demo_fleet.design_spec("svd", 6, sensors),
    )
    return designs.run_design(session, design, designs.design_step)


def test_a_builtin_design_is_calibrated_and_the_trend_reads_it(
    session: Session, coarse_schedule: EngineSchedule, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(estimator, "builtin_schedule", lambda: coarse_schedule)
    design = _design(session, coarse_schedule)
    assert calibration.design_calibration(session, design.id) is None
    stored = calibration.calibrate_design(
        session, operator_id=design.operator_id, design_id=design.id, seeds=(5,), aircraft=1,
        flights=200,
    )
    session.expire_all()
    back = calibration.design_calibration(session, design.id)
    assert back is not None
    assert back.to_dict() == stored == Calibration.from_dict(stored).to_dict()
    assert back.names == tuple(design.spec["health"])
    assert back.source["seeds"] == [5] and back.source["records"] > 0
    assert np.all(back.level_std >= 0.0)
    # The slopes' gain and its standard error are stored; one fleet cannot cross-validate
    # them: no slope is shown, and nothing asks to recalibrate.
    assert len(stored["slope_gain_std"]) == len(back.names)
    assert np.isnan(np.asarray(back.slope_gain)).all() and back.slope_sigma_known
    # Nor a slope correction: A = 0 and the sigma's scale 1 are stored.
    p = len(back.names)
    assert stored["slope_correction"] == [[0.0] * p] * p and stored["slope_scale"] == [1.0] * p
    # The design document keeps its other keys.
    refreshed = session.get(EstimatorDesign, design.id)
    assert refreshed is not None and refreshed.result is not None
    assert "model" in refreshed.result


def test_an_imported_design_is_not_calibrated(
    session: Session, coarse_schedule: EngineSchedule, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(estimator, "builtin_schedule", lambda: coarse_schedule)
    design = _design(session, coarse_schedule)
    model = session.get(EngineModel, design.engine_model_id)
    assert model is not None
    model.source = "imported"
    session.flush()
    with pytest.raises(Conflict):
        calibration.calibrate_design(session, operator_id=design.operator_id,
                                     design_id=design.id, seeds=(5,), aircraft=1, flights=100)


def test_the_calibration_job_stores_it_with_the_design(
    client: TestClient, session: Session, session_factory: sessionmaker[Session],
    coarse_schedule: EngineSchedule, monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(estimator, "builtin_schedule", lambda: coarse_schedule)
    simulate_once(monkeypatch)  # one simulation for both databases
    design, job = _post_calibration(
        client, session, coarse_schedule, "Calibration Job Air",
        {"seeds": [5], "aircraft": 1, "flights": 200, "stream_seed": 7, "stream_aircraft": 2,
         "stream_duration_s": 400})
    assert job.status_code == 202, job.text
    assert run_pending(session_factory) == [job.json()["id"]]
    session.expire_all()
    back = calibration.design_calibration(session, design.id)
    assert back is not None and back.source["seeds"] == [5]
    # The stream estimates' calibration beside it, on recorded flights of a fleet of its own.
    streams = stream_calibration.design_calibration(session, design.id)
    assert streams is not None and streams.source["seeds"] == [7]
    assert streams.source["groups"] == 2 and streams.source["flights"] == 16
    assert streams.source["windows"] > 0 and streams.names == back.names


def test_a_calibration_of_nothing_is_refused(
    client: TestClient, session: Session, coarse_schedule: EngineSchedule,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(estimator, "builtin_schedule", lambda: coarse_schedule)
    design, reply = _post_calibration(client, session, coarse_schedule, "Calibration Nothing Air",
                                      {"snapshots": False, "streams": False})
    assert reply.status_code == 422, reply.text
    assert "nothing to calibrate" in reply.text
    assert session.scalars(select(Job).where(Job.operator_id == design.operator_id)).all() == []


def _post_calibration(
    client: TestClient, session: Session, schedule: EngineSchedule, operator: str,
    parameters: dict[str, object],
) -> tuple[EstimatorDesign, Any]:
    """A new operator's built-in design and the answer to its calibration job's POST."""
    tenant = make_tenant(session, operator)
    design = _design(session, schedule, tenant.operator_id)
    session.commit()
    reply = client.post(
        "/api/v1/jobs",
        json={"kind": "calibrate_design", "parameters": {"design_id": design.id, **parameters}},
        headers=tenant.headers(),
    )
    return design, reply
