"""Stream recordings of an engine whose type has signals of its own, on both databases.

The made-up two-spool engine of ``tests.support.custom_type`` (sensors N1, N2, EGT [degC],
PS3, FF_meas, inputs FF and IGV, health fan_loss ... hpt_area) is defined through the API with
an active design; a whole-flight CSV of it, simulated from its model file's dynamics with a
known health shift half-way and EGT sent in degF, is stored in the type's names and the model
file's units, estimated by the stream filter against the model's own trims, and its estimates
track the health before and after the shift, served in the type's names. Its steady windows
become the engine's records with the type's signals. A column the type does not have, or a
unit its signal does not take, refuses the file or the live chunk naming the column and the
type, and stores nothing.

The type's model is at one operating point, so its recordings need no operating condition: a
whole-flight file (CSV or Parquet) and a live recording carrying only ``time_s``, the inputs
and the sensors are stored, estimated to the same health, and their steady windows (found on
the inputs held and the sensors settled) become records without a phase or a condition.
"""

from __future__ import annotations

import csv
import io
from datetime import datetime, timedelta
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from app.config import Settings
from app.jobs.runner import run_pending
from app.models.stream_estimates import StreamFilterState
from app.signals import CONDITION_COLUMNS
from tests.support import custom_type as own

TYPE = "'Made-up 2-spool'"
N = 3000  # 60 s at the model's 50 Hz
SHIFT_AT = N // 2
STARTED = own.T0 + timedelta(days=2)


@pytest.fixture
def custom(client: TestClient, session: Session) -> tuple[own.CustomFleet, dict[str, str]]:
    _operator, key = own.make_operator(session)
    headers = {"X-API-Key": key}

    post = own.poster(client.post, headers)

    return own.setup(post, lambda _body: None, n=0), headers


def health() -> np.ndarray:
    """Nominal, then the engine's health TRUTH from sample SHIFT_AT on."""
    h = np.zeros((N, len(own.HEALTH)))
    h[SHIFT_AT:] = own.TRUTH
    return h


def csv_text(header: list[str], values: np.ndarray) -> bytes:
    sink = io.StringIO()
    writer = csv.writer(sink)
    writer.writerow(header)
    writer.writerows([f"{v:.6g}" for v in row] for row in values)
    return sink.getvalue().encode()


def meta(started: Any = STARTED) -> dict[str, Any]:
    return {"tail": "N700", "position": 1, "started_at": own.utc(started)}


def without_condition(header: list[str], values: np.ndarray) -> tuple[list[str], np.ndarray]:
    """The recording without its operating-condition columns."""
    keep = [j for j, name in enumerate(header) if name not in CONDITION_COLUMNS]
    return [header[j] for j in keep], values[:, keep]


def assert_tracks_the_shift(body: dict[str, Any]) -> None:
    """The stream estimates of a recording of ``health()``: nominal, then TRUTH, each within
    three of the filter's 1-sigma and the settled mean within half of it."""
    assert body["names"]["health"] == list(own.HEALTH)
    assert body["names"]["sensors"] == ["N1", "N2", "EGT", "PS3"]
    assert body["n_samples_estimated"] == N
    t = np.array(body["t_s"])
    shift_s = SHIFT_AT * 0.02
    before = (t >= 10.0) & (t < shift_s - 1.0)  # settled from the nominal start
    after = t >= shift_s + 10.0  # settled after the shift
    for j, name in enumerate(own.HEALTH):
        h = np.array(body["h_hat"][name], float)
        sigma = np.array(body["h_sigma"][name], float)
        assert np.all(np.isfinite(h)) and np.all(sigma > 0), name
        # Window means within three of the filter's per-sample 1-sigma of the truth.
        assert np.all(np.abs(h[before]) <= 3.0 * sigma[before]), (name, h[before])
        error = h[after] - own.TRUTH[j]
        assert np.all(np.abs(error) <= 3.0 * sigma[after]), (name, error, sigma[after])
        # The shift is seen, with its sign and size: the settled mean within half a sigma.
        spread = float(sigma[after].mean())
        assert abs(float(error.mean())) <= 0.5 * spread, (name, error.mean(), spread)
        step = h[after].mean() - h[before].mean()
        assert step == pytest.approx(own.TRUTH[j], abs=spread), name
    residual = np.array(body["residual"]["EGT"], float)
    assert abs(float(residual[after].mean())) < 3.0 * own.NOISE_STD[2]


