"""Stream recordings under a design that chooses the constant-gain EKF (``stream_filter``
``"cgekf"``, seed 001) on the built-in engine.

A simulated flight of the nonlinear engine with an HPC fault in the span of the tuners gives
finite estimates that settle near the true health shift; a live upload in chunks that split
windows anywhere stores the rows of the whole-flight upload bit for bit; the option is
validated in the design spec and refused on a design that is not on the built-in engine.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pyarrow as pa
import pytest
from fastapi.testclient import TestClient
from sqlalchemy.orm import Session

from app.config import Settings
from app.models import EstimatorDesign
from app.models.estimates import EstimateLayout
from app.services.snapshots import estimator
from app.services.streams import estimator as stream_estimator
from estimation.cgekf import AUX_ESTIMATED, SEED001_SENSORS, SEED001_TUNERS
from estimation.design import DesignSpecError, design_to_dict, parse_spec
from estimation.engine.flight import FlightProfile
from estimation.engine.health import HEALTH_NAMES, N_HEALTH
from estimation.engine.linearize import linearize
from estimation.engine.schedule import build_schedule
from estimation.engine.sensors import SENSOR_NAMES, noise_std
from estimation.engine.transient import simulate
from estimation.model import LinearModel
from estimation.tuners import design_filter
from tests.app.services.streams.test_estimation import (
    CSV,
    START,
    _activate,
    _csv,
    _estimate,
    _rows,
    _state,
    _upload_file,
    fleet_data,  # noqa: F401  (fixture)
)
from tests.support.fleet_fixture import Fleet

DT = 0.05
HPC = {"hpc_eff": -2.0, "hpc_flow": -2.0}  # seed 002's HPC fault, in the tuners' span


@pytest.fixture
def small_schedule(monkeypatch: pytest.MonkeyPatch) -> None:
    """A schedule around the ground run of the flights below (the trims of the aux outputs
    and of commands a recording lacks), instead of the whole envelope's."""
    sched = build_schedule({"alt": (0.0, 2000.0), "mach": (0.0, 0.2), "power": (40.0, 100.0)})
    monkeypatch.setattr(estimator, "builtin_schedule", lambda: sched)


def _model() -> LinearModel:
    return (linearize(0.0, 0.0, 100.0, dt=DT).select_sensors(list(SEED001_SENSORS))
            .select_health(list(HEALTH_NAMES[:10])).select_aux(list(AUX_ESTIMATED)))


def _document(model: LinearModel, stream_filter: str = "cgekf") -> dict[str, Any]:
    vstar = np.zeros((len(SEED001_TUNERS), 10))
    vstar[np.arange(len(SEED001_TUNERS)), [HEALTH_NAMES.index(t) for t in SEED001_TUNERS]] = 1
    nx, p = model.n_states, model.n_health
    design = design_filter(model, vstar, 0.05**2 * np.eye(nx), 0.005**2 * np.eye(p),
                           4.0 * np.eye(p))
    return {**design_to_dict(design), "stream_filter": stream_filter}


def _flight(seconds: float, health: dict[str, float], seed: int) -> pa.Table:
    """Idle, a slam to take-off at 20 s, then take-off power with Mach rising to 0.1: the
    nonlinear engine in closed loop with seed 001's sensor noise."""
    h = np.zeros(N_HEALTH)
    for name, value in health.items():
        h[HEALTH_NAMES.index(name)] = value
    prof = FlightProfile(np.array([0.0, 20.0, 26.0, seconds]), np.zeros((1, 4)),
                         np.array([[0.0, 0.0, 0.0, 0.1]]), np.array([[40.0, 40.0, 100.0, 100.0]]),
                         np.zeros(1))
    ty = np.array([linearize(0.0, 0.0, 100.0, dt=DT).trim[s] for s in SENSOR_NAMES])
    sim = simulate(prof, seconds, health=h, dt=DT, noise_std=noise_std(ty),
                   rng=np.random.default_rng(seed))
    c = sim.condition
    columns: dict[str, Any] = {"time_s": sim.time_s, "alt_ft": c.alt_ft[:, 0],
                               "mach": c.mach[:, 0], "dtamb_k": c.dtamb_k[:, 0],
                               "power_pct": c.power_pct[:, 0]}
    columns.update({n: sim.u[:, 0, i] for i, n in enumerate(("Wf", "VSV", "VBV"))})
    columns.update({n: sim.measured[:, 0, SENSOR_NAMES.index(n)] for n in SEED001_SENSORS})
    return pa.table(columns).slice(0, round(seconds / DT))  # whole windows


