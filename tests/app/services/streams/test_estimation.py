"""Stream estimation: the steady-state reduced-order filter over uploaded recordings.

A simulated flight (the design's own linear model with a tuner shift and sensor noise)
converges to the true tuners within the filter's 1-sigma, and its error spread matches the
Lyapunov theory; live chunks of any sizes give the rows of the whole file; a re-run and a
late earlier recording leave no duplicates; the schedule splits a climb into gain segments
the same way whatever the chunking; another operator gets 404.
"""

from __future__ import annotations

import io
from dataclasses import replace
from datetime import timedelta
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pytest
import scipy.linalg
from fastapi.testclient import TestClient
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.config import Settings
from app.models import Engine, EngineModel, EstimatorDesign, Job
from app.models.estimates import EstimateLayout
from app.models.stream_estimates import StreamEstimate, StreamFilterState
from app.services.snapshots import estimator
from app.services.streams import calibration as stream_calibration
from app.services.streams import estimator as stream_estimator
from app.services.streams import store as stream_store
from estimation import stream_filter, uncertainty
from estimation.design import design_to_dict
from estimation.engine.schedule import build_schedule
from estimation.model import LinearModel
from estimation.tuners import design_filter, svd_vstar
from tests.estimation.models import reference_model, reference_noise
from tests.support.fleet_fixture import SWAP_AT, Fleet, make_fleet

DT = 0.05  # 20 Hz
M_TUNERS = 4
CSV = {"Content-Type": "text/csv"}
START = SWAP_AT + timedelta(days=1)
Q_TRUE = np.array([1.5, -1.0, 0.8, -0.6])  # percent


def _model() -> LinearModel:
    return reference_model(dt=DT)


def _design_document(model: LinearModel) -> dict[str, Any]:
    noise = reference_noise(model)
    design = design_filter(model, svd_vstar(model, M_TUNERS), noise["Q"], noise["Qh"], noise["Ph"])
    return design_to_dict(design)


def _activate(session: Session, fleet: Fleet, model: LinearModel, document: dict[str, Any],
              source: str = "imported") -> EstimatorDesign:
    engine = session.get(Engine, fleet.engines["ESN-2"])
    assert engine is not None
    row = EngineModel(
        operator_id=fleet.operator_id, engine_type_id=engine.engine_type_id, name="ref",
        version=1, source=source, format="fleethealth.linear-model/1", content=model.to_dict(),
        checksum="0" * 64, dt=model.dt, n_states=model.n_states,
        sensor_names=model.sensor_names, health_names=model.health_names,
        aux_names=model.aux_names,
    )
    session.add(row)
    session.flush()
    design = EstimatorDesign(
        operator_id=fleet.operator_id, engine_type_id=engine.engine_type_id,
        engine_model_id=row.id, name="stream", spec={}, status="ready", active=True,
        result=document,
    )
    session.add(design)
    session.flush()
    return design


@pytest.fixture
def fleet_data(session: Session) -> Fleet:
    return make_fleet(session)


def _simulate(model: LinearModel, n: int, q_true: np.ndarray, seed: int) -> pa.Table:
    """A flight at one operating condition: plant = the linear model with h = V*^+ q_true
    (in the span of the tuners, so the reduced model is exact), actuator wiggles, noise."""
    rng = np.random.default_rng(seed)
    vstar = svd_vstar(model, M_TUNERS)
    h = np.linalg.lstsq(vstar, q_true, rcond=None)[0]  # minimum norm: V*^+ q_true
    t = np.arange(n) * DT
    u = np.column_stack([1.0 * np.sin(0.3 * t) + 0.5 * np.sin(0.11 * t + 1.0), np.zeros(n),
                         np.zeros(n)])  # Wf wiggles; VSV has no stored unit, VBV stays
    x = np.linalg.solve(np.eye(model.n_states) - model.A, model.L @ h)  # steady at start
    y = np.empty((n, model.n_sensors))
    for k in range(n):
        y[k] = model.C @ x + model.D @ u[k] + model.M @ h
        x = model.A @ x + model.B @ u[k] + model.L @ h
    y += rng.normal(size=y.shape) * model.sensor_noise_std
    gains = estimator.single_point_schedule(model)(np.zeros((1, 4)))
    y_stored = gains.y_trim[0] * (1.0 + y / 100.0)
    u_stored = gains.u_trim[0] * (1.0 + u / 100.0)
    columns: dict[str, Any] = {
        "time_s": t, "alt_ft": np.full(n, 35000.0), "mach": np.full(n, 0.8),
        "dtamb_k": np.zeros(n), "power_pct": np.full(n, 85.0),
    }
    columns.update({s.name: u_stored[:, i] for i, s in enumerate(model.inputs)
                    if np.isfinite(gains.u_trim[0, i])})  # an actuator with no stored unit: none
    columns.update({s.name: y_stored[:, i] for i, s in enumerate(model.sensors)})
    return pa.table(columns)


