"""Stream estimation through the service: upload a whole flight, estimate it, read its trend.

One engine, a simulated flight of the reference model (6 sensors, 4 SVD tuners) at 20 Hz,
uploaded as CSV through HTTP, then estimated by the ``estimate_recording`` service (read the
Parquet chunks, per-sample trims, scheduled steady-state filter, one-second windows, rows
stored), and the same flight as live one-minute chunks each estimated on arrival. Peers
measured in the same run on the same samples:

  core      estimation.kalman.filter_stream_states over the whole flight (the filter alone)
  numpy     plain closed-loop recursion, one [1, n] x [n, n] product per step

Figures: samples/s of upload, estimation and both end to end; the service estimation time
over the core filter time; live chunk latency (upload + estimate) per chunk.

Run from the repository root:  .venv/bin/python bench/bench_stream_service.py
(``--database-url postgresql+psycopg://...`` to use a PostgreSQL database: it is migrated and
filled, use a throw-away one).
"""

from __future__ import annotations

import argparse
import io
import tempfile
import time
import uuid
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
from _common import ROOT  # noqa: F401  (puts the repository on sys.path)
from fastapi.testclient import TestClient

from app.config import Settings
from app.db import make_engine, make_sessionmaker
from app.main import create_app
from app.migrate import upgrade
from app.models import EngineModel, EstimatorDesign
from app.services.fleet import service as fleet
from app.services.snapshots import estimator
from app.services.streams import estimator as stream_estimator
from app.services.streams import run as stream_run
from app.services.streams import store as stream_store
from app.services.tenancy.service import create_operator, issue_api_key
from estimation.design import design_to_dict
from estimation.kalman import filter_stream_states
from estimation.tuners import design_filter, svd_vstar
from tests.estimation.models import reference_model, reference_noise

DT = 0.05
M = 4
START = datetime(2026, 6, 1, 8, 0, tzinfo=UTC)


def flight_table(model, n: int, seed: int = 0) -> pa.Table:
    rng = np.random.default_rng(seed)
    vstar = svd_vstar(model, M)
    h = np.linalg.lstsq(vstar, np.array([1.5, -1.0, 0.8, -0.6]), rcond=None)[0]
    t = np.arange(n) * DT
    u = np.zeros((n, model.n_inputs))
    u[:, 0] = np.sin(0.3 * t)
    x = np.linalg.solve(np.eye(model.n_states) - model.A, model.L @ h)
    y = np.empty((n, model.n_sensors))
    for k in range(n):  # the plant, simulated once
        y[k] = model.C @ x + model.D @ u[k] + model.M @ h
        x = model.A @ x + model.B @ u[k] + model.L @ h
    y += rng.normal(size=y.shape) * model.sensor_noise_std
    gains = estimator.single_point_schedule(model)(np.zeros((1, 4)))
    cols = {"time_s": t, "alt_ft": np.full(n, 35000.0), "mach": np.full(n, 0.8),
            "dtamb_k": np.zeros(n), "power_pct": np.full(n, 85.0)}
    cols["Wf"] = gains.u_trim[0, 0] * (1 + u[:, 0] / 100)
    for i, s in enumerate(model.sensors):
        cols[s.name] = gains.y_trim[0, i] * (1 + y[:, i] / 100)
    return pa.table(cols)


def csv_bytes(table: pa.Table) -> bytes:
    sink = io.BytesIO()
    pacsv.write_csv(table, sink)
    return sink.getvalue()


