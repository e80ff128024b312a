"""FD001 end to end: C-MAPSS units imported through the REST upload, a design on the built-in
engine at FD001's operating condition, the estimation pipeline; FD001's fault mode is HPC
degradation, so the HPC health parameters must carry the largest estimated deterioration from
early life to end of life (the simulation's truth, checked against the estimates)."""

from __future__ import annotations

import uuid

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.cli.importers import CMAPSS_SENSORS, FD001_TRAIN, import_cmapss
from app.models import Engine, EngineType
from app.services.designs import engine_models
from app.services.designs import service as designs
from app.services.snapshots import estimator, store
from app.services.tenancy import service as tenancy
from app.services.trends import service as trends
from estimation.engine.schedule import EngineSchedule, build_schedule
from tests.support.paths import FD001

UNITS = 4
MODULES = ("fan", "lpc", "hpc", "hpt", "lpt")


@pytest.fixture(scope="module")
def fd001_schedule() -> EngineSchedule:
    # FD001 flies one condition (sea level static, TRA 100): a small grid around it.
    return build_schedule({"alt": (0.0, 2000.0), "mach": (0.0, 0.1), "power": (90.0, 100.0)})


@pytest.mark.skipif(not FD001.exists(), reason=f"no C-MAPSS file at {FD001}")
def test_hpc_carries_the_largest_deterioration_at_end_of_life(
    client: TestClient, session: Session, fd001_schedule: EngineSchedule,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(estimator, "builtin_schedule", lambda: fd001_schedule)
    operator = tenancy.create_operator(session, name=f"FD001 {uuid.uuid4().hex[:8]}")
    _row, key = tenancy.issue_api_key(session, operator=operator, role="analyst", name="fd")
    session.commit()
    client.headers["X-API-Key"] = key
    import_cmapss(FD001, client, units=UNITS)

    engine_type = session.scalar(
        select(EngineType).where(
            EngineType.operator_id == operator.id, EngineType.name == FD001_TRAIN.engine_type
        )
    )
    assert engine_type is not None
    model = fd001_schedule.model_at(0.0, 0.0, 100.0)
    row, _ = engine_models.register_builtin_model(
        session, operator_id=operator.id, engine_type_id=engine_type.id, name="FD001 point",
        model=model,
    )
    design = designs.create_design(
        session, operator_id=operator.id, engine_model_id=row.id, name="svd 7",
        spec={
            "format": "fleethealth.design-spec/1", "method": "svd", "tuners": 7,
            "sensors": list(CMAPSS_SENSORS), "health": list(model.health_names[:10]),
            "noise": {"Q": 1e-4, "Qh": 1e-4, "Ph": 4.0},
        },
    )
    designs.run_design(session, design, designs.design_step)
    designs.activate_design(session, operator_id=operator.id, design_id=design.id)
    summary = store.catch_up(session, operator.id)
    assert summary["engines"] == UNITS

    engines = session.scalars(select(Engine).where(Engine.operator_id == operator.id)).all()
    for engine in engines:
        trend = trends.engine_trend(session, operator.id, engine.id, max_points=0)
        health = next(g for g in trend["groups"] if g["key"] == "health")
        # Deterioration: end of life against early life (record 20, once the filter settled).
        change = {s["name"]: s["value"][-1] - s["value"][20] for s in health["series"]}
        per_module = {
            m: np.hypot(change[f"{m}_eff"], change[f"{m}_flow"]) for m in MODULES
        }
        assert max(per_module, key=per_module.get) == "hpc", (engine.esn, per_module)
        assert change["hpc_flow"] < 0 and change["hpc_eff"] < 0  # HPC loses, not gains
