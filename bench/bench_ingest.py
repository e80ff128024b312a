"""Bulk snapshot ingest on PostgreSQL: HTTP end to end against a raw COPY of the same rows.

The records are ``fleethealth simulate --mode snapshot``'s (``bench_ingest_fleet.simulate``:
the demo's fleet settings for ``--aircraft`` twin-engine aircraft, take-off and cruise, every
engine at its own conditions, deterioration, washes, swaps and abrupt faults), ``--rows`` of
them. Every upload is a copy of that fleet of its own (``bench_storage.renamed``: its tails and
serial numbers suffixed, installed by the demo's ``_fleet``), so every run stores every row.

The server is ``fleethealth serve`` in its own process, as deployed (uvicorn, its job runner)
on a free port (or ``--port``) and a throw-away PostgreSQL database, dropped after; an httpx
client in this process uploads the ``--rows`` records in one request (CSV, then Parquet):
parse, validate, resolve to ESNs, deduplicate, COPY, commit. This operator's engine type (the
demo's) has no design, so the uploads queue no estimation. The peer is a raw COPY of the very
rows the CSV upload stored (read back, a century later so they do not collide) into the same
table, as CSV and as PostgreSQL binary, committed, in the same run
(``bench_ingest_fleet.raw_binary_copy``).

Then end to end with estimation: a second operator with the demo's engine type and designs
(``app.services.demo.fleet``: the built-in engine, the active design estimating every
turbomachinery health parameter) uploads the records over HTTP (CSV), and the time runs from
the request to the end of the estimation job the upload queued, which the server's job runner
starts as the upload commits (filter, detection, isolation, estimates stored).

With ``--sustained K``: a third operator uploads the same records in K consecutive uploads
(slices in time order), back to back: the time from the first request to the last estimate
stored, ingest of one upload overlapping estimation of the one before.

BLAS and OpenMP run one thread in this process and the server's; the load is printed first
and last. ``bench_ingest_fleet.py`` times the end-to-end path at larger sizes.

Targets (issue 5): >= 50,000 snapshots/s end to end (parse + validate + store + estimate), and
>= 30 % of the raw COPY rate.

    .venv/bin/python bench/bench_ingest.py [--rows 100000] [--repeat 3] [--no-estimate]
        [--sustained K] [--aircraft 25] [--port N]
"""

from __future__ import annotations

import argparse
import io
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import _common
import httpx
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq
from _common import ROOT, serving

sys.path.insert(0, str(ROOT / "bench"))

from bench_ingest_fleet import raw_binary_copy, simulate, wait_for_jobs
from bench_storage import renamed
from sqlalchemy import create_engine, text

from app.db import make_engine, make_sessionmaker, transaction
from app.migrate import upgrade
from app.services.demo import fleet as demo
from app.services.fleet import service as fleet
from app.services.tenancy import service as tenancy


def copies_operator(url: str, name: str, plan: Any, table: pa.Table, first: int, count: int,
                    designs: bool) -> tuple[str, int, list[pa.Table]]:
    """An operator with the demo's engine type (and its designs if ``designs``) and copies
    ``first`` .. ``first + count - 1`` of the simulated fleet installed; (key, id, records of
    each copy)."""
    factory = make_sessionmaker(make_engine(url))
    tables = []
    with transaction(factory) as session:
        operator = tenancy.create_operator(session, name=name)
        _row, key = tenancy.issue_api_key(session, operator=operator, role="analyst", name="b")
        if designs:
            type_id, _design = demo._designs(session, operator.id, lambda _m: None)
        else:
            type_id = fleet.create_engine_type(session, operator_id=operator.id,
                                               name=demo.ENGINE_TYPE).id
        for k in range(first, first + count):
            plan_k, table_k = renamed(plan, table, k)
            demo._fleet(session, operator.id, type_id, plan_k)
            tables.append(table_k)
        operator_id = operator.id
    return key, operator_id, tables


def csv_of(table: pa.Table) -> bytes:
    sink = io.BytesIO()
    pacsv.write_csv(table, sink)
    return sink.getvalue()