def _csv(table: pa.Table) -> bytes:
    sink = io.BytesIO()
    pacsv.write_csv(table, sink)
    return sink.getvalue()


def _upload_file(client: TestClient, fleet: Fleet, table: pa.Table, position: int,
                 start=START, tail: str = "N101") -> dict[str, Any]:
    response = client.post(
        "/api/v1/streams", content=_csv(table), headers={**fleet.analyst, **CSV},
        params={"tail": tail, "position": position, "started_at": start.isoformat()},
    )
    assert response.status_code == 201, response.text[:400]
    return response.json()["recording"]


def _estimate(session: Session, settings: Settings, fleet: Fleet, recording_id: int
              ) -> dict[str, Any]:
    return stream_store.estimate_recording(
        session, operator_id=fleet.operator_id, recording_id=recording_id,
        data_dir=settings.data_dir,
    )


def _rows(session: Session, recording_id: int) -> list[tuple[int, float, int, bytes]]:
    return [tuple(r) for r in session.execute(  # type: ignore[misc]
        select(StreamEstimate.window, StreamEstimate.t_s, StreamEstimate.n, StreamEstimate.packed)
        .where(StreamEstimate.recording_id == recording_id).order_by(StreamEstimate.window)
    ).all()]


def _state(session: Session, recording_id: int) -> StreamFilterState:
    row = session.scalar(
        select(StreamFilterState).where(StreamFilterState.recording_id == recording_id)
    )
    assert row is not None
    return row


def _lyapunov_tuner_std(model: LinearModel, document: dict[str, Any]) -> np.ndarray:
    """Steady-state error spread of q_hat with constant health and sensor noise only
    (docs/math.md section 3): P_hat = Phi P_hat Phi^T + K R K^T, Phi = A_xq - K C_xq A_xq, solved
    here by scipy's Lyapunov solver from the design document's gain."""
    K = np.asarray(document["gain"])
    vstar = np.asarray(document["vstar"])
    nx = model.n_states
    m = vstar.shape[0]
    Vp = np.linalg.pinv(vstar)
    n = nx + m
    A = np.zeros((n, n))
    A[:nx, :nx], A[:nx, nx:], A[nx:, nx:] = model.A, model.L @ Vp, np.eye(m)
    C = np.hstack([model.C, model.M @ Vp])
    Phi = A - K @ C @ A
    P = scipy.linalg.solve_discrete_lyapunov(Phi, K @ model.R @ K.T)
    return np.sqrt(np.diag(P)[nx:])


