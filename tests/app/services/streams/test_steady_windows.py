"""Streams in the engine's history: a recording's steady windows become records of the engine.

One engine of a seeded fleet has 150 flights of snapshots, then two whole flights recorded at
20 Hz by the closed-loop transient simulator (``simulated``), the second with the seed 002 HPC
fault. Through the upload API and the snapshot pipeline:

- each recording gives one record per steady window (take-off, climb, cruise), each equal to
  the steady-state solver's snapshot of the same engine at the window's mean condition within
  a fraction of the sensor noise;
- their health estimates track the simulator's truth as closely as the engine's snapshots do;
- the faulted recording raises an event isolated to HPC through the normal pipeline;
- uploading a recording again, summarising it again or estimating again duplicates nothing;
- the engine trend (JSON and CSV) marks the stream records with their recording;
- live chunks of any size give the records of the whole file.
"""

from __future__ import annotations

import csv
import io
from datetime import UTC, datetime
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.config import Settings
from app.models import Snapshot, StreamRecording, Upload
from app.models.estimates import Event
from app.services.demo import fleet as demo
from app.services.designs import engine_models
from app.services.designs import service as designs
from app.services.fleet import service as fleet_service
from app.services.snapshots import backlog, estimator
from app.services.snapshots import store as snapshots_store
from app.services.streams import steady
from app.services.streams import store as stream_store
from app.services.tenancy import service as tenancy
from app.services.trends import service as trends
from app.services.uploads import store as uploads_store
from estimation.engine.fleet import StreamFlight
from estimation.engine.health import HEALTH_NAMES
from estimation.engine.sensors import SENSOR_NAMES
from estimation.engine.steady import steady_state
from estimation.steady_windows import field_of, steady_windows, window_length, window_means
from tests.app.services.streams.simulated import (
    FAULT,
    FLIGHTS,
    TIMES_S,
    Simulated,
    simulate_engine,
    stream_csv,
)

pytestmark = pytest.mark.long(seconds=85)

CSV = {"Content-Type": "text/csv"}
SETTLE = 60  # snapshots after the first before they are scored (filter start-up)


@pytest.fixture(scope="session")
def simulated() -> Simulated:
    """Once per test process: the tests of both backends share the simulation (about a minute);
    a module scope would run it again for the second backend, whose tests pytest groups
    apart."""
    return simulate_engine()


class Seeded:
    def __init__(self, operator_id: int, key: str, engine_id: int) -> None:
        self.operator_id = operator_id
        self.headers = {"X-API-Key": key}
        self.engine_id = engine_id


def _seed(session: Session, sim: Simulated, design: bool = True) -> Seeded:
    """The engine, its installation, the demo's active design and its snapshots, estimated."""
    op = tenancy.create_operator(session, name=f"Stream Air {datetime.now(UTC).timestamp()}")
    _, key = tenancy.issue_api_key(session, operator=op, role="admin", name="admin")
    engine_type = fleet_service.create_engine_type(session, operator_id=op.id, name="built-in")
    if design:
        p = demo.DESIGN_POINT
        model = estimator.builtin_schedule().model_at(p["alt"], p["mach"], p["power"])
        row, _ = engine_models.register_builtin_model(
            session, operator_id=op.id, engine_type_id=engine_type.id, name="cruise",
            model=model)
        method, tuners = demo.ACTIVE_DESIGN
        d = designs.create_design(
            session, operator_id=op.id, engine_model_id=row.id, name="all health",
            spec=demo.design_spec(method, tuners, [n for n in model.sensor_names if n != "Wf"]))
        designs.run_design(session, d, designs.design_step)
        designs.activate_design(session, operator_id=op.id, design_id=d.id)
    plan = sim.plan
    tail = fleet_service.create_aircraft(session, operator_id=op.id, tail=plan.tails[0])
    engine_id = 0
    for inst in plan.installations:
        engine = fleet_service.create_engine(session, operator_id=op.id, esn=inst.esn,
                                             engine_type_id=engine_type.id)
        fleet_service.install(
            session, operator_id=op.id, engine_id=engine.id, aircraft_id=tail.id,
            position=inst.position, installed_at=datetime.fromtimestamp(inst.installed_at, UTC))
        engine_id = engine.id
    sink = io.BytesIO()
    pq.write_table(sim.snapshots, sink)
    uploads_store.ingest_snapshots(session, operator_id=op.id, api_key_id=None,
                                   body=sink.getvalue(), content_format="parquet")
    snapshots_store.catch_up(session, op.id)
    return Seeded(op.id, key, engine_id)


