"""Ingest with estimation on the product's path: simulated fleet data over HTTP into
``fleethealth serve`` on PostgreSQL, against a raw binary COPY of the same rows.

The data are ``fleethealth simulate --mode snapshot``'s (``estimation.engine.fleet``: the
demo's fleet settings, take-off and cruise records, deterioration, washes, swaps and abrupt
faults) for ``--aircraft`` twin-engine aircraft, as many flights as give ``--rows`` records.
The operator's engine type is the built-in engine with the demo's designs
(``app.services.demo.fleet``; the active one estimates every turbomachinery health parameter);
building them is timed on its own, and the demo's model-error calibration is left out (it
changes the filter's numbers, not its work). The server runs on a data directory whose engine
caches (schedule, nominal trim table) are built before (timed on their own: a server builds
them once), and a first upload of ``--warm`` records, estimated before the clock starts, lets
its job process make what it keeps between jobs (the CUSUM and wear-bank designs). Then the
records go up as CSV in requests of at most ``--chunk`` records, back to back, and the time
runs from the first request to the end of the last estimation job the uploads queued (filter,
detection, isolation, estimates stored), so ingest of one request overlaps estimation of the
one before.

The peer is a raw binary COPY of the very rows the uploads stored (read back with their
timestamps moved a century on, so they do not collide) into the same table, committed, in
the same run.

Targets (issue 17): >= 50,000 records/s end to end, and >= 30 % of the raw binary COPY.

    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_ingest_fleet.py [--rows 100000] [--repeat 1]
    .venv/bin/python bench/bench_ingest_fleet.py --large      # 2,000,000 records
"""

from __future__ import annotations

import argparse
import io
import os
import sys
import time
from pathlib import Path
from typing import Any

from _common import (
    ROOT,
    cpu_by_process,
    load_line,
    postgres_backends,
    process_cpu,
    throwaway_database,
)

sys.path.insert(0, str(ROOT / "bench"))

import httpx  # noqa: E402
import numpy as np  # noqa: E402
import pyarrow as pa  # noqa: E402
import pyarrow.compute as pc  # noqa: E402
import pyarrow.csv as pacsv  # noqa: E402
from sqlalchemy import create_engine, text  # noqa: E402
from sqlalchemy.engine import make_url  # noqa: E402

from app.db import make_engine, make_sessionmaker, transaction  # noqa: E402
from app.migrate import upgrade  # noqa: E402
from app.models.ingest import SNAPSHOT_COLUMNS  # noqa: E402
from app.services.demo import fleet as demo  # noqa: E402
from app.services.demo.simulation_files import snapshot_table  # noqa: E402
from app.services.tenancy import service as tenancy  # noqa: E402
from estimation.engine.fleet import fleet_snapshots, plan_fleet  # noqa: E402
from tests.support import server  # noqa: E402

THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def threads_line() -> str:
    return ", ".join(f"{k}={os.environ.get(k, 'unset')}" for k in THREAD_VARIABLES)