def setup(factory, model, source: str = "imported", m: int = M) -> tuple[int, str]:
    """Operator, analyst key, two engines on one tail, a design on ``model`` active."""
    with factory() as session, session.begin():
        op = create_operator(session, name=f"Bench Air {uuid.uuid4().hex[:6]}")
        _row, key = issue_api_key(session, operator=op, role="analyst", name="bench")
        etype = fleet.create_engine_type(session, operator_id=op.id, name="generic")
        aircraft = fleet.create_aircraft(session, operator_id=op.id, tail="N1")
        for pos in (1, 2):
            eng = fleet.create_engine(session, operator_id=op.id, esn=f"E{pos}",
                                      engine_type_id=etype.id)
            fleet.install(session, operator_id=op.id, engine_id=eng.id, aircraft_id=aircraft.id,
                          position=pos, installed_at=START - timedelta(days=30))
        row = EngineModel(
            operator_id=op.id, engine_type_id=etype.id, name="ref", version=1,
            source=source, format="fleethealth.linear-model/1", content=model.to_dict(),
            checksum="0" * 64, dt=model.dt, n_states=model.n_states,
            sensor_names=model.sensor_names, health_names=model.health_names,
            aux_names=model.aux_names,
        )
        session.add(row)
        session.flush()
        noise = reference_noise(model)
        design = design_filter(model, svd_vstar(model, m), noise["Q"], noise["Qh"], noise["Ph"])
        session.add(EstimatorDesign(
            operator_id=op.id, engine_type_id=etype.id, engine_model_id=row.id, name="d",
            spec={}, status="ready", active=True, result=design_to_dict(design)))
        return op.id, key


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=60.0)
    ap.add_argument("--chunk-s", type=float, default=60.0)
    ap.add_argument("--database-url", default=None)
    args = ap.parse_args()

    model = reference_model(dt=DT)
    n = int(args.minutes * 60 / DT)
    table = flight_table(model, n)
    body = csv_bytes(table)
    with tempfile.TemporaryDirectory() as tmp:
        url = args.database_url or f"sqlite:///{tmp}/bench.sqlite3"
        upgrade(url)
        engine = make_engine(url)
        factory = make_sessionmaker(engine)
        settings = Settings(data_dir=Path(tmp) / "data", database_url=url, log_json=False,
                            log_level="WARNING")
        operator_id, key = setup(factory, model)
        headers = {"X-API-Key": key, "Content-Type": "text/csv"}
        with TestClient(create_app(settings, engine)) as client:
            t0 = time.perf_counter()
            r = client.post("/api/v1/streams", content=body, headers=headers, params={
                "tail": "N1", "position": 1, "started_at": START.isoformat()})
            t_upload = time.perf_counter() - t0
            assert r.status_code == 201, r.text[:300]
            rec_id = r.json()["recording"]["id"]
            t0 = time.perf_counter()
            with factory() as session, session.begin():
                summary = stream_store.estimate_recording(
                    session, operator_id=operator_id, recording_id=rec_id,
                    data_dir=settings.data_dir)
            t_est = time.perf_counter() - t0
            t0 = time.perf_counter()
            trend = client.get(f"/api/v1/streams/{rec_id}/estimates",
                               headers={"X-API-Key": key})
            t_read = time.perf_counter() - t0
            assert trend.status_code == 200

            # Live: the same flight in chunks, each estimated when it arrives.
            opened = client.post("/api/v1/streams/live", headers={"X-API-Key": key}, json={
                "tail": "N1", "position": 2, "started_at": START.isoformat(), "dt_s": DT})
            live_id = opened.json()["id"]
            per = int(args.chunk_s / DT)
            latencies = []
            for index, lo in enumerate(range(0, n, per)):
                part = csv_bytes(table.slice(lo, per))
                t0 = time.perf_counter()
                r = client.post(f"/api/v1/streams/{live_id}/chunks", params={"index": index},
                                content=part, headers=headers)
                assert r.status_code == 201, r.text[:300]
                with factory() as session, session.begin():
                    stream_store.estimate_recording(
                        session, operator_id=operator_id, recording_id=live_id,
                        data_dir=settings.data_dir)
                latencies.append(time.perf_counter() - t0)

        with factory() as session:
            from sqlalchemy import select

            from app.models.stream_estimates import StreamEstimate, StreamFilterState
            rows = {rid: session.execute(
                select(StreamEstimate.packed).where(StreamEstimate.recording_id == rid)
                .order_by(StreamEstimate.window)).scalars().all() for rid in (rec_id, live_id)}
            states = {s.recording_id: s for s in session.scalars(select(StreamFilterState))}
            x_whole = np.asarray(states[rec_id].state["x_end"])
            x_live = np.asarray(states[live_id].state["x_end"])
            est = stream_estimator._ESTIMATORS[next(iter(stream_estimator._ESTIMATORS))]
        engine.dispose()

    # Peers on the same samples: deviations once, then the filter alone.
    cond, dy, du = stream_run.deviations(est, table)
    g = est.gain(est.snapped(cond[0]), DT)

    def core() -> np.ndarray:
        return filter_stream_states(g.A, g.C, g.K, dy[:, None, :], u=du[:, None, :], B=g.B,
                                    D=g.D)

    def plain() -> np.ndarray:
        Phi = (np.eye(len(g.A)) - g.K @ g.C) @ g.A
        IKCB = (np.eye(len(g.A)) - g.K @ g.C) @ g.B
        drive = dy @ g.K.T - du @ (g.K @ g.D).T
        drive[1:] += du[:-1] @ IKCB.T
        out = np.empty((n, len(g.A)))
        x = np.zeros(len(g.A))
        for k in range(n):
            x = Phi @ x + drive[k]
            out[k] = x
        return out

    t0 = time.perf_counter()
    core()
    t_core = time.perf_counter() - t0
    t0 = time.perf_counter()
    plain()
    t_plain = time.perf_counter() - t0

    print(f"flight: {n} samples at {1 / DT:g} Hz ({args.minutes:g} min), {len(body) / 1e6:.1f} MB "
          f"CSV, database {'PostgreSQL' if url.startswith('postgresql') else 'SQLite'}")
    print(f"upload (HTTP, parse, store)      {t_upload:7.3f} s  {n / t_upload:12,.0f} samples/s")
    print(f"estimate (service, rows stored)  {t_est:7.3f} s  {n / t_est:12,.0f} samples/s  "
          f"({summary['windows']} windows, {summary['segments']} segment)")
    print(f"end to end (upload + estimate)   {t_upload + t_est:7.3f} s  "
          f"{n / (t_upload + t_est):12,.0f} samples/s")
    print(f"trend read (HTTP, JSON)          {t_read * 1e3:7.1f} ms")
    print(f"peer core filter_stream_states   {t_core:7.3f} s  {n / t_core:12,.0f} samples/s")
    print(f"peer plain numpy recursion       {t_plain:7.3f} s  {n / t_plain:12,.0f} samples/s")
    print(f"service estimate / core filter   {t_est / t_core:7.2f} x")
    lat = np.asarray(latencies)
    print(f"live: {len(lat)} chunks of {args.chunk_s:g} s, upload + estimate per chunk "
          f"median {np.median(lat) * 1e3:.0f} ms, max {lat.max() * 1e3:.0f} ms "
          f"({per / np.median(lat):,.0f} samples/s)")
    same = rows[rec_id] == rows[live_id]
    print(f"live chunks == whole file: rows bit for bit {same}, "
          f"max |x_end diff| {np.max(np.abs(x_whole - x_live)):.3g}")


