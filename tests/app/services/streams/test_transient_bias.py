"""Transient bias compensation of a design (docs/math.md section 7) through the service: the
fit on a design's recordings (job and command line), stored with the design, applied by stream
estimation; the API's bad input and tenants."""

from __future__ import annotations

from typing import Any

import numpy as np
import pyarrow as pa
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.config import Settings
from app.models import Job
from app.models.estimates import EstimateLayout
from app.services.snapshots import estimator
from app.services.streams import bias
from estimation.bias import BIAS_FORMAT
from estimation.model import LinearModel
from estimation.tuners import svd_vstar
from tests.app.services.streams.test_estimation import (
    DT,
    M_TUNERS,
    Q_TRUE,
    _activate,
    _design_document,
    _estimate,
    _model,
    _rows,
    _state,
    _upload_file,
)
from tests.support.fleet_fixture import Fleet, make_fleet

MISMATCH = 150.0  # percent of sensor per (1/s) of transient index: the plant's transient bias


@pytest.fixture
def fleet_data(session: Session) -> Fleet:
    return make_fleet(session)


def _flight(model: LinearModel, n: int, q_true: np.ndarray, seed: int) -> pa.Table:
    """The linear model with fuel-flow steps (transients) and a sensor bias proportional to
    the true transient index, mean relative state rate (seed 004 eq. 8): a model-plant
    mismatch the design's model does not have."""
    rng = np.random.default_rng(seed)
    h = np.linalg.lstsq(svd_vstar(model, M_TUNERS), q_true, rcond=None)[0]
    t = np.arange(n) * DT
    u = np.zeros((n, model.n_inputs))
    u[:, 0] = 3.0 * np.sign(np.sin(2 * np.pi * t / 20.0))  # Wf steps every 10 s
    x = np.linalg.solve(np.eye(model.n_states) - model.A, model.L @ h + model.B @ u[0])
    y = np.empty((n, model.n_sensors))
    x_prev = x
    for k in range(n):
        ti = np.mean(x - x_prev) / 100.0 / DT
        y[k] = model.C @ x + model.D @ u[k] + model.M @ h + MISMATCH * ti
        x_prev, x = x, model.A @ x + model.B @ u[k] + model.L @ h
    y += rng.normal(size=y.shape) * model.sensor_noise_std
    g = estimator.single_point_schedule(model)(np.zeros((1, 4)))
    columns: dict[str, Any] = {
        "time_s": t, "alt_ft": np.full(n, 35000.0), "mach": np.full(n, 0.8),
        "dtamb_k": np.zeros(n), "power_pct": np.full(n, 85.0),
    }
    columns.update({s.name: g.u_trim[0, i] * (1.0 + u[:, i] / 100.0)
                    for i, s in enumerate(model.inputs) if np.isfinite(g.u_trim[0, i])})
    columns.update({s.name: g.y_trim[0, i] * (1.0 + y[:, i] / 100.0)
                    for i, s in enumerate(model.sensors)})
    return pa.table(columns)


def _tuners(session: Session, recording_id: int) -> np.ndarray:
    layout = EstimateLayout.from_dict(_state(session, recording_id).layout)
    values = layout.unpack([r[3] for r in _rows(session, recording_id)])
    return values[:, layout.slices()["q"]]