def test_a_flight_converges_to_the_true_tuner_shift_within_its_sigma(
    client: TestClient, session: Session, fleet_data: Fleet, settings: Settings
) -> None:
    model = _model()
    document = _design_document(model)
    design = _activate(session, fleet_data, model, document)
    n = 6000  # five minutes at 20 Hz
    recording = _upload_file(client, fleet_data, _simulate(model, n, Q_TRUE, seed=1), 2)
    summary = _estimate(session, settings, fleet_data, recording["id"])
    assert summary["samples"] == n and summary["design_id"] == design.id
    state = _state(session, recording["id"])
    layout = EstimateLayout.from_dict(state.layout)
    values = layout.unpack([r[3] for r in _rows(session, recording["id"])])
    sl = layout.slices()
    assert values.shape[0] == n * DT / stream_store.WINDOW_S
    q, q_sigma = values[:, sl["q"]], values[:, sl["q_sigma"]]
    tail = q[-120:]  # the last two minutes, long after the filter settled
    # Converged: the mean error is inside the filter's own 1-sigma, every tuner.
    assert np.all(np.abs(tail.mean(axis=0) - Q_TRUE) < q_sigma[-1])
    # The spread of the one-second means against the Lyapunov theory of the design's gain
    # (one-second means of a slowly correlated error keep most of its variance).
    theory = _lyapunov_tuner_std(model, document)
    spread = tail.std(axis=0)
    assert np.all(spread < 1.5 * theory) and np.all(spread > 0.3 * theory)
    # h_hat = V*^+ q_hat, and the 1-sigma is the steady-state covariance of the design gain.
    np.testing.assert_allclose(values[:, sl["h"]], q @ np.linalg.pinv(
        np.asarray(document["vstar"])).T, atol=1e-4)
    P = np.asarray(document["P_prior"])
    K, C = np.asarray(document["gain"]), np.hstack(
        [model.C, model.M @ np.linalg.pinv(np.asarray(document["vstar"]))])
    P_post = (np.eye(len(P)) - K @ C) @ P
    np.testing.assert_allclose(q_sigma[-1], np.sqrt(np.diag(P_post)[model.n_states:]),
                               rtol=1e-5)
    # Residuals are white noise around zero of the sensors' size.
    resid = values[:, sl["residual"]][-120:]
    assert np.all(np.abs(resid.mean(axis=0)) < 3 * model.sensor_noise_std / np.sqrt(20 * 120)
                  + 0.05)


def test_live_chunks_give_the_rows_of_the_whole_file(
    client: TestClient, session: Session, fleet_data: Fleet, settings: Settings
) -> None:
    model = _model()
    _activate(session, fleet_data, model, _design_document(model))
    n = 1500
    table = _simulate(model, n, Q_TRUE, seed=2)
    whole = _upload_file(client, fleet_data, table, 2)
    _estimate(session, settings, fleet_data, whole["id"])
    # The same samples live, on another engine, in chunks that split windows anywhere.
    opened = client.post("/api/v1/streams/live", headers=fleet_data.analyst, json={
        "tail": "N102", "position": 1, "started_at": START.isoformat(), "dt_s": DT})
    assert opened.status_code == 201, opened.text
    live_id = opened.json()["id"]
    sizes = [7, 30, 333, 19, 500, 2, 609]  # windows are 20 samples
    assert sum(sizes) == n
    at = 0
    for index, size in enumerate(sizes):
        response = client.post(f"/api/v1/streams/{live_id}/chunks", params={"index": index},
                               content=_csv(table.slice(at, size)),
                               headers={**fleet_data.analyst, **CSV})
        assert response.status_code == 201, response.text[:400]
        at += size
        _estimate(session, settings, fleet_data, live_id)
    a, b = _rows(session, whole["id"]), _rows(session, live_id)
    assert len(a) == len(b) == n // 20
    assert a == b  # bit for bit (float32 blobs, windows, times, counts)
    xa = np.asarray(_state(session, whole["id"]).state["x_end"])
    xb = np.asarray(_state(session, live_id).state["x_end"])
    np.testing.assert_allclose(xb, xa, rtol=0, atol=1e-12)
    # A re-run stores nothing new and changes nothing.
    _estimate(session, settings, fleet_data, live_id)
    st = _state(session, live_id)
    st.n_samples, st.restart_sample = 0, 0
    st.state = {**st.state, "x": st.state["x_initial"], "u_prev": [0.0] * 3, "anchor": None,
                "switches": 0}
    session.flush()
    _estimate(session, settings, fleet_data, live_id)
    assert _rows(session, live_id) == b


