"""Service read paths through ``fleethealth serve`` on PostgreSQL, on the product's own data:
one engine's trend over 10,000 snapshots, the fleet status, and the fleet deterioration, at
fleet sizes of 10 and 1,000 engines (``--large``: 10 / 1,000 / 10,000 / 100,000).

The records are ``fleethealth simulate --mode snapshot``'s (``estimation.engine.fleet``, the
demo's fleet settings: take-off and cruise, every engine at its own conditions, deterioration,
washes, swaps, abrupt faults; ``bench_ingest_fleet.simulate``). Each fleet is an operator of its
own in one throw-away database, with the demo's engine type and designs (the built-in engine,
the active design estimating every turbomachinery health parameter) and the demo's
installations; its records go through the product's bulk path in-process
(``bench_storage.load_copies``: ``ingest_snapshots``, then the estimation it queues,
``store.catch_up``, which stores the estimates and writes the deterioration periods). A fleet
of more than ``--base-engines`` engines is that many simulated engines copied, each copy a
fleet of its own tails and serial numbers. The trend's engine is one aircraft's engine with
``--snapshots`` records, in an operator of its own.

Then every read goes over a real socket (httpx) to ``fleethealth serve`` in its own process on
a free port (``--port`` to choose), JSON (and CSV) included, ``--repeat`` times after a warm-up.
Peers measured in the same run on the same rows, in this process:

- trend: a bare ``SELECT`` of the engine's estimate rows (the floor any trend read pays), the
  trend service called in-process (what HTTP adds), and the same numbers stored as JSON arrays
  (the storage not chosen);
- fleet status: a bare ``SELECT`` of every engine's latest estimate row, and the status
  service in-process;
- deterioration: a bare ``SELECT`` of the fleet's weekly period rows (``fleet_periods``, one
  row a week, what the route reads).

BLAS and OpenMP run one thread in this process and the server's; the load average is printed
first and last.

Targets (issue 5): trend p95 <= 50 ms; fleet status p95 <= 300 ms at 1,000 engines; (issue 17)
fleet deterioration p95 <= 300 ms at 2M records (``--engines 1000 --history 2000``, or
``--large``: 100,000 engines of 20 records).

    .venv/bin/python bench/bench_service.py [--snapshots 10000] [--engines 10,1000]
        [--history 20] [--large]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import _common
import httpx
import numpy as np
from bench_ingest_fleet import simulate
from bench_storage import load_copies
from sqlalchemy import text
from sqlalchemy.orm import sessionmaker

from app.db import make_engine, make_sessionmaker, transaction
from app.migrate import upgrade
from app.models.estimates import EstimateLayout
from app.services.demo import fleet as demo
from app.services.fleet import status as fleet_status
from app.services.tenancy import service as tenancy
from app.services.trends import service as trends

TREND_P95_S = 0.050
READ_P95_S = 0.300
STATUS_AT = 1000  # engines: the fleet status target's size


def timed(fn: Callable[[], object], repeat: int) -> list[float]:
    out = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return out


def p95(samples: list[float]) -> float:
    return float(np.percentile(samples, 95))


def line(label: str, samples: list[float], note: str = "") -> None:
    print(f"  {label:52s} median {1000 * statistics.median(samples):8.1f} ms  p95 "
          f"{1000 * p95(samples):8.1f} ms{note}")


def verdict(seconds: float, target: float) -> str:
    return f"target <= {1000 * target:.0f} ms: {'PASS' if seconds <= target else 'FAIL'}"


def operator(factory: sessionmaker[Any], name: str, plan: Any, base: Any,
             copies: int) -> tuple[int, str]:
    """An operator with the demo's engine type and designs and ``copies`` of the simulated
    fleet loaded and estimated through the product's path; (operator id, analyst key)."""
    with transaction(factory) as session:
        row = tenancy.create_operator(session, name=name)
        _key_row, key = tenancy.issue_api_key(session, operator=row, role="analyst", name="b")
        operator_id = row.id
    t0 = time.perf_counter()
    with transaction(factory) as session:
        type_id, _design = demo._designs(session, operator_id, lambda _m: None)
    print(f"{name}: the demo's engine type and designs in {time.perf_counter() - t0:.1f} s")
    load_copies(factory, operator_id, type_id, plan, base, copies)
    with factory() as session:
        session.execute(text("ANALYZE"))
        session.commit()
    return operator_id, key