def scheduled(minutes: float) -> None:
    """A climb to 35,000 ft, cruise and descent on the built-in engine's schedule: gains
    re-scheduled along the envelope (coarse schedule grid, design model linearised at 15 ms,
    resampled to the recording's 50 ms)."""
    from estimation.engine.schedule import build_schedule

    sched = build_schedule({"alt": (0.0, 20000.0, 40000.0), "mach": (0.2, 0.5, 0.85),
                            "power": (60.0, 100.0)})
    estimator.builtin_schedule = lambda: sched  # type: ignore[assignment]
    model = sched.model_at(20000.0, 0.5, 80.0).select_health(sched.template.health_names[:10])
    n = int(minutes * 60 / DT)
    f = np.linspace(0.0, 1.0, n)
    alt = 35000.0 * np.clip(np.minimum(f / 0.3, (1.0 - f) / 0.3), 0.0, 1.0)
    mach = 0.25 + 0.55 * alt / 35000.0
    power = np.where(np.gradient(alt) > 0, 95.0, np.where(np.gradient(alt) < 0, 65.0, 85.0))
    cond = np.column_stack([alt, mach, np.zeros(n), power])
    trims = sched.trims_at(cond[:, [0, 1, 3, 2]])
    rng = np.random.default_rng(1)
    cols = {"time_s": np.arange(n) * DT, "alt_ft": alt, "mach": mach, "dtamb_k": np.zeros(n),
            "power_pct": power}
    for s_ in model.sensors:
        a, b = stream_estimator._stored_affine(s_.name, s_.unit)
        cols[s_.name] = (a * trims[s_.name] + b) * (1 + rng.normal(size=n) * 0.002)
    body = csv_bytes(pa.table(cols))
    with tempfile.TemporaryDirectory() as tmp:
        url = f"sqlite:///{tmp}/bench.sqlite3"
        upgrade(url)
        engine = make_engine(url)
        factory = make_sessionmaker(engine)
        settings = Settings(data_dir=Path(tmp) / "data", database_url=url, log_json=False,
                            log_level="WARNING")
        operator_id, key = setup(factory, model, source="builtin", m=6)
        with TestClient(create_app(settings, engine)) as client:
            r = client.post("/api/v1/streams", content=body, params={
                "tail": "N1", "position": 1, "started_at": START.isoformat()},
                headers={"X-API-Key": key, "Content-Type": "text/csv"})
            assert r.status_code == 201, r.text[:300]
            rec_id = r.json()["recording"]["id"]
        t0 = time.perf_counter()
        with factory() as session, session.begin():
            summary = stream_store.estimate_recording(
                session, operator_id=operator_id, recording_id=rec_id,
                data_dir=settings.data_dir)
        t_est = time.perf_counter() - t0
        engine.dispose()
    print(f"scheduled flight (climb 0 -> 35,000 ft, cruise, descent): {n} samples, "
          f"{summary['segments']} gain segments, estimate {t_est:.3f} s "
          f"({n / t_est:,.0f} samples/s, {t_est / summary['segments'] * 1e3:.0f} ms a segment "
          "all in)")


if __name__ == "__main__":
    main()
    scheduled(30.0)