def test_a_late_earlier_flight_reruns_the_later_one_without_duplicates(
    client: TestClient, session: Session, fleet_data: Fleet, settings: Settings
) -> None:
    model = _model()
    _activate(session, fleet_data, model, _design_document(model))
    later = _upload_file(client, fleet_data, _simulate(model, 800, Q_TRUE, seed=3), 2)
    _estimate(session, settings, fleet_data, later["id"])
    alone = _rows(session, later["id"])
    # The earlier flight arrives late: the later one now starts from its tuners.
    earlier = _upload_file(client, fleet_data, _simulate(model, 2400, Q_TRUE, seed=4), 2,
                           start=START - timedelta(hours=6))
    summary = _estimate(session, settings, fleet_data, earlier["id"])
    assert summary["rerun_recordings"] == [later["id"]]
    after = _rows(session, later["id"])
    assert len(after) == len(alone) == 40 and after != alone
    end_earlier = np.asarray(_state(session, earlier["id"]).state["x_end"])
    initial_later = np.asarray(_state(session, later["id"]).state["x_initial"])
    np.testing.assert_array_equal(initial_later[model.n_states:], end_earlier[model.n_states:])
    count = session.scalar(select(func.count()).select_from(StreamEstimate).where(
        StreamEstimate.recording_id.in_([earlier["id"], later["id"]])))
    assert count == 40 + 120
    # Running both again changes nothing.
    assert _estimate(session, settings, fleet_data, earlier["id"])["rerun_recordings"] == []
    assert _rows(session, later["id"]) == after