def _upload(client: TestClient, seeded: Seeded, flight: StreamFlight) -> Any:
    response = client.post(
        "/api/v1/streams", content=stream_csv(flight), headers={**seeded.headers, **CSV},
        params={"tail": flight.tail, "position": flight.position,
                "started_at": datetime.fromtimestamp(flight.started_at, UTC).isoformat(),
                "flight_id": flight.flight_id},
    )
    assert response.status_code in (200, 201), response.text[:400]
    return response


def _expected_windows(flight: StreamFlight) -> list[Any]:
    """The steady windows of a flight by the pure function, as ``steady`` applies it."""
    dt = float(flight.time_s[1] - flight.time_s[0])
    spools = flight.sensors[:, [SENSOR_NAMES.index("Nf"), SENSOR_NAMES.index("Nc")]]
    return steady_windows(flight.alt_ft, flight.mach, flight.power_pct, spools, dt,
                          field_of(flight.alt_ft[0], flight.mach[0]), 0, steady.CRITERIA)


def _records(session: Session, engine_id: int, upload_ids: list[int]) -> list[Snapshot]:
    return list(session.scalars(
        select(Snapshot).where(Snapshot.engine_id == engine_id,
                               Snapshot.upload_id.in_(upload_ids))
        .order_by(Snapshot.recorded_at)).all())


def _health_rms(trend: dict[str, Any], keep: np.ndarray, truth: np.ndarray) -> float:
    """RMS error [%] of the trend's observable health levels at points ``keep`` against
    ``truth`` [len(keep), 13]."""
    group = next(g for g in trend["groups"] if g["key"] == "health")
    errors = []
    for s in group["series"]:
        if s["name"] not in HEALTH_NAMES or s["name"] in (group.get("unobservable") or []):
            continue
        value = np.array([np.nan if v is None else v for v in s["value"]], float)[keep]
        errors.append(value - truth[:, HEALTH_NAMES.index(s["name"])])
    e = np.concatenate(errors)
    return float(np.sqrt(np.nanmean(e ** 2)))