def test_a_cgekf_design_estimates_a_flight_near_the_simulated_truth(
    client: TestClient, session: Session, fleet_data: Fleet,  # noqa: F811
    settings: Settings, small_schedule: None,
) -> None:
    model = _model()
    design = _activate(session, fleet_data, model, _document(model), source="builtin")
    table = _flight(100.0, HPC, seed=11)
    recording = _upload_file(client, fleet_data, table, 2)
    summary = _estimate(session, settings, fleet_data, recording["id"])
    assert summary["design_id"] == design.id and summary["samples"] == table.num_rows
    layout = EstimateLayout.from_dict(_state(session, recording["id"]).layout)
    values = layout.unpack([r[3] for r in _rows(session, recording["id"])])
    sl = layout.slices()
    assert values.shape[0] == table.num_rows // 20 and np.isfinite(values).all()
    h = values[:, sl["h"]]
    truth = np.array([HPC.get(n, 0.0) for n in layout.health])
    # The last ten seconds at take-off power: the HPC shift found, the rest near zero
    # (seed 001's filter on its own engine; 0.5 % is a quarter of the fault).
    late = h[-10:].mean(axis=0)
    tuned = [layout.health.index(t) for t in SEED001_TUNERS]
    np.testing.assert_allclose(late[tuned], truth[tuned], atol=0.5)
    # At the start the filter knew no fault: the HPC estimate has moved toward it since.
    hpc = [layout.health.index(n) for n in HPC]
    assert np.all(np.abs(h[0, hpc] - truth[hpc]) > np.abs(late[hpc] - truth[hpc]))
    # The innovations at the end are of the sensors' noise size (percent of trim).
    assert np.abs(values[-10:, sl["residual"]].mean(axis=0)).max() < 0.5
    # Under the same design with the scheduled linear filter the rows differ (the design
    # chose the filter).
    linear = EstimatorDesign(
        operator_id=design.operator_id, engine_type_id=design.engine_type_id,
        engine_model_id=design.engine_model_id, name="linear", spec={}, status="ready",
        active=False, result=_document(model, "scheduled_linear"))
    session.add(linear)
    session.flush()
    other = stream_estimator.estimator_for(session, linear, recording["signals"])
    assert other.stream_filter == "scheduled_linear"
    assert stream_estimator.estimator_for(session, design, recording["signals"]).stream_filter == \
        "cgekf"


def test_a_live_chunked_cgekf_upload_equals_the_whole_flight(
    client: TestClient, session: Session, fleet_data: Fleet,  # noqa: F811
    settings: Settings, small_schedule: None,
) -> None:
    model = _model()
    _activate(session, fleet_data, model, _document(model), source="builtin")
    table = _flight(30.0, HPC, seed=12)
    n = table.num_rows
    whole = _upload_file(client, fleet_data, table, 2)
    _estimate(session, settings, fleet_data, whole["id"])
    opened = client.post("/api/v1/streams/live", headers=fleet_data.analyst, json={
        "tail": "N102", "position": 1, "started_at": START.isoformat(), "dt_s": DT})
    assert opened.status_code == 201, opened.text
    live_id = opened.json()["id"]
    bounds = [0, 7, 37, 370, 389, 411, n]  # windows are 20 samples: split anywhere
    for index, (lo, hi) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
        response = client.post(f"/api/v1/streams/{live_id}/chunks", params={"index": index},
                               content=_csv(table.slice(lo, hi - lo)),
                               headers={**fleet_data.analyst, **CSV})
        assert response.status_code == 201, response.text[:400]
        _estimate(session, settings, fleet_data, live_id)
    a, b = _rows(session, whole["id"]), _rows(session, live_id)
    # The restarts carry the engine model's whole state (gas-path unknowns, chord Jacobian,
    # its refresh cycle): bit for bit (float32 blobs, windows, times, counts), though the
    # whole file's interval comes from its time stamps and the live one's is declared.
    assert len(a) == n // 20 and a == b
    np.testing.assert_array_equal(np.asarray(_state(session, live_id).state["x_end"]),
                                  np.asarray(_state(session, whole["id"]).state["x_end"]))
    # The kept engine state counted every sample through the restarts (the Jacobian refresh
    # every 200 samples fell inside chunks 3 and 6, after restarts at 20 and 400).
    plant = _state(session, live_id).state["plant"]
    assert plant["calls"] == n and np.shape(plant["jinv"]) == (1, 5, 5)


def test_the_stream_filter_option_is_validated_and_needs_the_builtin_engine(
    client: TestClient, session: Session, fleet_data: Fleet,  # noqa: F811
    settings: Settings, small_schedule: None,
) -> None:
    model = _model()
    spec = {"format": "fleethealth.design-spec/1", "tuners": 2,
            "noise": {"Qh": [0.1] * 10, "Ph": [2.0] * 10}}
    assert parse_spec(spec, model)["stream_filter"] == "scheduled_linear"
    assert parse_spec({**spec, "stream_filter": "cgekf"}, model)["stream_filter"] == "cgekf"
    with pytest.raises(DesignSpecError, match="stream_filter"):
        parse_spec({**spec, "stream_filter": "ekf"}, model)
    # An imported model cannot run the built-in engine's filter: the job says why.
    design = _activate(session, fleet_data, model, _document(model))
    recording = _upload_file(client, fleet_data, _flight(2.0, {}, seed=13), 2)
    with pytest.raises(stream_estimator.StreamEstimationError, match="built-in engine"):
        stream_estimator.estimator_for(session, design, recording["signals"])
