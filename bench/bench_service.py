"""Service read paths on PostgreSQL: one engine's trend over 10,000 snapshots, the fleet
status of 1000 engines, and the fleet deterioration of 1000 engines with 2000 records each
(2M estimates).

Builds a throw-away database on the machine's PostgreSQL server (FLEETHEALTH_TEST_POSTGRES_URL
or postgres@127.0.0.1/test as the admin connection), fills it with estimates in the stored
format, and times the services and the HTTP routes (TestClient, JSON included). Peers measured
in the same run: a bare ``SELECT`` of the same rows (the floor any trend query pays), and the
same trend query reading JSON arrays instead of packed float32 (the storage not chosen).

The deterioration's per-engine weekly and monthly sums are written by the pipeline's own
function (``app.services.snapshots.buckets.refresh``) from the estimates' blocks as an
estimation run hands them to its writer (the 2M estimates themselves are not stored: the read
never touches them); its floor is a bare SELECT of those rows.

    .venv/bin/python bench/bench_service.py [--snapshots 10000] [--engines 1000]
        [--history 2000]

Targets (issue 5): trend p95 <= 50 ms; fleet status <= 300 ms; (issue 17) fleet deterioration
<= 300 ms at 2M records.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
import uuid
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
from sqlalchemy import create_engine, insert, text
from sqlalchemy.engine import make_url

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from app.config import Settings  # noqa: E402
from app.db import make_engine, make_sessionmaker  # noqa: E402
from app.main import create_app  # noqa: E402
from app.migrate import upgrade  # noqa: E402
from app.models import (  # noqa: E402
    Aircraft,
    Engine,
    EngineModel,
    EngineType,
    EstimatorDesign,
    Installation,
    Snapshot,
    Upload,
)
from app.models.estimates import (  # noqa: E402
    VALUE_DTYPE,  # noqa: E402
    Estimate,
    EstimateLayout,
    FilterState,
)
from app.services.fleet import status as fleet_status  # noqa: E402
from app.services.snapshots import buckets  # noqa: E402
from app.services.tenancy.service import create_operator, issue_api_key  # noqa: E402
from app.services.trends import service as trends  # noqa: E402
from app.signals import PHASES  # noqa: E402

ADMIN_URL = os.environ.get(
    "FLEETHEALTH_TEST_POSTGRES_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/test"
)
T0 = datetime(2025, 1, 1, tzinfo=UTC)
# The built-in engine's layout: 10 tuners and health parameters, 6 aux, 11 sensors, 8 faults.
LAYOUT = EstimateLayout(
    tuners=tuple(f"q{i + 1}" for i in range(10)),
    health=("fan_eff", "fan_flow", "lpc_eff", "lpc_flow", "hpc_eff", "hpc_flow", "hpt_eff",
            "hpt_flow", "lpt_eff", "lpt_flow"),
    aux=("Fn", "T40", "SM_fan", "SM_LPC", "SM_HPC", "BPR"),
    sensors=("Nf", "Nc", "T24", "P24", "T30", "Ps30", "P30", "T48", "P50", "T50", "P15"),
    faults=("Fan", "LPC", "HPC", "HPT", "LPT", "Wf", "VSV", "VBV"),
    health_from_tuners=tuple(tuple(row) for row in np.eye(10)),  # the demo design: h = q
)


def estimates(rng: np.random.Generator, n: int) -> np.ndarray:
    """n random estimates (n, width): normal values, 1-sigmas 0.2-1.2, WSSRs 0-20."""
    values = rng.normal(size=(n, LAYOUT.width))
    s = LAYOUT.slices()
    for block in ("q_sigma", "h_sigma", "z_sigma"):
        values[:, s[block]] = 0.2 + rng.random((n, s[block].stop - s[block].start))
    values[:, s["wssr"]] = 20.0 * rng.random((n, s["wssr"].stop - s["wssr"].start))
    values[:, s["h"]] = values[:, s["q"]]
    values[:, s["h_sigma"]] = values[:, s["q_sigma"]]
    return values


def timed(fn: Callable[[], object], repeat: int) -> list[float]:
    out = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return out


def p95(samples: list[float]) -> float:
    return float(np.percentile(samples, 95))


def fill(url: str, n_snapshots: int, n_engines: int) -> dict[str, object]:
    engine = make_engine(url)
    factory = make_sessionmaker(engine)
    rng = np.random.default_rng(1)
    with factory() as session:
        operator = create_operator(session, name="Bench Air")
        _row, key = issue_api_key(session, operator=operator, role="admin", name="bench")
        etype = EngineType(operator_id=operator.id, name="generic")
        session.add(etype)
        session.flush()
        model = EngineModel(
            operator_id=operator.id, engine_type_id=etype.id, name="m", version=1,
            source="imported", format="fleethealth.linear-model/1", content={},
            checksum="0" * 64, dt=0.015, n_states=2, sensor_names=[], health_names=[],
            aux_names=[],
        )
        session.add(model)
        session.flush()
        design = EstimatorDesign(
            operator_id=operator.id, engine_type_id=etype.id, engine_model_id=model.id,
            name="d", spec={}, status="ready", active=True,
        )
        upload = Upload(operator_id=operator.id, kind="snapshots", content_format="json",
                        checksum="0" * 64, status="stored")
        session.add_all([design, upload])
        session.flush()
        n_aircraft = n_engines // 2
        session.execute(insert(Aircraft), [
            {"operator_id": operator.id, "tail": f"T{a:05d}"} for a in range(n_aircraft)
        ])
        session.execute(insert(Engine), [
            {"operator_id": operator.id, "esn": f"E{e:06d}", "engine_type_id": etype.id}
            for e in range(n_engines)
        ])
        aircraft_ids = [r[0] for r in session.execute(
            text("SELECT id FROM aircraft WHERE operator_id = :o ORDER BY id"),
            {"o": operator.id})]
        engine_ids = [r[0] for r in session.execute(
            text("SELECT id FROM engines WHERE operator_id = :o ORDER BY id"), {"o": operator.id})]
        session.execute(insert(Installation), [
            {"operator_id": operator.id, "engine_id": e, "aircraft_id": aircraft_ids[i // 2],
             "position": i % 2 + 1, "installed_at": T0}
            for i, e in enumerate(engine_ids)
        ])
        common = {"operator_id": operator.id, "aircraft_id": aircraft_ids[0], "position": 1,
                  "upload_id": upload.id, "alt_ft": 0.0, "mach": 0.0, "dtamb_k": 0.0,
                  "power_pct": 100.0}
        # The trend engine: n_snapshots records, 6 h apart.
        times = [T0 + timedelta(hours=6 * i) for i in range(n_snapshots)]
        big = engine_ids[0]
        session.execute(insert(Snapshot), [
            dict(common, engine_id=big, recorded_at=t, phase="cruise") for t in times
        ])
        # Every other engine: one snapshot (its latest estimate is what fleet status reads).
        session.execute(insert(Snapshot), [
            dict(common, engine_id=e, recorded_at=T0, phase="cruise") for e in engine_ids[1:]
        ])
        values = estimates(rng, n_snapshots)
        cruise = np.full(n_snapshots, PHASES.index("cruise"))
        blobs = LAYOUT.encode(values, cruise)
        session.execute(insert(Estimate), [
            {"engine_id": big, "design_id": design.id, "seq": i, "recorded_at": times[i],
             "packed": blobs[i].tobytes()}
            for i in range(n_snapshots)
        ])
        one = LAYOUT.encode(estimates(rng, 1), cruise[:1])[0].tobytes()
        session.execute(insert(Estimate), [
            {"engine_id": e, "design_id": design.id, "seq": 0, "recorded_at": T0,
             "packed": one}
            for e in engine_ids[1:]
        ])
        session.execute(insert(FilterState), [
            {"operator_id": operator.id, "engine_id": e, "design_id": design.id,
             "layout": LAYOUT.to_dict(), "state": {"filter": {}, "detector": {}},
             "n_records": n_snapshots if e == big else 1,
             "last_recorded_at": times[-1] if e == big else T0,
             "updated_at": T0}
            for e in engine_ids
        ])
        # The storage not chosen, for comparison: the same numbers as JSON arrays.
        session.execute(text("CREATE TABLE bench_json (seq int, recorded_at timestamptz, "
                             "phase text, doc jsonb)"))
        session.execute(text("INSERT INTO bench_json VALUES (:s, :t, 'cruise', :d)"), [
            {"s": i, "t": times[i], "d": json.dumps(values[i].astype(np.float32).tolist())}
            for i in range(n_snapshots)
        ])
        session.execute(text("CREATE INDEX ON bench_json (seq)"))
        session.commit()
        session.execute(text("ANALYZE"))
        session.commit()
        return {"engine": engine, "factory": factory, "operator_id": operator.id, "key": key,
                "big": big, "aircraft": aircraft_ids[0]}


def fill_periods(ctx: dict[str, object], n_records: int) -> int:
    """Every engine's periods after ``n_records`` records 8 h apart, through the pipeline's
    bucket writer, 100 engines per transaction (as a job's batches); returns the records."""
    factory, op = ctx["factory"], ctx["operator_id"]
    rng = np.random.default_rng(2)
    epoch = T0.timestamp() + 8 * 3600.0 * np.arange(n_records)
    with factory() as s:  # type: ignore[operator]
        engine_ids = [r[0] for r in s.execute(text(
            "SELECT engine_id FROM filter_states WHERE operator_id = :o ORDER BY engine_id"),
            {"o": op})]
        design_id = s.execute(text("SELECT id FROM estimator_designs WHERE operator_id = :o"),
                              {"o": op}).scalar_one()
    for start in range(0, len(engine_ids), 100):
        collector = buckets.BucketCollector(LAYOUT)
        for e in engine_ids[start:start + 100]:
            packed = estimates(rng, n_records).astype(VALUE_DTYPE)
            collector.add((e, 0, epoch, [], packed))
        with factory() as s:  # type: ignore[operator]
            buckets.refresh(s, operator_id=op, design_id=design_id, layout=LAYOUT,  # type: ignore[arg-type]
                            collected=collector)
            s.commit()
    with factory() as s:  # type: ignore[operator]
        s.execute(text("ANALYZE deterioration_buckets"))
        s.commit()
    return len(engine_ids) * n_records


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--snapshots", type=int, default=10_000)
    parser.add_argument("--engines", type=int, default=1000)
    parser.add_argument("--repeat", type=int, default=40)
    parser.add_argument("--history", type=int, default=2000,
                        help="records per engine behind the fleet deterioration")
    args = parser.parse_args()

    name = f"fleethealth_bench_{uuid.uuid4().hex[:10]}"
    admin = create_engine(ADMIN_URL, isolation_level="AUTOCOMMIT")
    with admin.connect() as conn:
        conn.execute(text(f'CREATE DATABASE "{name}"'))
    url = make_url(ADMIN_URL).set(database=name).render_as_string(hide_password=False)
    try:
        upgrade(url)
        t = time.perf_counter()
        ctx = fill(url, args.snapshots, args.engines)
        print(f"filled {args.snapshots} estimates of one engine and {args.engines} engines "
              f"in {time.perf_counter() - t:.1f} s")
        factory, op, big = ctx["factory"], ctx["operator_id"], ctx["big"]

        def service_trend(max_points: int) -> Callable[[], object]:
            def run() -> object:
                with factory() as s:
                    return trends.engine_trend(s, op, big, max_points=max_points)
            return run

        def raw_select() -> object:
            with factory() as s:
                return s.execute(text(
                    "SELECT recorded_at, seq, packed FROM estimates "
                    "WHERE engine_id = :e ORDER BY seq"), {"e": big}).all()

        def json_storage() -> object:
            with factory() as s:
                rows = s.execute(text(
                    "SELECT recorded_at, seq, phase, doc FROM bench_json ORDER BY seq")).all()
                return np.array([r[3] for r in rows], dtype=float)

        def status() -> object:
            with factory() as s:
                return fleet_status.fleet_status(s, op)

        app = create_app(Settings(database_url=url, log_json=False, log_level="WARNING"),
                         ctx["engine"])
        from fastapi.testclient import TestClient

        headers = {"X-API-Key": ctx["key"]}
        with TestClient(app) as client:
            def http(path: str, **params: object) -> Callable[[], object]:
                def run() -> object:
                    r = client.get(path, headers=headers, params=params)
                    assert r.status_code == 200, r.text
                    return r.content
                return run

            rows = [
                ("raw SELECT of the rows (floor)", raw_select),
                ("same rows as JSON arrays (storage not chosen)", json_storage),
                ("trend service, default decimation", service_trend(trends.DEFAULT_MAX_POINTS)),
                ("trend service, all 10000 points", service_trend(0)),
                ("GET trend (HTTP, JSON), decimated", http(f"/api/v1/engines/{big}/trend")),
                ("GET trend (HTTP, JSON), all points",
                 http(f"/api/v1/engines/{big}/trend", max_points=0)),
                ("GET trend as CSV, decimated",
                 http(f"/api/v1/engines/{big}/trend", format="csv")),
            ]
            print(f"\ntrend of one engine with {args.snapshots} snapshots "
                  f"({args.repeat} runs each)")
            results = {}
            for label, fn in rows:
                fn()  # warm up
                samples = timed(fn, args.repeat)
                results[label] = samples
                print(f"  {label:48s} median {1000 * statistics.median(samples):7.1f} ms"
                      f"  p95 {1000 * p95(samples):7.1f} ms")
            floor = statistics.median(results["raw SELECT of the rows (floor)"])
            for label in ("trend service, default decimation",
                          "GET trend (HTTP, JSON), decimated"):
                print(f"  {label}: {statistics.median(results[label]) / floor:.1f}x the bare "
                      "SELECT")
            target = p95(results["GET trend (HTTP, JSON), decimated"])
            print(f"  target p95 <= 50 ms (HTTP, default decimation): {1000 * target:.1f} ms "
                  f"{'PASS' if target <= 0.050 else 'FAIL'}")

            status_http = http("/api/v1/fleet/status")
            status()
            status_http()
            s_service = timed(status, max(5, args.repeat // 4))
            s_http = timed(status_http, max(5, args.repeat // 4))
            print(f"\nfleet status of {args.engines} engines")
            print(f"  service   median {1000 * statistics.median(s_service):7.1f} ms  "
                  f"p95 {1000 * p95(s_service):7.1f} ms")
            print(f"  HTTP      median {1000 * statistics.median(s_http):7.1f} ms  "
                  f"p95 {1000 * p95(s_http):7.1f} ms")
            worst = p95(s_http)
            print(f"  target <= 300 ms (HTTP): {1000 * worst:.1f} ms "
                  f"{'PASS' if worst <= 0.300 else 'FAIL'}")

            t = time.perf_counter()
            records = fill_periods(ctx, args.history)
            print(f"\nfleet deterioration of {args.engines} engines, {records:,} records "
                  f"(periods written in {time.perf_counter() - t:.1f} s)")

            def period_rows() -> object:
                with factory() as s:
                    return s.execute(text(
                        "SELECT engine_id, start, n, sums FROM deterioration_buckets "
                        "WHERE design_id = (SELECT id FROM estimator_designs WHERE "
                        "operator_id = :o) AND period = 'week'"), {"o": op}).all()

            floor = timed(period_rows, max(5, args.repeat // 4))
            print(f"  bare SELECT of the weekly rows (floor)  median "
                  f"{1000 * statistics.median(floor):7.1f} ms")
            for bucket in ("week", "month"):
                get = http("/api/v1/fleet/deterioration", bucket=bucket)
                get()
                samples = timed(get, max(5, args.repeat // 4))
                print(f"  GET deterioration?bucket={bucket:5s} (HTTP)  median "
                      f"{1000 * statistics.median(samples):7.1f} ms  p95 "
                      f"{1000 * p95(samples):7.1f} ms  target <= 300 ms "
                      f"{'PASS' if p95(samples) <= 0.300 else 'FAIL'}")
        ctx["engine"].dispose()
    finally:
        with admin.connect() as conn:
            conn.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        admin.dispose()


if __name__ == "__main__":
    main()