def end_to_end(url: str, base: str, args: argparse.Namespace, plan: Any, table: pa.Table,
               times: dict[str, list[float]]) -> None:
    """Upload over HTTP and wait for the estimation job the upload queued to end; adds the
    times to ``times``."""
    n = table.num_rows
    key, operator_id, tables = copies_operator(url, "Bench Estimate Air", plan, table, 100,
                                               args.repeat, designs=True)
    engine = create_engine(url)
    with httpx.Client(base_url=base, timeout=600, headers={"X-API-Key": key}) as client:
        for rep, rows in enumerate(tables):
            body = csv_of(rows)
            started = time.perf_counter()
            response = client.post("/api/v1/snapshots/file", content=body,
                                   headers={"Content-Type": "text/csv"})
            response.raise_for_status()
            stored = time.perf_counter()
            wait_for_jobs(engine, operator_id, started)
            done = time.perf_counter()
            if response.json()["rows_stored"] != n:
                raise SystemExit("end to end: upload incomplete")
            times.setdefault("http csv + estimate", []).append(done - started)
            times.setdefault("  estimate", []).append(done - stored)
            with engine.connect() as connection:
                queued, ran = connection.execute(text(
                    "SELECT extract(epoch FROM started_at - created_at), "
                    "extract(epoch FROM finished_at - started_at) FROM jobs "
                    "WHERE operator_id = :o ORDER BY id DESC LIMIT 1"), {"o": operator_id}).one()
            print(f"  end to end {rep + 1}: {done - started:.3f} s: response after "
                  f"{stored - started:.3f} s, the job waited {queued:.3f} s to start and ran "
                  f"{ran:.3f} s")
    with engine.connect() as connection:
        estimated = connection.execute(text(
            "SELECT count(*) FROM estimates e JOIN engines g ON g.id = e.engine_id "
            "WHERE g.operator_id = :o"), {"o": operator_id}).scalar_one()
        failed = connection.execute(text(
            "SELECT count(*) FROM jobs WHERE operator_id = :o AND status <> 'succeeded'"),
            {"o": operator_id}).scalar_one()
    engine.dispose()
    if estimated != args.repeat * n or failed:
        raise SystemExit(f"{estimated} estimates stored, expected {args.repeat * n}; "
                         f"{failed} job(s) not succeeded")


def sustained(url: str, base: str, args: argparse.Namespace, plan: Any, table: pa.Table,
              times: dict[str, list[float]]) -> None:
    """Uploads back to back into the server, whose job runner estimates them as they commit:
    the time from the first request to the last estimate stored, for the records in
    ``args.sustained`` uploads per repetition."""
    k = args.sustained
    key, operator_id, tables = copies_operator(url, "Bench Sustained Air", plan, table, 200,
                                               args.repeat, designs=True)
    engine = create_engine(url)

    def stored() -> int:
        with engine.connect() as connection:
            return int(connection.execute(text(
                "SELECT count(*) FROM estimates e JOIN engines g ON g.id = e.engine_id "
                "WHERE g.operator_id = :o"), {"o": operator_id}).scalar_one())

    try:
        with httpx.Client(base_url=base, timeout=600, headers={"X-API-Key": key}) as client:
            for rep, rows in enumerate(tables):
                n = rows.num_rows
                # Consecutive slices in time order: each upload continues every engine's history.
                bodies = [csv_of(rows.slice(part * n // k, (part + 1) * n // k - part * n // k))
                          for part in range(k)]
                goal = stored() + n
                started = time.perf_counter()
                for body in bodies:
                    client.post("/api/v1/snapshots/file", content=body,
                                headers={"Content-Type": "text/csv"}).raise_for_status()
                posted = time.perf_counter()
                while stored() < goal:
                    if time.perf_counter() - started > 600:
                        raise SystemExit("sustained: estimates did not arrive")
                    time.sleep(0.02)
                wait_for_jobs(engine, operator_id, started)
                done = time.perf_counter()
                times.setdefault(f"http csv + estimate, {k} uploads", []).append(done - started)
                print(f"  sustained {rep + 1}: {k} uploads posted in {posted - started:.3f} s, "
                      f"last estimate stored at {done - started:.3f} s")
    finally:
        engine.dispose()


def main() -> None:
    print(_common.load_line())
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=100_000)
    ap.add_argument("--aircraft", type=int, default=25)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-estimate", action="store_true", help="ingest alone")
    ap.add_argument("--sustained", type=int, default=0,
                    help="uploads per repetition into a server with its job runner (0: skip)")
    ap.add_argument("--port", type=int, default=None, help="the server's (default: a free one)")
    ap.add_argument("--seed", type=int, default=20260101)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/fh/cache"),
                    help="the built-in engine's schedule and trim table cache")
    args = ap.parse_args()
    t0 = time.perf_counter()
    plan, table = simulate(args.aircraft, args.rows, args.seed)
    print(f"simulated {table.num_rows:,} records of {len(plan.esns)} engines in "
          f"{time.perf_counter() - t0:.1f} s")
    with _common.schedule_cache(args.cache), \
            _common.throwaway_database("postgresql") as (url, _label):
        upgrade(url)
        # Copy 0 is the warm-up; copies 1 .. 2 * repeat the CSV and Parquet uploads.
        key, operator_id, tables = copies_operator(url, "Bench Air", plan, table, 0,
                                                   1 + 2 * args.repeat, designs=False)
        with serving(url, port=args.port, schedule_cache=args.cache) as base:
            measure(url, base, key, operator_id, tables, args, plan, table)
    print(_common.load_line())