def trend_reads(client: httpx.Client, factory: sessionmaker[Any], operator_id: int,
                repeat: int) -> bool:
    """The trend of the operator's engine with the most estimates, against its floors."""
    with factory() as session:
        engine_id, n = session.execute(text(
            "SELECT e.engine_id, count(*) FROM estimates e JOIN engines g ON g.id = e.engine_id "
            "WHERE g.operator_id = :o GROUP BY e.engine_id ORDER BY count(*) DESC LIMIT 1"),
            {"o": operator_id}).one()
        layout = EstimateLayout.from_dict(session.execute(text(
            "SELECT layout FROM filter_states WHERE engine_id = :e"),
            {"e": engine_id}).scalars().first())
        rows = session.execute(text(
            "SELECT seq, recorded_at, packed FROM estimates WHERE engine_id = :e ORDER BY seq"),
            {"e": engine_id}).all()
        values = layout.decode_blobs([bytes(r[2]) for r in rows]).astype(np.float32)
        session.execute(text("CREATE TABLE IF NOT EXISTS bench_json (seq int, "
                             "recorded_at timestamptz, phase text, doc jsonb)"))
        session.execute(text("INSERT INTO bench_json VALUES (:s, :t, 'cruise', :d)"), [
            {"s": r[0], "t": r[1], "d": json.dumps([None if x != x else x for x in v.tolist()])}
            for r, v in zip(rows, values, strict=True)])
        session.execute(text("CREATE INDEX ON bench_json (seq)"))
        session.commit()

    def raw_select() -> object:
        with factory() as s:
            return s.execute(text("SELECT recorded_at, seq, packed FROM estimates "
                                  "WHERE engine_id = :e ORDER BY seq"), {"e": engine_id}).all()

    def json_storage() -> object:
        with factory() as s:
            got = s.execute(text(
                "SELECT recorded_at, seq, phase, doc FROM bench_json ORDER BY seq")).all()
            return np.array([r[3] for r in got], dtype=float)

    def service(max_points: int) -> Callable[[], object]:
        def run() -> object:
            with factory() as s:
                return trends.engine_trend_json(s, operator_id, engine_id,
                                                max_points=max_points)
        return run

    def http(**params: object) -> Callable[[], object]:
        def run() -> object:
            r = client.get(f"/api/v1/engines/{engine_id}/trend", params=params)
            assert r.status_code == 200, r.text[:300]
            return r.content
        return run

    reads = [
        ("bare SELECT of the rows (floor)", raw_select),
        ("same rows as JSON arrays (storage not chosen)", json_storage),
        ("trend service in-process, default decimation", service(trends.DEFAULT_MAX_POINTS)),
        (f"trend service in-process, all {n} points", service(0)),
        ("GET trend (HTTP, JSON), decimated", http()),
        ("GET trend (HTTP, JSON), all points", http(max_points=0)),
        ("GET trend as CSV, decimated", http(format="csv")),
    ]
    print(f"\ntrend of one engine with {n:,} estimates ({repeat} runs each)")
    results = {}
    for label, fn in reads:
        fn()  # warm-up
        results[label] = timed(fn, repeat)
        line(label, results[label])
    floor = statistics.median(results["bare SELECT of the rows (floor)"])
    for label in ("trend service in-process, default decimation",
                  "GET trend (HTTP, JSON), decimated"):
        print(f"  {label}: {statistics.median(results[label]) / floor:.1f}x the bare SELECT")
    worst = p95(results["GET trend (HTTP, JSON), decimated"])
    print(f"  GET trend, decimated, p95 {1000 * worst:.1f} ms, {verdict(worst, TREND_P95_S)}")
    return worst <= TREND_P95_S


