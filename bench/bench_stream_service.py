"""Stream estimation through ``fleethealth serve`` on a real socket: a simulated flight uploaded
as CSV and estimated by the server's job, and the same flight as live chunks.

The server runs in its own process as deployed (uvicorn, its job runner) on its own port
(a free one, or ``--port``) and a throw-away database (SQLite file, PostgreSQL database,
dropped after). The operator's engine type is the demo's built-in engine with the demo's active
design (made by the product's design service, as the demo makes it); the built-in engine's
schedule is read from the cache (``--cache``), so neither process builds it.

The flight: one of ``fleethealth simulate --mode stream``'s whole-flight CSV files of the
built-in engine (20 Hz, the first ``--seconds`` of the flight: ground idle, take-off, climb).
Ground idle is cut (the filter only predicts there: ``bench_stream_filter.filterable``); the
bench first sends the flight as simulated, ground idle included, and prints what the server's
job made of it. Then, over HTTP (httpx, real sockets):

1. warm-up: the flight uploaded for one engine and estimated (the job process's first run
   loads the schedule and computes the gains: printed as the cold figure);
2. whole flight: the same file for another engine, ``POST /api/v1/streams``; the job the
   upload queued estimates it (reads the Parquet chunk, trims and deviations, the scheduled
   filter, one-second window rows stored); the clock runs from the POST until
   ``GET /streams/{id}/estimates`` reports every sample estimated (polled every 10 ms);
3. live: the same samples for a third engine as ``--chunk-s`` chunks (``POST /streams/live``,
   ``POST /streams/{id}/chunks``) sent back to back, each until its estimates can be read.

Figures per sample (microseconds) against the core filter alone on the same samples in this
process: ``filter_piece`` over the flight with the same estimator (the gains cached), and
``filter_inputs`` (trims, deviations) beside it; the job's own run time from its row. The
live rows are compared with the whole file's (the same stored windows).

BLAS and OpenMP run one thread in both processes; the load average is printed first and last.

    .venv/bin/python bench/bench_stream_service.py [--backends sqlite,postgresql] [--port N]
        [--seconds 600] [--chunk-s 30]
"""

from __future__ import annotations

import argparse
import io
import time
from datetime import UTC, datetime
from pathlib import Path

import _common
import httpx
import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
from bench_stream_filter import filterable
from sqlalchemy import select

from app.db import make_engine, make_sessionmaker
from app.migrate import upgrade
from app.models import Job
from app.services.fleet import service as fleet
from app.services.streams.estimator import StreamEstimator, estimator_for
from app.services.streams.run import Carry, filter_inputs, filter_piece
from app.services.tenancy.service import create_operator, issue_api_key
from app.services.uploads.parse import ParsedTable, parse_body

TAILS = ("N0", "N1", "N2", "N3")  # as simulated; warm-up; whole flight; live


def setup(url: str, signals: list[str]) -> tuple[int, str, StreamEstimator]:
    """Operator, analyst key, the demo's engine type and active design, one engine on each of
    ``TAILS``; returns (operator id, key, the stream estimator the job will build)."""
    engine = make_engine(url)
    with make_sessionmaker(engine)() as session, session.begin():
        operator = create_operator(session, name="Bench Stream Air")
        _row, key = issue_api_key(session, operator=operator, role="analyst", name="bench")
        kind, design = _common.demo_design(session, operator.id)
        for i, tail in enumerate(TAILS):
            aircraft = fleet.create_aircraft(session, operator_id=operator.id, tail=tail)
            row = fleet.create_engine(session, operator_id=operator.id, esn=f"SE{i}",
                                      engine_type_id=kind)
            fleet.install(session, operator_id=operator.id, engine_id=row.id,
                          aircraft_id=aircraft.id, position=1,
                          installed_at=datetime(2025, 1, 1, tzinfo=UTC))
        est = estimator_for(session, design, signals)
        operator_id = operator.id
    engine.dispose()
    return operator_id, key, est


def job_runs(url: str, operator_id: int, recording_id: int) -> list[Job]:
    """The estimation jobs of one recording, oldest first."""
    engine = make_engine(url)
    with make_sessionmaker(engine)() as session:
        jobs = [j for j in session.scalars(
            select(Job).where(Job.operator_id == operator_id, Job.kind == "estimate_recording")
            .order_by(Job.id)) if j.parameters.get("recording_id") == recording_id]
        session.expunge_all()
    engine.dispose()
    return jobs