def measure(url: str, base: str, key: str, operator_id: int, tables: list[pa.Table],
            args: argparse.Namespace, plan: Any, table: pa.Table) -> None:
    """Every measurement against the server at ``base``, then the table of results."""
    n = table.num_rows
    print(f"bulk snapshot ingest: {n:,} records per request, {len(plan.esns)} engines a copy, "
          f"PostgreSQL, fleethealth serve at {base}")
    times: dict[str, list[float]] = {
        "http csv": [],
        "http parquet": [],
        "raw COPY csv": [],
        "raw COPY bin": [],
    }
    sizes: dict[str, int] = {}
    with httpx.Client(base_url=base, timeout=600, headers={"X-API-Key": key}) as client:
        client.post("/api/v1/snapshots/file", content=csv_of(tables[0].slice(0, 1000)),
                    headers={"Content-Type": "text/csv"}).raise_for_status()
        for rep in range(args.repeat):
            csv_upload = None
            for label, rows in (("http csv", tables[1 + 2 * rep]),
                                ("http parquet", tables[2 + 2 * rep])):
                sink = io.BytesIO()
                if label == "http csv":
                    pacsv.write_csv(rows, sink)
                    media = "text/csv"
                else:
                    pq.write_table(rows, sink)
                    media = "application/vnd.apache.parquet"
                body = sink.getvalue()
                sizes[label] = len(body)
                started = time.perf_counter()
                response = client.post("/api/v1/snapshots/file", content=body,
                                       headers={"Content-Type": media})
                elapsed = time.perf_counter() - started
                response.raise_for_status()
                stored = response.json()["rows_stored"]
                if stored != n:
                    raise SystemExit(f"{label}: stored {stored} of {n} rows")
                times[label].append(elapsed)
                if label == "http csv":
                    csv_upload = response.json()["id"]
            # Centuries apart: the fleet's own records span years, at repeating times of day.
            for label, fmt, years in (("raw COPY csv", "csv", 200 * rep + 100),
                                      ("raw COPY bin", "binary", 200 * rep + 200)):
                seconds, size = raw_binary_copy(url, operator_id, fmt, csv_upload, years)
                times[label].append(seconds)
                sizes[label] = size
            print(f"  repetition {rep + 1}: "
                  + ", ".join(f"{k} {v[-1]:.3f} s" for k, v in times.items()))
    with create_engine(url).connect() as connection:
        total = connection.execute(text(
            "SELECT count(*) FROM snapshots WHERE operator_id = :o"), {"o": operator_id}
        ).scalar_one()
    expected = 1000 + len(times) * args.repeat * n
    if total != expected:
        raise SystemExit(f"table holds {total} rows, expected {expected}")
    if not args.no_estimate:
        end_to_end(url, base, args, plan, table, times)
        if args.sustained:
            sustained(url, base, args, plan, table, times)

    # The peer is the faster raw COPY of the two formats.
    raw_rate = max(n / statistics.median(times[k]) for k in ("raw COPY csv", "raw COPY bin"))
    print(f"  {'path':<13} {'median s':>9} {'best s':>8} {'snapshots/s':>12} "
          f"{'% of COPY':>9} {'body MB':>8}")
    results = {}
    for label, values in times.items():
        if label.startswith("  "):
            continue  # parts of the end-to-end figure, shown below
        rate = n / statistics.median(values)
        results[label] = rate
        print(f"  {label:<13} {statistics.median(values):9.3f} {min(values):8.3f} "
              f"{rate:12,.0f} {100 * rate / raw_rate:8.1f}% {sizes.get(label, 0) / 1e6:8.1f}")
    # Both peers: the CSV COPY loads the rows as stored; the binary COPY loads them in
    # PostgreSQL's own format, the fastest a table can be filled.
    peers = {k: n / statistics.median(times[k]) for k in ("raw COPY csv", "raw COPY bin")}
    for label in [k for k in results if k.startswith("http")]:
        rate = results[label]
        for peer, peer_rate in peers.items():
            ok = rate >= 50_000 and rate >= 0.3 * peer_rate
            print(f"target {label}: >= 50,000 snapshots/s and >= 30 % of {peer}: "
                  f"{rate:,.0f}/s, {100 * rate / peer_rate:.0f} % -> {'PASS' if ok else 'FAIL'}")
    if not args.no_estimate:
        for label in [k for k in times if k.startswith("  estimate")]:
            rate = n / statistics.median(times[label])
            print(f"  {label.strip():<22} alone: {statistics.median(times[label]):7.3f} s, "
                  f"{rate:,.0f} records/s")


if __name__ == "__main__":
    main()