def _coverage(trend: dict[str, Any], keep: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Fractions of the observable health levels at points ``keep`` whose shown +-1 sigma and
    +-2 sigma hold ``truth`` [len(keep), 13]."""
    group = next(g for g in trend["groups"] if g["key"] == "health")
    z = []
    for s in group["series"]:
        if s["name"] not in HEALTH_NAMES or s["name"] in (group.get("unobservable") or []):
            continue
        value = np.array([np.nan if v is None else v for v in s["value"]], float)[keep]
        sigma = np.array([np.nan if v is None else v for v in s["sigma"]], float)[keep]
        z.append(np.abs(value - truth[:, HEALTH_NAMES.index(s["name"])]) / sigma)
    zz = np.concatenate(z)
    zz = zz[np.isfinite(zz)]
    return float(np.mean(zz <= 1.0)), float(np.mean(zz <= 2.0))


def test_streams_join_the_engines_history_with_its_snapshots(
    client: TestClient, session: Session, settings: Settings, simulated: Simulated
) -> None:
    sim = simulated
    seeded = _seed(session, sim)
    healthy, faulted = sim.flights
    n_snapshots = sim.snapshots.num_rows

    first = _upload(client, seeded, healthy).json()
    expected = _expected_windows(healthy)
    phases = {w.phase for w in expected}
    assert phases == {"takeoff", "climb", "cruise"}
    records = _records(session, seeded.engine_id, [first["upload"]["id"]])
    # One record per steady window, at the window's middle, with the window's phase.
    assert len(records) == len(expected) >= 15
    assert [r.phase for r in records] == [w.phase for w in expected]
    assert all(r.flight_id == healthy.flight_id for r in records)
    recording = session.get(StreamRecording, first["recording"]["id"])
    assert recording is not None
    dt = float(recording.dt_s)
    W = window_length(dt, steady.CRITERIA.window_s)
    middle = [(recording.started_at - datetime.fromtimestamp(healthy.started_at, UTC))
              .total_seconds() + (w.start + (W - 1) / 2) * dt for w in expected]
    got = [(r.recorded_at - recording.started_at).total_seconds() for r in records]
    np.testing.assert_allclose(got, middle, atol=1e-3)
    upload = session.get(Upload, first["upload"]["id"])
    assert upload is not None and upload.affected[0]["rows"] == len(expected)

    # The stream filter runs the whole flight under the demo's design, ground idle included:
    # at idle its ten tuners are unobservable, so the filter predicts there and says "not
    # estimated" (null 1-sigma) instead of failing the recording; from take-off on every
    # window is estimated.
    stream_store.estimate_recording(session, operator_id=seeded.operator_id,
                                    recording_id=recording.id, data_dir=settings.data_dir)
    body = client.get(f"/api/v1/streams/{recording.id}/estimates",
                      headers=seeded.headers).json()
    assert body["n_samples_estimated"] == recording.n_samples
    t = np.array(body["t_s"])
    sigma = np.array([[np.nan if v is None else v for v in series]
                      for series in body["h_sigma"].values()])
    idle = t < TIMES_S[1] - body["window_s"]
    flying = t >= TIMES_S[2]
    assert idle.any() and np.isnan(sigma[:, idle]).all()
    assert np.isfinite(sigma[:, flying]).all()
    assert all(v is not None for series in body["h_hat"].values() for v in series)

    # Each record is the snapshot the engine would give at the window's mean condition:
    # the steady-state solver with the flight's true health, within a fraction of the noise.
    cond = np.array([[r.alt_ft, r.mach, r.dtamb_k, r.power_pct] for r in records])
    solved = steady_state(cond[:, :3], power=cond[:, 3],
                          health=np.tile(healthy.health, (len(records), 1)))
    from estimation.engine.fleet import engine_noise_std

    stored = np.array([[getattr(r, n.lower()) for n in SENSOR_NAMES] for r in records])
    in_noise = np.abs(stored - solved.sensors) / engine_noise_std()
    steady_rows = np.array([r.phase != "takeoff" for r in records])
    print(f"windows {len(records)}: " + ", ".join(
        f"{p} {sum(r.phase == p for r in records)}" for p in ("takeoff", "climb", "cruise"))
        + f"; |mean - solved| / noise: climb and cruise {np.max(in_noise[steady_rows]):.2f}, "
        f"take-off {np.max(in_noise[~steady_rows]):.2f}")
    assert np.max(in_noise[steady_rows]) < 0.5
    assert np.max(in_noise) < 1.0  # take-off: the spools' heat soak after the throttle step

    # The snapshot pipeline estimates them with the engine's snapshots, one baseline.
    snapshots_store.catch_up(session, seeded.operator_id)
    trend = trends.engine_trend(session, seeded.operator_id, seeded.engine_id, max_points=0)
    assert trend["n_records"] == n_snapshots + len(expected)
    marked = np.array([r is not None for r in trend["recording"]])
    assert marked.sum() == len(expected)
    assert set(r for r in trend["recording"] if r is not None) == {recording.id}
    assert marked[-len(expected):].all()  # after the snapshots, in time order

    # Health against the truth: the stream records as close as the engine's snapshots.
    epoch = np.array([datetime.fromisoformat(t.replace("Z", "+00:00")).timestamp()
                      for t in trend["time"]])
    snap_keep = np.flatnonzero(~marked)[SETTLE:]
    starts = np.array([f[0].started_at for f in sim.plan.flights])
    rounds = np.searchsorted(starts, epoch[snap_keep], side="right") - 1
    engine = sim.plan.esns.index(healthy.esn)
    snap_rms = _health_rms(trend, snap_keep, sim.plan.health[rounds, engine])
    stream_keep = np.flatnonzero(marked)
    stream_rms = _health_rms(trend, stream_keep, np.tile(healthy.health, (len(stream_keep), 1)))
    print(f"health RMS: snapshots {snap_rms:.3f} %, stream windows {stream_rms:.3f} %")
    snap_cover = _coverage(trend, snap_keep, sim.plan.health[rounds, engine])
    stream_cover = _coverage(trend, stream_keep, np.tile(healthy.health, (len(stream_keep), 1)))
    print("truth within +-1 / +-2 sigma: snapshots {:.2f} / {:.2f}, stream windows {:.2f} / "
          "{:.2f}".format(*snap_cover, *stream_cover))
    # The bands shown on stream points hold the truth no less often than on snapshots
    # (measured: snapshots 0.66 / 0.81, stream windows 0.80 / 0.80).
    assert stream_cover[0] >= snap_cover[0] - 0.05 and stream_cover[1] >= snap_cover[1] - 0.05
    assert stream_rms <= max(1.5 * snap_rms, 0.3)

    # The faulted flight: an event isolated to the injected fault, through the pipeline.
    second = _upload(client, seeded, faulted).json()
    snapshots_store.catch_up(session, seeded.operator_id)
    rec2 = session.get(StreamRecording, second["recording"]["id"])
    assert rec2 is not None
    events = session.scalars(select(Event).where(Event.engine_id == seeded.engine_id)
                             .order_by(Event.detected_at)).all()
    in_flight = [e for e in events if e.detected_at >= rec2.started_at]
    assert in_flight, [(e.kind, e.fault, e.detected_at) for e in events]
    assert in_flight[0].kind == "isolated_fault" and in_flight[0].fault == FAULT
    assert not [e for e in events if e.detected_at < rec2.started_at and e.kind != "wear"]

    # Again: the same file (a replay), summarising again, estimating the engine again from
    # its first record: nothing new.
    count = session.scalar(select(func.count()).select_from(Snapshot)
                           .where(Snapshot.engine_id == seeded.engine_id))
    again = _upload(client, seeded, healthy)
    assert again.status_code == 200 and again.json()["upload"]["replayed"]
    assert steady.summarise_windows(session, settings.data_dir, recording, upload, 0) == 0
    first_at = session.scalar(select(func.min(Snapshot.recorded_at))
                              .where(Snapshot.engine_id == seeded.engine_id))
    backlog.mark(session, seeded.operator_id, {seeded.engine_id: (first_at, None)})
    snapshots_store.catch_up(session, seeded.operator_id)
    assert session.scalar(select(func.count()).select_from(Snapshot)
                          .where(Snapshot.engine_id == seeded.engine_id)) == count
    assert session.scalar(select(func.count()).select_from(Event)
                          .where(Event.engine_id == seeded.engine_id)) == len(events)

    # The trend API marks the stream records with their recording, JSON and CSV.
    got = client.get(f"/api/v1/engines/{seeded.engine_id}/trend",
                     params={"max_points": 0}, headers=seeded.headers)
    assert got.status_code == 200
    body = got.json()
    by_recording = {rid: body["recording"].count(rid) for rid in (recording.id, rec2.id)}
    assert by_recording == {recording.id: len(expected),
                            rec2.id: len(_expected_windows(faulted))}
    assert body["recording"].count(None) == n_snapshots
    text = client.get(f"/api/v1/engines/{seeded.engine_id}/trend",
                      params={"max_points": 0, "format": "csv"}, headers=seeded.headers).text
    rows = list(csv.DictReader(io.StringIO(text)))
    assert [r["recording_id"] or None for r in rows] == [
        None if r is None else str(r) for r in body["recording"]]


@pytest.mark.parametrize("chunk", [7777, 20_000])
def test_live_chunks_give_the_records_of_the_whole_file(
    client: TestClient, session: Session, simulated: Simulated, chunk: int
) -> None:
    seeded = _seed(session, simulated, design=False)
    flight = simulated.flights[0]
    dt = float(flight.time_s[1] - flight.time_s[0])
    opened = client.post("/api/v1/streams/live", headers=seeded.headers, json={
        "tail": flight.tail, "position": flight.position, "flight_id": flight.flight_id,
        "started_at": datetime.fromtimestamp(flight.started_at, UTC).isoformat(), "dt_s": dt})
    assert opened.status_code == 201, opened.text
    rid = opened.json()["id"]
    table = pa.csv.read_csv(io.BytesIO(stream_csv(flight)))
    upload_ids = []
    for index, start in enumerate(range(0, table.num_rows, chunk)):
        sink = io.BytesIO()
        pa.csv.write_csv(table.slice(start, chunk), sink)
        response = client.post(f"/api/v1/streams/{rid}/chunks", params={"index": index},
                               content=sink.getvalue(), headers={**seeded.headers, **CSV})
        assert response.status_code == 201, response.text[:300]
        upload_ids.append(response.json()["upload_id"])
        # A chunk sent again is answered as before and stores nothing.
        if index == 1:
            resent = client.post(f"/api/v1/streams/{rid}/chunks", params={"index": index},
                                 content=sink.getvalue(), headers={**seeded.headers, **CSV})
            assert resent.status_code == 200
    records = _records(session, seeded.engine_id, upload_ids)
    expected = _expected_windows(flight)
    assert [r.phase for r in records] == [w.phase for w in expected]
    W = window_length(dt, steady.CRITERIA.window_s)
    names = ["alt_ft", "mach", "power_pct", "nc", "t48"]
    values = np.column_stack([flight.alt_ft, flight.mach, flight.power_pct,
                              flight.sensors[:, SENSOR_NAMES.index("Nc")],
                              flight.sensors[:, SENSOR_NAMES.index("T48")]])
    want = window_means(values, np.array([w.start for w in expected]), W)
    have = np.array([[getattr(r, n) for n in names] for r in records])
    np.testing.assert_allclose(have, want, rtol=1e-9)
    # Each window is stored by the chunk that completed it.
    first_sample = {u: i * chunk for i, u in enumerate(upload_ids)}
    for r, w in zip(records, expected, strict=True):
        assert first_sample[r.upload_id] < w.stop <= first_sample[r.upload_id] + chunk
    assert FLIGHTS > 0