def test_a_custom_type_stream_is_stored_in_its_units_and_tracks_a_known_health(
    client: TestClient, custom: tuple[own.CustomFleet, dict[str, str]], session: Session,
    session_factory: sessionmaker[Session], settings: Settings, monkeypatch: pytest.MonkeyPatch,
) -> None:
    fleet, headers = custom
    # The queued jobs run here read the service's data directory, as a job runner does.
    monkeypatch.setattr("app.config.get_settings", lambda: settings)
    header, values = own.samples(N, health())
    response = client.post("/api/v1/streams", params=meta(), content=csv_text(header, values),
                           headers={**headers, "Content-Type": "text/csv"})
    assert response.status_code == 201, response.text
    recording = response.json()["recording"]
    assert recording["engine_id"] == fleet.engine_id and recording["n_samples"] == N
    assert {"N1", "N2", "EGT", "PS3", "FF_meas", "FF", "IGV"} <= set(recording["signals"])

    # Stored in the model file's units: EGT sent in degF is kept in degC.
    stored = client.get(f"/api/v1/streams/{recording['id']}/samples", headers=headers)
    assert stored.status_code == 200
    rows = list(csv.DictReader(io.StringIO(stored.text)))
    egt_f = values[:, header.index("EGT[degF]")]
    egt = np.array([float(r["EGT"]) for r in rows])
    np.testing.assert_allclose(egt, (egt_f - 32.0) / 1.8, rtol=1e-5)
    assert abs(float(np.mean(egt[:SHIFT_AT])) - own.TRIM["EGT"]) < 2.0  # degC, not degF
    assert float(rows[0]["N1"]) == pytest.approx(values[0, header.index("N1[%]")], rel=1e-5)

    run_pending(session_factory)
    got = client.get(f"/api/v1/streams/{recording['id']}/estimates",
                     params={"max_points": 100_000}, headers=headers)
    assert got.status_code == 200, got.text
    assert_tracks_the_shift(got.json())
    # A model at one operating point: one gain for the whole recording.
    state = session.scalar(select(StreamFilterState).where(
        StreamFilterState.recording_id == recording["id"]))
    assert state is not None and state.n_segments == 1

    # The steady cruise windows are the engine's records, in the type's names and units.
    records = client.get(f"/api/v1/engines/{fleet.engine_id}/snapshots", headers=headers)
    assert records.status_code == 200
    listed = records.json()
    assert listed["count"] >= 1 and listed["units"]["EGT"] == "degC"
    first = listed["snapshots"][0]
    assert first["EGT"] == pytest.approx(float(np.mean(egt[:1500])), abs=1.0)
    assert first["N1"] == pytest.approx(own.TRIM["N1"], rel=0.01)


def test_a_column_or_unit_the_type_does_not_have_refuses_the_stream_naming_both(
    client: TestClient, custom: tuple[own.CustomFleet, dict[str, str]],
) -> None:
    _fleet, headers = custom
    header, values = own.samples(50, np.zeros((50, len(own.HEALTH))))
    csv_headers = {**headers, "Content-Type": "text/csv"}

    def refused(path: str, body: bytes, *expected: str, **params: Any) -> None:
        response = client.post(path, params=params, content=body, headers=csv_headers)
        assert response.status_code == 422, response.text
        for text in expected:
            assert text in response.json()["error"]["message"], (text, response.text)

    # A built-in engine's signal on this engine: unknown for its type, named with it.
    with_t30 = csv_text([*header, "T30"], np.column_stack([values, np.full(50, 1400.0)]))
    refused("/api/v1/streams", with_t30, "unknown column 'T30'", TYPE, **meta())
    # A unit the signal's quantity does not take.
    bad_unit = csv_text([h.replace("EGT[degF]", "EGT[psia]") for h in header], values)
    refused("/api/v1/streams", bad_unit, "unknown unit 'psia' for temperature", **meta())
    assert client.get("/api/v1/streams", headers=headers).json()["total"] == 0

    # Live: the recording opens; a chunk with the unknown column is refused, stores nothing;
    # the good chunk is stored converted.
    live = client.post("/api/v1/streams/live", json={**meta(), "dt_s": 0.02}, headers=headers)
    assert live.status_code == 201, live.text
    rid = live.json()["id"]
    refused(f"/api/v1/streams/{rid}/chunks", with_t30, "unknown column 'T30'", TYPE, index=0)
    assert client.get(f"/api/v1/streams/{rid}", headers=headers).json()["n_samples"] == 0
    good = client.post(f"/api/v1/streams/{rid}/chunks", params={"index": 0},
                       content=csv_text(header, values), headers=csv_headers)
    assert good.status_code == 201, good.text
    assert good.json()["recording"]["n_samples"] == 50
    stored = client.get(f"/api/v1/streams/{rid}/samples", headers=headers)
    first = next(csv.DictReader(io.StringIO(stored.text)))
    assert float(first["EGT"]) == pytest.approx(
        (values[0, header.index("EGT[degF]")] - 32.0) / 1.8, rel=1e-5)
    assert "T30" not in first


def records_of(client: TestClient, engine_id: int, headers: dict[str, str],
               recording_id: int) -> list[dict[str, Any]]:
    """The engine's records that summarise a steady window of the recording (their upload
    belongs to it: ``trends.service.stream_records``), from the trend, with the listed
    snapshot at each one's time."""
    trend = client.get(f"/api/v1/engines/{engine_id}/trend", params={"max_points": 0},
                       headers=headers)
    assert trend.status_code == 200, trend.text
    body = trend.json()
    times = [ms(t) for t, r in zip(body["time"], body["recording"], strict=True)
             if r == recording_id]
    listed = client.get(f"/api/v1/engines/{engine_id}/snapshots", headers=headers).json()
    by_time = {ms(s["recorded_at"]): s for s in listed["snapshots"]}
    return [by_time[t] for t in times]