def wait_estimated(client: httpx.Client, rid: int, n: int, url: str, operator_id: int,
                   timeout: float = 600.0) -> bool:
    """Poll the recording's estimates every 10 ms until ``n`` samples are estimated (True), or
    until its job failed (False)."""
    t0 = time.perf_counter()
    while True:
        got = client.get(f"/api/v1/streams/{rid}/estimates", params={"max_points": 10})
        got.raise_for_status()
        if got.json()["n_samples_estimated"] >= n:
            return True
        jobs = job_runs(url, operator_id, rid) if time.perf_counter() - t0 > 1.0 else []
        if jobs and all(j.status == "failed" for j in jobs):
            return False
        if time.perf_counter() - t0 > timeout:
            raise SystemExit(f"recording {rid}: not estimated within {timeout:g} s")
        time.sleep(0.01)


def csv_of(table: pa.Table) -> bytes:
    sink = io.BytesIO()
    pacsv.write_csv(table, sink)
    return sink.getvalue()


def after_idle(est: StreamEstimator, raw: bytes,
               parsed: ParsedTable) -> tuple[pa.Table, float, int]:
    """The flight file as simulated, its rows from the first filterable sample (ground idle
    cut: ``bench_stream_filter.filterable``), time from zero; (rows, dt, samples cut)."""
    dt = float(np.median(np.diff(parsed.table["time_s"].to_numpy())))
    cond, _dy, _du = filter_inputs(est, parsed.table)
    cut = filterable(est, cond, dt)
    sent = pacsv.read_csv(io.BytesIO(raw)).slice(cut)
    t_col = sent.schema.get_field_index("time_s")
    return sent.set_column(t_col, "time_s", pa.array(np.arange(sent.num_rows) * dt)), dt, cut