def test_the_schedule_splits_a_climb_into_gain_segments_whatever_the_chunking(
    client: TestClient, session: Session, fleet_data: Fleet, settings: Settings,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    sched = build_schedule({"alt": (0.0, 40000.0), "mach": (0.2, 0.85), "power": (60.0, 100.0)})
    monkeypatch.setattr(estimator, "builtin_schedule", lambda: sched)
    model = sched.model_at(20000.0, 0.5, 80.0).select_health(sched.template.health_names[:10])
    noise = reference_noise(model)
    design = design_filter(model, svd_vstar(model, 6), noise["Q"], noise["Qh"], noise["Ph"])
    _activate(session, fleet_data, model, design_to_dict(design), source="builtin")
    n = 1200  # one minute at 20 Hz: climb 10,000 -> 14,000 ft, Mach 0.5 -> 0.56
    t = np.arange(n) * DT
    cond = np.column_stack([10000 + 4000 * t / t[-1], 0.5 + 0.06 * t / t[-1], np.zeros(n),
                            np.full(n, 90.0)])
    est_model = model
    trims = sched.trims_at(cond[:, [0, 1, 3, 2]])
    rng = np.random.default_rng(5)
    columns: dict[str, Any] = {"time_s": t, "alt_ft": cond[:, 0], "mach": cond[:, 1],
                               "dtamb_k": cond[:, 2], "power_pct": cond[:, 3]}
    for s in est_model.sensors:
        a, b = stream_estimator._stored_affine(s.name, s.unit)
        columns[s.name] = (a * trims[s.name] + b) * (1 + rng.normal(size=n) * 0.002)
    table = pa.table(columns)
    whole = _upload_file(client, fleet_data, table, 2)
    summary = _estimate(session, settings, fleet_data, whole["id"])
    # Altitude leaves its 1000 ft box every quarter of the climb, before Mach leaves its 0.02
    # box (every third): anchors near 10, 11, 12 and 13 thousand feet.
    assert summary["segments"] == 4
    # The samples sit on the scheduled trims (a healthy engine, 0.2 % noise): with trims
    # taken at each sample's condition the tuners stay within 3 sigma of zero.
    layout = EstimateLayout.from_dict(_state(session, whole["id"]).layout)
    last = layout.unpack([_rows(session, whole["id"])[-1][3]])[0]
    sl = layout.slices()
    assert np.all(np.abs(last[sl["q"]]) < 3 * last[sl["q_sigma"]])
    opened = client.post("/api/v1/streams/live", headers=fleet_data.analyst, json={
        "tail": "N102", "position": 1, "started_at": START.isoformat(), "dt_s": DT})
    live_id = opened.json()["id"]
    bounds = [0, 250, 251 + 13, 700, 1013, n]
    for index, (lo, hi) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
        response = client.post(f"/api/v1/streams/{live_id}/chunks", params={"index": index},
                               content=_csv(table.slice(lo, hi - lo)),
                               headers={**fleet_data.analyst, **CSV})
        assert response.status_code == 201, response.text[:400]
        _estimate(session, settings, fleet_data, live_id)
    assert _state(session, live_id).n_segments == summary["segments"]
    assert _rows(session, live_id) == _rows(session, whole["id"])
    np.testing.assert_allclose(np.asarray(_state(session, live_id).state["x_end"]),
                               np.asarray(_state(session, whole["id"]).state["x_end"]),
                               rtol=0, atol=1e-12)


def test_resampling_keeps_the_steady_state_gains() -> None:
    """A model at 15 ms resampled to 50 ms keeps G_y, G_z (closed form) and its poles move to
    lambda^(50/15) (zero-order hold of the same continuous system)."""
    fine = reference_model(dt=0.015)
    coarse = stream_filter.resample(fine, DT)
    for a, b in zip(fine.steady_state_gains(), coarse.steady_state_gains(), strict=True):
        np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(np.sort(np.linalg.eigvals(coarse.A).real),
                               np.sort(np.linalg.eigvals(fine.A).real ** (DT / 0.015)),
                               rtol=1e-9)
    # Against the independently built model at 50 ms (reference_model's own eigen-route).
    np.testing.assert_allclose(coarse.A, reference_model(dt=DT).A, rtol=1e-9, atol=1e-12)


def test_the_trend_endpoint_json_csv_viewer_and_tenants(
    client: TestClient, session: Session, fleet_data: Fleet, settings: Settings
) -> None:
    model = _model()
    _activate(session, fleet_data, model, _design_document(model))
    recording = _upload_file(client, fleet_data, _simulate(model, 1000, Q_TRUE, seed=6), 2)
    # The upload queued the estimation job for the recording.
    job = session.scalar(select(Job).where(Job.operator_id == fleet_data.operator_id,
                                           Job.kind == "estimate_recording"))
    assert job is not None and job.parameters["recording_id"] == recording["id"]
    _estimate(session, settings, fleet_data, recording["id"])
    url = f"/api/v1/streams/{recording['id']}/estimates"
    got = client.get(url, headers=fleet_data.viewer)
    assert got.status_code == 200, got.text
    body = got.json()
    assert body["n_samples_estimated"] == 1000 and len(body["t_s"]) == 50
    rows = _rows(session, recording["id"])
    layout = EstimateLayout.from_dict(_state(session, recording["id"]).layout)
    values = layout.unpack([r[3] for r in rows])
    np.testing.assert_allclose(body["q_hat"]["q1"], values[:, layout.slices()["q"]][:, 0])
    assert set(body["residual"]) == set(model.sensor_names)
    small = client.get(url, params={"max_points": 10}, headers=fleet_data.viewer).json()
    assert len(small["t_s"]) == 10 and small["window_s"] == pytest.approx(5.0)
    np.testing.assert_allclose(small["q_hat"]["q1"][0], np.mean(body["q_hat"]["q1"][:5]))
    csv = client.get(url, params={"format": "csv"}, headers=fleet_data.viewer)
    assert csv.status_code == 200 and csv.headers["content-type"].startswith("text/csv")
    back = pacsv.read_csv(io.BytesIO(csv.content))
    np.testing.assert_allclose(back["q_hat.q1"].to_numpy(), body["q_hat"]["q1"])
    assert client.get(url, headers=fleet_data.other).status_code == 404
    other_design = client.get(url, params={"design_id": 999_999}, headers=fleet_data.viewer)
    assert other_design.status_code == 404
    # Before any estimate: an empty series, not an error.
    fresh = _upload_file(client, fleet_data, _simulate(model, 100, Q_TRUE, seed=7), 1)
    empty = client.get(f"/api/v1/streams/{fresh['id']}/estimates", headers=fleet_data.viewer)
    assert empty.status_code == 200 and empty.json()["t_s"] == []
    assert client.get("/api/v1/streams/999999/estimates", headers=fleet_data.viewer
                      ).status_code == 404


def test_job_kind_is_registered_and_internal() -> None:
    from app.jobs.kinds import load_kinds
    from app.services.jobs.registry import registry

    load_kinds()
    kind = registry.get("estimate_recording")
    assert kind.submittable is False
    assert kind.validate({"recording_id": 3}).model_dump() == {"recording_id": 3,
                                                              "through_sample": 0}
    with pytest.raises(Exception, match="recording_id"):
        kind.validate({})



def test_samples_missing_a_sensor_are_predicted_not_measured(
    client: TestClient, session: Session, fleet_data: Fleet, settings: Settings
) -> None:
    model = _model()
    _activate(session, fleet_data, model, _design_document(model))
    n = 2000
    table = _simulate(model, n, Q_TRUE, seed=8)
    gap = slice(600, 660)  # three seconds without T30 (null cells)
    t30 = table["T30"].to_numpy().copy()
    values = [None if gap.start <= k < gap.stop else float(v) for k, v in enumerate(t30)]
    holed = table.set_column(table.schema.get_field_index("T30"), "T30",
                             pa.array(values, pa.float64()))
    full = _upload_file(client, fleet_data, table, 2)
    gapped = _upload_file(client, fleet_data, holed, 1, tail="N102")  # another engine
    for rec in (full, gapped):
        _estimate(session, settings, fleet_data, rec["id"])
    layout = EstimateLayout.from_dict(_state(session, gapped["id"]).layout)
    sl = layout.slices()
    a = layout.unpack([r[3] for r in _rows(session, full["id"])])
    b = layout.unpack([r[3] for r in _rows(session, gapped["id"])])
    assert np.all(np.isfinite(b[:, sl["q"]]))
    # Before the gap the two runs agree exactly; the gap's windows have no T30 residual.
    np.testing.assert_array_equal(b[:30], a[:30])
    t30_col = sl["residual"].start + layout.sensors.index("T30")
    assert np.all(np.isnan(b[30:33, t30_col])) and np.all(np.isfinite(b[33:, t30_col]))
    # The missing three seconds leave the tuners within their 1-sigma of the full run's.
    gap_q = b[-1, sl["q"]]
    assert np.all(np.abs(gap_q - a[-1, sl["q"]]) < a[-1, sl["q_sigma"]])
    body = client.get(f"/api/v1/streams/{gapped['id']}/estimates", headers=fleet_data.viewer)
    assert body.status_code == 200 and body.json()["residual"]["T30"][30] is None


def test_uploads_and_live_chunks_queue_jobs_that_estimate_the_recording(
    client: TestClient, session: Session, fleet_data: Fleet, settings: Settings,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from app.services.jobs.registry import registry

    model = _model()
    _activate(session, fleet_data, model, _design_document(model))
    table = _simulate(model, 400, Q_TRUE, seed=9)
    opened = client.post("/api/v1/streams/live", headers=fleet_data.analyst, json={
        "tail": "N102", "position": 1, "started_at": START.isoformat(), "dt_s": DT})
    live_id = opened.json()["id"]
    for index, (lo, size) in enumerate([(0, 150), (150, 250)]):
        response = client.post(f"/api/v1/streams/{live_id}/chunks", params={"index": index},
                               content=_csv(table.slice(lo, size)),
                               headers={**fleet_data.analyst, **CSV})
        assert response.status_code == 201
    # A resent chunk queues nothing more.
    again = client.post(f"/api/v1/streams/{live_id}/chunks", params={"index": 1},
                        content=_csv(table.slice(150, 250)), headers={**fleet_data.analyst, **CSV})
    assert again.status_code == 200
    jobs = session.scalars(select(Job).where(Job.operator_id == fleet_data.operator_id,
                                             Job.kind == "estimate_recording")
                           .order_by(Job.id)).all()
    assert [j.parameters for j in jobs] == [
        {"recording_id": live_id, "through_sample": 150},
        {"recording_id": live_id, "through_sample": 400},
    ]
    # The job function, as a runner calls it, with the service's data directory.
    monkeypatch.setattr("app.config.get_settings", lambda: settings)
    kind = registry.get("estimate_recording")
    seen: list[float] = []
    result = kind.function(session, kind.validate(jobs[0].parameters),
                           lambda fraction, message=None: seen.append(fraction),
                           operator_id=fleet_data.operator_id)
    assert result["samples"] == 400 and seen[-1] == 1.0
    # The second job finds nothing left to do.
    assert kind.function(session, kind.validate(jobs[1].parameters), lambda *a: None,
                         operator_id=fleet_data.operator_id)["samples"] == 0
    assert len(_rows(session, live_id)) == 20


def test_the_recording_estimates_carry_the_designs_stream_calibration(
    client: TestClient, session: Session, fleet_data: Fleet, settings: Settings
) -> None:
    """Without a stream calibration the estimates say their band is the filter's own; with
    one (``streams.calibration``), they are the calibrated level and tuners with the honest
    1-sigma, the unobservable ones null and named; a recording lacking a sensor the
    calibration used keeps the filter's own, and says why."""
    model = _model()
    document = _design_document(model)
    design = _activate(session, fleet_data, model, document)
    recording = _upload_file(client, fleet_data, _simulate(model, 400, Q_TRUE, seed=3), 2)
    _estimate(session, settings, fleet_data, recording["id"])
    url = f"/api/v1/streams/{recording['id']}/estimates"
    query = {"max_points": 100_000}
    before = client.get(url, params=query, headers=fleet_data.analyst).json()
    assert before["uncertainty"] == "uncalibrated"
    assert before["unobservable"] == [] and before["tuners_unobservable"] == []
    names, tuners = tuple(before["names"]["health"]), tuple(before["names"]["tuners"])
    p, m = len(names), len(tuners)
    C = np.zeros((p, uncertainty.correction_width(p)))
    C[:, 0] = 0.1 * np.arange(1, p + 1)  # a constant offset per parameter
    V = np.asarray(document["vstar"])
    calib = uncertainty.Calibration(
        names=names, level_std=np.full(p, 0.3), change_std=np.zeros(p),
        slope_error=np.zeros(p), bias2=np.zeros(p), drift=np.zeros(p),
        observable=np.arange(p) < p - 1, level_correction=C, tuner_names=tuners,
        tuner_std=np.full(m, 0.2), tuner_correction=V @ C, tuner_observable=np.arange(m) < m - 1,
        source={"sensors": list(model.sensor_names)})
    stream_calibration.store_calibration(session, design, calib)
    after = client.get(url, params=query, headers=fleet_data.analyst).json()
    assert after["uncertainty"] == "calibrated"
    assert after["unobservable"] == [names[-1]] and after["tuners_unobservable"] == [tuners[-1]]

    def column(body: dict[str, Any], key: str, name: str) -> np.ndarray:
        return np.array([np.nan if v is None else v for v in body[key][name]], float)

    for k, name in enumerate(names[:-1]):
        np.testing.assert_allclose(column(after, "h_hat", name),
                                   column(before, "h_hat", name) - C[k, 0], atol=1e-9)
        np.testing.assert_allclose(column(after, "h_sigma", name),
                                   np.hypot(column(before, "h_sigma", name), 0.3), atol=1e-9)
    for k, name in enumerate(tuners[:-1]):
        np.testing.assert_allclose(column(after, "q_hat", name),
                                   column(before, "q_hat", name) - (V @ C)[k, 0], atol=1e-9)
        np.testing.assert_allclose(column(after, "q_sigma", name),
                                   np.hypot(column(before, "q_sigma", name), 0.2), atol=1e-9)
    assert np.isnan(column(after, "h_hat", names[-1])).all()
    assert np.isnan(column(after, "q_sigma", tuners[-1])).all()
    # Calibrated with a sensor this recording lacks: the filter's own sigma, said so.
    stream_calibration.store_calibration(session, design, replace(
        calib, source={"sensors": [*model.sensor_names, "T25"]}))
    other = client.get(url, params=query, headers=fleet_data.analyst).json()
    assert other["uncertainty"] == "sensors" and other["unobservable"] == []
    assert other["h_hat"] == before["h_hat"] and other["q_sigma"] == before["q_sigma"]