def ms(text: str) -> int:
    """An ISO time in whole milliseconds (the trend gives milliseconds, the listing more)."""
    return round(datetime.fromisoformat(text.replace("Z", "+00:00")).timestamp() * 1000.0)


def parquet_bytes(header: list[str], values: np.ndarray) -> bytes:
    sink = io.BytesIO()
    pq.write_table(pa.table({name: values[:, j] for j, name in enumerate(header)}), sink)
    return sink.getvalue()


@pytest.mark.parametrize("path", ["csv", "parquet", "live"])
def test_a_single_point_type_stream_needs_no_operating_condition(
    client: TestClient, custom: tuple[own.CustomFleet, dict[str, str]],
    session_factory: sessionmaker[Session], settings: Settings, monkeypatch: pytest.MonkeyPatch,
    path: str,
) -> None:
    fleet, headers = custom
    monkeypatch.setattr("app.config.get_settings", lambda: settings)
    header, values = without_condition(*own.samples(N, health()))
    assert header == ["time_s", "N1[%]", "N2[%]", "EGT[degF]", "PS3[kPa]", "FF_meas[kg/h]",
                      "FF[kg/h]", "IGV[deg]"]
    csv_headers = {**headers, "Content-Type": "text/csv"}
    if path == "csv":
        response = client.post("/api/v1/streams", params=meta(),
                               content=csv_text(header, values), headers=csv_headers)
        assert response.status_code == 201, response.text
        recording = response.json()["recording"]
    elif path == "parquet":
        response = client.post(
            "/api/v1/streams", params=meta(), content=parquet_bytes(header, values),
            headers={**headers, "Content-Type": "application/vnd.apache.parquet"})
        assert response.status_code == 201, response.text
        recording = response.json()["recording"]
    else:
        # Live, in chunks that split the windows: each window is summarised once, whole.
        live = client.post("/api/v1/streams/live", json={**meta(), "dt_s": 0.02},
                           headers=headers)
        assert live.status_code == 201, live.text
        rid = live.json()["id"]
        for index, part in enumerate(np.array_split(values, 4)):
            sent = client.post(f"/api/v1/streams/{rid}/chunks", params={"index": index},
                               content=csv_text(header, part), headers=csv_headers)
            assert sent.status_code == 201, sent.text
        closed = client.post(f"/api/v1/streams/{rid}/close", headers=headers)
        assert closed.status_code == 200, closed.text
        recording = closed.json()
    assert recording["n_samples"] == N
    assert not set(CONDITION_COLUMNS) & set(recording["signals"])

    # Estimated on the model's own trims: the same health as with the condition sent.
    run_pending(session_factory)
    got = client.get(f"/api/v1/streams/{recording['id']}/estimates",
                     params={"max_points": 100_000}, headers=headers)
    assert got.status_code == 200, got.text
    assert_tracks_the_shift(got.json())

    # Two steady 30 s windows (inputs held, sensors settled: the shift falls on the second's
    # first sample), records of the engine with no phase and no condition, the mean of the
    # type's signals over each window, estimated by the snapshot pipeline.
    windows = records_of(client, fleet.engine_id, headers, recording["id"])
    assert len(windows) == 2
    egt = (values[:, header.index("EGT[degF]")] - 32.0) / 1.8
    for k, record in enumerate(windows):
        assert record["phase"] is None
        assert all(record[c] is None for c in CONDITION_COLUMNS)
        window = slice(k * N // 2, (k + 1) * N // 2)
        assert record["EGT"] == pytest.approx(float(np.mean(egt[window])), abs=1e-3)
        assert record["FF"] == pytest.approx(own.TRIM["FF"], rel=1e-9)
    assert windows[1]["N1"] < windows[0]["N1"]  # the fan lost efficiency half-way


def test_an_unsteady_input_or_sensor_is_no_steady_window(
    client: TestClient, custom: tuple[own.CustomFleet, dict[str, str]],
) -> None:
    """Without a condition, the type's own signals decide: fuel flow ramped by 5 % over the
    first window, or a sensor drifting 6 % through the second (a transient index of 2e-3
    per second, twice the dead band), leaves that window out."""
    fleet, headers = custom
    header, values = without_condition(*own.samples(N, np.zeros((N, len(own.HEALTH)))))
    values[: N // 2, header.index("FF[kg/h]")] *= np.linspace(1.0, 1.05, N // 2)
    values[N // 2:, header.index("PS3[kPa]")] *= np.linspace(1.0, 1.06, N - N // 2)
    response = client.post("/api/v1/streams", params=meta(), content=csv_text(header, values),
                           headers={**headers, "Content-Type": "text/csv"})
    assert response.status_code == 201, response.text
    assert "steady windows" not in response.json()["upload"]["message"]
    assert records_of(client, fleet.engine_id, headers,
                      response.json()["recording"]["id"]) == []