def run(url: str, label: str, args: argparse.Namespace) -> bool:
    upgrade(url)
    path, entry = _common.simulated_streams(args.aircraft, args.seconds, args.seed)[0]
    raw = path.read_bytes()
    parsed = parse_body(raw, "csv", kind="stream")
    operator_id, key, est = setup(url, sorted(parsed.signals))
    sent, dt, cut = after_idle(est, raw, parsed)
    body = csv_of(sent)
    n = sent.num_rows
    started = datetime.fromisoformat(str(entry["started_at"]).replace("Z", "+00:00"))
    print(f"\n== {label}: flight {entry['flight_id']} of {args.seconds:g} s at {1 / dt:g} Hz "
          f"({parsed.num_rows:,} samples as simulated); {cut:,} samples of ground idle cut, "
          f"{n:,} sent ({len(body) / 1e6:.1f} MB CSV)")

    def upload(client: httpx.Client, tail: str, content: bytes) -> tuple[int, float]:
        t0 = time.perf_counter()
        r = client.post("/api/v1/streams", content=content, headers={"Content-Type": "text/csv"},
                        params={"tail": tail, "position": 1, "started_at": started.isoformat()})
        assert r.status_code == 201, r.text[:300]
        return r.json()["recording"]["id"], time.perf_counter() - t0

    with _common.serving(url, port=args.port, schedule_cache=args.cache) as base, \
            httpx.Client(base_url=base, timeout=600, headers={"X-API-Key": key}) as client:
        rid_raw, _ = upload(client, TAILS[0], raw)
        ok_raw = wait_estimated(client, rid_raw, parsed.num_rows, url, operator_id)
        jobs = job_runs(url, operator_id, rid_raw)
        error = (jobs[-1].error or "").strip().splitlines() if jobs else []
        print(f"as simulated (ground idle included): estimated {ok_raw}; job "
              f"{jobs[-1].status if jobs else 'none'}"
              f"{': ' + error[-1][:160] if error else ''}")

        t0 = time.perf_counter()
        rid_warm, _ = upload(client, TAILS[1], body)
        wait_estimated(client, rid_warm, n, url, operator_id)
        t_cold = time.perf_counter() - t0

        t0 = time.perf_counter()
        rid, t_post = upload(client, TAILS[2], body)
        ok = wait_estimated(client, rid, n, url, operator_id)
        t_whole = time.perf_counter() - t0
        job = job_runs(url, operator_id, rid)[-1]
        t_job = ((job.finished_at - job.started_at).total_seconds()
                 if job.finished_at and job.started_at else float('nan'))
        whole = client.get(f"/api/v1/streams/{rid}/estimates",
                           params={"max_points": 100_000}).json()

        opened = client.post("/api/v1/streams/live", json={
            "tail": TAILS[3], "position": 1, "started_at": started.isoformat(), "dt_s": dt})
        opened.raise_for_status()
        live_id = opened.json()["id"]
        per = int(round(args.chunk_s / dt))
        latencies = []
        t0 = time.perf_counter()
        for index, lo in enumerate(range(0, n, per)):
            part = csv_of(sent.slice(lo, per))
            t1 = time.perf_counter()
            r = client.post(f"/api/v1/streams/{live_id}/chunks", params={"index": index},
                            content=part, headers={"Content-Type": "text/csv"})
            assert r.status_code == 201, r.text[:300]
            ok &= wait_estimated(client, live_id, min(n, lo + per), url, operator_id)
            latencies.append(time.perf_counter() - t1)
        t_live = time.perf_counter() - t0
        live = client.get(f"/api/v1/streams/{live_id}/estimates",
                          params={"max_points": 100_000}).json()

    # The core filter alone on the same samples, this process, the same estimator (warm).
    stored = parse_body(body, "csv", kind="stream").table
    carry = Carry(np.zeros(est.n), np.zeros(est.model.n_inputs), None, 0)
    cond, dy, du = filter_inputs(est, stored)
    filter_piece(est, dt, cond, dy, du, carry)  # the gains, once
    t_inputs = _common.best_time(lambda: filter_inputs(est, stored), repeat=3)
    t_core = _common.best_time(lambda: filter_piece(est, dt, cond, dy, du, carry), repeat=3)

    def us(t: float, samples: int = n) -> str:
        return f"{1e6 * t / samples:7.2f} us a sample  {samples / t:11,.0f} samples/s"

    lat = np.array(latencies)
    diff = max(float(np.nanmax(np.abs(np.array(whole["h_hat"][k], float)
                                      - np.array(live["h_hat"][k], float))))
               for k in whole["h_hat"])
    print(f"  cold (first job: schedule, gains)      {t_cold:7.3f} s  {us(t_cold)}")
    print(f"  whole flight, POST to estimates read   {t_whole:7.3f} s  {us(t_whole)}  "
          f"{t_whole / t_core:6.1f}x the core filter")
    print(f"    of which the upload (HTTP, parse, store) {t_post:.3f} s, the job's run "
          f"{t_job:.3f} s ({us(t_job)}, {t_job / t_core:.1f}x the core filter)")
    print(f"  live, {len(lat)} chunks of {args.chunk_s:g} s back to back {t_live:7.3f} s  "
          f"{us(t_live)}  {t_live / t_core:6.1f}x the core filter; a chunk's POST to its "
          f"estimates read: p50 {1e3 * np.median(lat):.0f} ms, p95 "
          f"{1e3 * np.percentile(lat, 95):.0f} ms")
    print(f"  core filter alone (filter_piece)       {t_core:7.3f} s  {us(t_core)}")
    print(f"  inputs alone (filter_inputs)           {t_inputs:7.3f} s  {us(t_inputs)}")
    print(f"  live windows == whole file's: {len(live['t_s'])} and {len(whole['t_s'])} windows, "
          f"max |health diff| {diff:.1e}")
    return ok and len(live["t_s"]) == len(whole["t_s"]) and diff < 1e-6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--backends", default="sqlite,postgresql")
    ap.add_argument("--port", type=int, default=None, help="the server's (default: a free one)")
    ap.add_argument("--seconds", type=float, default=600.0, help="simulated seconds of flight")
    ap.add_argument("--aircraft", type=int, default=8,
                    help="aircraft of the simulated pool (bench_stream_filter's; the first flight)")
    ap.add_argument("--chunk-s", type=float, default=30.0)
    ap.add_argument("--seed", type=int, default=20260101)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/fh/cache"),
                    help="the built-in engine's schedule cache")
    args = ap.parse_args()
    with _common.schedule_cache(args.cache):
        _common.run_on_backends(args.backends, lambda url, label: run(url, label, args))


if __name__ == "__main__":
    main()