def test_the_fit_job_stores_a_model_that_stream_estimation_applies(
    client: TestClient, session: Session, fleet_data: Fleet, settings: Settings,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from app.jobs.kinds import load_kinds
    from app.services.jobs.registry import registry

    model = _model()
    design = _activate(session, fleet_data, model, _design_document(model))
    healthy = _upload_file(client, fleet_data, _flight(model, 2400, np.zeros(M_TUNERS), 1), 2)
    before = _upload_file(client, fleet_data, _flight(model, 2400, Q_TRUE, 2), 1, tail="N102")
    after = _upload_file(client, fleet_data, _flight(model, 2400, Q_TRUE, 2), 2, tail="N102")
    _estimate(session, settings, fleet_data, before["id"])  # no bias model yet
    none_yet = client.get(f"/api/v1/designs/{design.id}/transient-bias",
                          headers=fleet_data.viewer)
    assert none_yet.status_code == 200 and none_yet.json()["model"] is None

    response = client.post(f"/api/v1/designs/{design.id}/transient-bias",
                           headers=fleet_data.analyst,
                           json={"recording_ids": [healthy["id"]], "ti_star": 1e-4})
    assert response.status_code == 202, response.text
    job = session.scalar(select(Job).where(Job.id == response.json()["id"]))
    assert job is not None and job.kind == bias.JOB_KIND
    load_kinds()
    monkeypatch.setattr("app.config.get_settings", lambda: settings)
    kind = registry.get(bias.JOB_KIND)
    seen: list[float] = []
    out = kind.function(session, kind.validate(job.parameters),
                        lambda fraction, message=None: seen.append(fraction),
                        operator_id=fleet_data.operator_id)
    assert seen[-1] == 1.0 and out["accelerating_samples"] > 100
    stored = client.get(f"/api/v1/designs/{design.id}/transient-bias", headers=fleet_data.viewer)
    assert stored.status_code == 200 and stored.json()["model"]["format"] == BIAS_FORMAT
    # The plant's bias is MISMATCH * TI on every sensor; the filter sees the index of its own
    # (low-passed) state estimate, so the learnt slope is of that order, not equal (measured
    # 1.2-1.7 x MISMATCH).
    up = np.asarray(stored.json()["model"]["accelerating"]["coeffs"])
    assert np.all((up[1] > 0.5 * MISMATCH) & (up[1] < 2.0 * MISMATCH))

    _estimate(session, settings, fleet_data, after["id"])
    q_off, q_on = _tuners(session, before["id"]), _tuners(session, after["id"])
    err_off = np.sqrt(np.mean((q_off[-60:] - Q_TRUE) ** 2))
    err_on = np.sqrt(np.mean((q_on[-60:] - Q_TRUE) ** 2))
    assert err_on < 0.5 * err_off, (err_on, err_off)


def test_the_api_rejects_bad_input_and_hides_other_operators_designs(
    client: TestClient, session: Session, fleet_data: Fleet,
) -> None:
    model = _model()
    design = _activate(session, fleet_data, model, _design_document(model))
    rec = _upload_file(client, fleet_data, _flight(model, 200, np.zeros(M_TUNERS), 3), 2)
    url = f"/api/v1/designs/{design.id}/transient-bias"
    for body in ({"recording_ids": []}, {"recording_ids": [rec["id"]], "ti_star": -1},
                 {"recording_ids": [rec["id"]], "extra": 1}, {}):
        assert client.post(url, headers=fleet_data.analyst, json=body).status_code == 422
    missing = client.post(url, headers=fleet_data.analyst, json={"recording_ids": [10**9]})
    assert missing.status_code == 422 and "recording_ids[0]" in missing.text
    assert client.post(url, headers=fleet_data.viewer,
                       json={"recording_ids": [rec["id"]]}).status_code == 403
    assert client.post(url, headers=fleet_data.other,
                       json={"recording_ids": [rec["id"]]}).status_code == 404
    assert client.get(url, headers=fleet_data.other).status_code == 404
    assert client.post("/api/v1/designs/999999999/transient-bias", headers=fleet_data.analyst,
                       json={"recording_ids": [rec["id"]]}).status_code == 404


def test_the_command_line_fits_and_stores_for_the_designs_operator(
    client: TestClient, session: Session, fleet_data: Fleet, settings: Settings,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import contextlib
    import json

    from typer.testing import CliRunner

    from app.cli import app as cli_app
    from app.models import EstimatorDesign

    model = _model()
    design = _activate(session, fleet_data, model, _design_document(model))
    rec = _upload_file(client, fleet_data, _flight(model, 1200, np.zeros(M_TUNERS), 4), 2)

    @contextlib.contextmanager
    def in_test_session(*_a: Any, **_k: Any):  # the command's unit of work, in this test's
        yield session

    monkeypatch.setattr("app.cli.bias.get_settings", lambda: settings)
    monkeypatch.setattr("app.db.make_engine", lambda *_a, **_k: None)
    monkeypatch.setattr("app.db.make_sessionmaker", lambda *_a, **_k: None)
    monkeypatch.setattr("app.db.transaction", in_test_session)
    runner = CliRunner()
    ok = runner.invoke(cli_app, ["fit-bias", str(design.id), str(rec["id"]), "--ti-star", "1e-4"])
    assert ok.exit_code == 0, ok.output
    assert json.loads(ok.stdout.strip().splitlines()[-1])["design_id"] == design.id
    row = session.get(EstimatorDesign, design.id)
    assert row is not None and row.result is not None
    assert row.result[bias.BIAS_KEY]["format"] == BIAS_FORMAT
    bad = runner.invoke(cli_app, ["fit-bias", str(design.id), "999999999"])
    assert bad.exit_code != 0 and "recording_ids[0]" in bad.output