def fleet_reads(client: httpx.Client, factory: sessionmaker[Any], operator_id: int,
                repeat: int) -> bool:
    """Fleet status and deterioration of the operator's fleet, against their floors."""
    with factory() as session:
        engines, records = session.execute(text(
            "SELECT count(DISTINCT e.engine_id), count(*) FROM estimates e "
            "JOIN engines g ON g.id = e.engine_id WHERE g.operator_id = :o"),
            {"o": operator_id}).one()

    def latest_rows() -> object:
        with factory() as s:
            return s.execute(text(
                "SELECT DISTINCT ON (e.engine_id) e.engine_id, e.seq, e.packed FROM estimates e "
                "JOIN filter_states f ON f.engine_id = e.engine_id AND f.design_id = e.design_id "
                "WHERE f.operator_id = :o ORDER BY e.engine_id, e.seq DESC"),
                {"o": operator_id}).all()

    def status_service() -> object:
        with factory() as s:
            return fleet_status.fleet_status(s, operator_id)

    def period_rows() -> object:
        with factory() as s:
            return s.execute(text(
                "SELECT start, n_engines, sums, squares FROM fleet_periods "
                "WHERE operator_id = :o AND period = 'week' ORDER BY start"),
                {"o": operator_id}).all()

    def http(path: str, **params: object) -> Callable[[], object]:
        def run() -> object:
            r = client.get(path, params=params)
            assert r.status_code == 200, r.text[:300]
            return r.content
        return run

    print(f"\nfleet of {engines:,} engines, {records:,} estimated records ({repeat} runs each)")
    reads = [
        ("bare SELECT of each engine's latest estimate (floor)", latest_rows),
        ("fleet status service in-process", status_service),
        ("GET fleet/status (HTTP)", http("/api/v1/fleet/status")),
        ("bare SELECT of the fleet's weekly period rows (floor)", period_rows),
        ("GET fleet/deterioration?bucket=week (HTTP)",
         http("/api/v1/fleet/deterioration", bucket="week")),
        ("GET fleet/deterioration?bucket=month (HTTP)",
         http("/api/v1/fleet/deterioration", bucket="month")),
    ]
    ok = True
    results = {}
    for label, fn in reads:
        fn()  # warm-up
        results[label] = timed(fn, repeat)
        note = ""
        if label.startswith("GET"):
            # The issue's targets: the status at 1,000 engines, the deterioration at up to 2M
            # records; a larger fleet's status is printed against 300 ms but not counted.
            note = f"  {verdict(p95(results[label]), READ_P95_S)}"
            counted = "status" not in label or engines <= 1.5 * STATUS_AT
            if not counted:
                note += f" (the target is set at {STATUS_AT:,} engines: not counted)"
            ok &= p95(results[label]) <= READ_P95_S or not counted
        line(label, results[label], note)

    def ratio(label: str, floor: str) -> float:
        return statistics.median(results[label]) / statistics.median(results[floor])

    print(f"  GET fleet/status {ratio('GET fleet/status (HTTP)', reads[0][0]):.1f}x its floor; "
          f"GET deterioration (week) {ratio(reads[4][0], reads[3][0]):.1f}x its floor")
    return ok


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--snapshots", type=int, default=10_000,
                    help="records of the trend's engine")
    ap.add_argument("--engines", default="10,1000", help="fleet sizes, comma-separated")
    ap.add_argument("--large", action="store_true",
                    help="fleet sizes 10, 1,000, 10,000 and 100,000")
    ap.add_argument("--history", type=int, default=20, help="records per engine of the fleets")
    ap.add_argument("--base-engines", type=int, default=1000,
                    help="engines simulated; a larger fleet is copies of them")
    ap.add_argument("--repeat", type=int, default=20)
    ap.add_argument("--port", type=int, default=None, help="the server's (default: a free one)")
    ap.add_argument("--seed", type=int, default=20260101)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/fh/cache"),
                    help="the built-in engine's schedule and trim table cache")
    args = ap.parse_args()
    sizes = [10, 1000, 10_000, 100_000] if args.large else [
        int(n) for n in args.engines.split(",")]
    print(_common.load_line())
    with _common.schedule_cache(args.cache), \
            _common.throwaway_database("postgresql") as (url, _label):
        upgrade(url)
        engine = make_engine(url)
        factory = make_sessionmaker(engine)
        t0 = time.perf_counter()
        # One aircraft's engines; a swap shares its positions' records between two engines.
        plan, table = simulate(1, 3 * args.snapshots, args.seed)
        print(f"simulated {table.num_rows:,} records of one aircraft for the trend in "
              f"{time.perf_counter() - t0:.1f} s")
        trend_operator = operator(factory, "Bench Trend Air", plan, table, 1)
        fleets = []
        for size in sizes:
            simulated = min(size, args.base_engines)
            t0 = time.perf_counter()
            plan, table = simulate(max(1, simulated // 2), simulated * args.history, args.seed)
            copies = max(1, round(size / simulated))
            print(f"\nsimulated {table.num_rows:,} records of {len(plan.esns)} engines in "
                  f"{time.perf_counter() - t0:.1f} s; {copies} cop{'y' if copies == 1 else 'ies'}")
            fleets.append(operator(factory, f"Bench Fleet Air {size}", plan, table, copies))
        ok = True
        with _common.serving(url, port=args.port, schedule_cache=args.cache) as base:
            print(f"\nreads through fleethealth serve at {base} ({_common.load_line()})")
            operator_id, key = trend_operator
            with httpx.Client(base_url=base, timeout=600, headers={"X-API-Key": key}) as client:
                ok &= trend_reads(client, factory, operator_id, args.repeat)
            for operator_id, key in fleets:
                with httpx.Client(base_url=base, timeout=600,
                                  headers={"X-API-Key": key}) as client:
                    ok &= fleet_reads(client, factory, operator_id, args.repeat)
        engine.dispose()
    print(f"\nload average at the end {os.getloadavg()[0]:.2f}")
    print("PASS" if ok else "FAIL")


if __name__ == "__main__":
    main()