def simulate(aircraft: int, rows: int, seed: int) -> tuple[Any, pa.Table]:
    """The demo's fleet of ``aircraft`` aircraft with enough flights for ``rows`` take-off and
    cruise records; the plan and the records (upload columns), the first ``rows`` by time."""
    flights = -(-rows // (4 * aircraft))
    size = demo.DemoSize(aircraft=aircraft, flights=flights, calibrate=False)
    from dataclasses import replace

    config = replace(demo.fleet_config(size), start_epoch_s=demo.demo_start_epoch(size))
    plan_rng, snap_rng = np.random.default_rng(seed).spawn(2)
    plan = plan_fleet(config, plan_rng)
    table = snapshot_table(fleet_snapshots(plan, snap_rng))
    table = table.filter(pc.is_in(table["phase"], value_set=pa.array(["takeoff", "cruise"])))
    table = table.sort_by("recorded_at").slice(0, rows)
    return plan, table


def build_operator(url: str, plan: Any) -> tuple[str, int, float]:
    """An operator with the demo's engine type, designs and fleet; (key, id, design seconds)."""
    factory = make_sessionmaker(make_engine(url))
    with transaction(factory) as session:
        operator = tenancy.create_operator(session, name="Bench Fleet Air")
        _row, key = tenancy.issue_api_key(session, operator=operator, role="analyst", name="b")
        operator_id = operator.id
    started = time.perf_counter()
    with transaction(factory) as session:
        type_id, _design_id = demo._designs(session, operator_id, lambda _m: None)
    design_s = time.perf_counter() - started
    with transaction(factory) as session:
        demo._fleet(session, operator_id, type_id, plan)
    return key, operator_id, design_s


def csv_bodies(table: pa.Table, chunk: int) -> list[bytes]:
    bodies = []
    for start in range(0, table.num_rows, chunk):
        sink = io.BytesIO()
        pacsv.write_csv(table.slice(start, chunk), sink)
        bodies.append(sink.getvalue())
    return bodies


def raw_binary_copy(url: str, operator_id: int, fmt: str = "binary", upload_id: int | None = None,
                    years: int = 100) -> tuple[float, int]:
    """Seconds for a COPY (``fmt``: binary or csv) of the operator's stored snapshots (of one
    upload if ``upload_id``; not the copies of earlier calls), ``years`` later, into the
    snapshots table and its commit; the payload is read back before the clock starts.
    Returns (seconds, payload bytes)."""
    import psycopg

    conninfo = make_url(url).set(drivername="postgresql").render_as_string(hide_password=False)
    columns = ", ".join(SNAPSHOT_COLUMNS)
    shifted = ", ".join(f"recorded_at + interval '{int(years)} years'" if c == "recorded_at"
                        else c for c in SNAPSHOT_COLUMNS)
    # The rows as stored (copies made before are a century or more later).
    which = f"operator_id = {int(operator_id)} AND recorded_at < '2100-01-01'" + (
        "" if upload_id is None else f" AND upload_id = {int(upload_id)}")
    with psycopg.connect(conninfo) as connection:
        sink = io.BytesIO()
        with connection.cursor().copy(
            f"COPY (SELECT {shifted} FROM snapshots WHERE {which}) TO STDOUT WITH (FORMAT {fmt})"
        ) as copy:
            for block in copy:
                sink.write(block)
        body = sink.getvalue()
        connection.commit()
        started = time.perf_counter()
        with connection.cursor() as cursor:
            with cursor.copy(f"COPY snapshots ({columns}) FROM STDIN WITH (FORMAT {fmt})") as copy:
                for offset in range(0, len(body), 1 << 20):
                    copy.write(body[offset: offset + (1 << 20)])
        connection.commit()
        return time.perf_counter() - started, len(body)


def wait_for_jobs(engine: Any, operator_id: int, started: float) -> None:
    """Until the operator has no queued or running job (the upload's job was queued in its
    transaction, so it is there once the response is). Polled on one connection, every 5 ms
    at first and then every 0.5 % of the time waited (at most 100 ms): the clock's resolution
    stays within 0.5 %, and the polling takes little of the CPU the timed work runs on (every
    5 ms, it took 1-2 s of CPU over a 20 s wait, on the same two cores)."""
    busy = text("SELECT count(*) FROM jobs WHERE operator_id = :o AND status IN "
                "('queued', 'running')")
    with engine.connect().execution_options(isolation_level="AUTOCOMMIT") as connection:
        while connection.execute(busy, {"o": operator_id}).scalar_one():
            waited = time.perf_counter() - started
            if waited > 600:
                raise SystemExit("the estimation job did not end")
            time.sleep(min(0.1, max(0.005, waited / 200)))


def post_all(client: httpx.Client, bodies: list[bytes]) -> None:
    for body in bodies:
        client.post("/api/v1/snapshots/file", content=body,
                    headers={"Content-Type": "text/csv"}).raise_for_status()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=100_000)
    ap.add_argument("--large", action="store_true", help="2,000,000 records")
    ap.add_argument("--aircraft", type=int, default=25)
    ap.add_argument("--chunk", type=int, default=250_000, help="records per request")
    ap.add_argument("--warm", type=int, default=2000, help="records estimated before timing")
    ap.add_argument("--seed", type=int, default=20260101)
    ap.add_argument("--port", type=int, default=None, help="the server's (default: a free one)")
    ap.add_argument("--data-dir", default="/tmp/fh-bench-fleet",
                    help="the server's data directory (its engine caches are kept)")
    args = ap.parse_args()
    n = 2_000_000 if args.large else args.rows
    os.environ["FLEETHEALTH_DATA_DIR"] = args.data_dir
    print(f"{load_line()}; {threads_line()} (the server: OMP_NUM_THREADS=1)")

    from app.services.snapshots import estimator

    started = time.perf_counter()
    estimator.builtin_schedule()
    estimator.builtin_trim_table()
    print(f"engine caches in {args.data_dir}: {time.perf_counter() - started:.1f} s "
          "(built once, then read)")
    started = time.perf_counter()
    plan, table = simulate(args.aircraft, n + args.warm, args.seed)
    warm, table = table.slice(0, args.warm), table.slice(args.warm)
    n = table.num_rows
    print(f"simulated {n} + {args.warm} records of {2 * args.aircraft} engines in "
          f"{time.perf_counter() - started:.1f} s")
    bodies = csv_bodies(table, args.chunk)
    with throwaway_database("postgresql") as (url, _label):
        upgrade(url)
        key, operator_id, design_s = build_operator(url, plan)
        print(f"the demo's engine type and designs built in {design_s:.1f} s (not timed below)")
        with server.serving(url, Path(args.data_dir), port=args.port) as (process, base):
            engine = create_engine(url)
            with httpx.Client(base_url=base, timeout=1800, headers={"X-API-Key": key}) as client:
                t0 = time.perf_counter()
                post_all(client, csv_bodies(warm, args.chunk))
                wait_for_jobs(engine, operator_id, t0)
                print(f"warm-up: {args.warm} records estimated in {time.perf_counter() - t0:.1f} s")
                with engine.connect() as connection:
                    before = connection.execute(text(
                        "SELECT coalesce(max(id), 0) FROM jobs WHERE operator_id = :o"),
                        {"o": operator_id}).scalar_one()
                cpu0 = cpu_by_process(process.pid)
                pg0 = {b: process_cpu(b) for b in postgres_backends(engine)}
                load0 = os.getloadavg()[0]
                t0 = time.perf_counter()
                post_all(client, bodies)
                posted = time.perf_counter()
                wait_for_jobs(engine, operator_id, t0)
                done = time.perf_counter()
                cpu1 = cpu_by_process(process.pid)
                cpu = sum(cpu1.values()) - sum(cpu0.values())
                roles = {p: c - cpu0.get(p, 0.0) for p, c in cpu1.items()}
                pg_cpu = sum(process_cpu(b) - pg0.get(b, 0.0) for b in postgres_backends(engine))
            with engine.connect() as connection:
                estimated = connection.execute(text(
                    "SELECT count(*) FROM estimates e JOIN engines g ON g.id = e.engine_id "
                "WHERE g.operator_id = :o"),
                    {"o": operator_id}).scalar_one() - args.warm
                ran, jobs, own, parts = connection.execute(text(
                    "SELECT coalesce(sum(extract(epoch FROM finished_at - started_at)), 0), "
                    "count(*), coalesce(sum((result->>'records')::int), 0), "
                    "max((result->>'groups')::int) FROM jobs "
                    "WHERE operator_id = :o AND id > :b"),
                    {"o": operator_id, "b": before}).one()
                failed = connection.execute(text(
                    "SELECT count(*) FROM jobs WHERE operator_id = :o AND status <> 'succeeded'"),
                    {"o": operator_id}).scalar_one()
            engine.dispose()
        copy_s, copy_bytes = raw_binary_copy(url, operator_id)
    wall = done - t0
    rate, peer = n / wall, (n + args.warm) / copy_s
    print(f"end to end: {len(bodies)} request(s) of <= {args.chunk} records answered after "
          f"{posted - t0:.2f} s, last job ended at {wall:.2f} s ({jobs} job(s) ran "
          f"{float(ran):.2f} s); server and job process CPU {cpu:.1f} s ({cpu / wall:.2f} "
          f"cores); load at start {load0:.2f}, at end {os.getloadavg()[0]:.2f}")
    print("  CPU by process: " + ", ".join(
        f"{'server' if p == process.pid else f'pid {p}'} {c:.2f} s" for p, c in roles.items())
        + f"; PostgreSQL backends {pg_cpu:.2f} s; machine CPU per 100,000 records "
        f"{(cpu + pg_cpu) * 1e5 / n:.2f} s")
    print(f"  {estimated} estimates stored of {n} records, {own} by the job's own process "
          f"({parts or 'no'} engine groups); {failed} job(s) not succeeded")
    print(f"  raw binary COPY of the same rows: {copy_s:.2f} s, {peer:,.0f} records/s, "
          f"{copy_bytes / 1e6:.1f} MB")
    ok = rate >= 50_000 and rate >= 0.3 * peer
    print(f"target: >= 50,000 records/s and >= 30 % of the raw binary COPY: {rate:,.0f} "
          f"records/s, {100 * rate / peer:.1f} % -> {'PASS' if ok else 'FAIL'}")
    if failed:
        raise SystemExit("an estimation job did not succeed")


if __name__ == "__main__":
    main()
