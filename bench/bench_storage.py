"""Storage at fleet scale on one PostgreSQL: millions of ``fleethealth simulate`` snapshots with
their estimates; bytes per record of each table, and the fleet reads at that size.

The records are ``fleethealth simulate --mode snapshot``'s (``estimation.engine.fleet``, the
demo's fleet settings: take-off and cruise, deterioration, washes, swaps, abrupt faults) for
``--aircraft`` twin-engine aircraft, ``--base`` records; simulating takes about a millisecond a
record here, so the fleet is that simulation copied ``--records / --base`` times, each copy a
fleet of its own (its tails and engine serial numbers suffixed), all over the same period. Each
copy goes through the product's bulk path in-process: ``ingest_snapshots`` (parse, validate,
resolve, deduplicate, binary COPY into ``snapshots``, backlog) and then the estimation the
upload queues (``store.catch_up``: the snapshot filter, detection, isolation, the estimates'
binary COPY and the deterioration periods), one copy after the other; the load does not go
through HTTP (``bench_ingest_fleet.py`` times that path).

Then: each table's size per row (table + indexes + TOAST), and through ``fleethealth serve``
(its own process, on a free port or ``--port``): the fleet status (its first page, the API's
default of up to 1,000 engines, and the fleet page's page of 200) and fleet deterioration (week,
month) p95 over ``--repeat`` requests each, and the server's resident memory before and at its
peak during those reads (sampled every 5 ms from /proc).

Targets (issue 17): estimates <= 150 bytes per record; fleet status and deterioration p95 <=
300 ms; server memory at most +200 MB during any read.

BLAS and OpenMP run one thread in this process and the server's.

    .venv/bin/python bench/bench_storage.py [--records 2000000]
    .venv/bin/python bench/bench_storage.py --records 10000000
"""

from __future__ import annotations

import argparse
import io
import os
import sys
import threading
import time
from pathlib import Path
from typing import Any

from _common import ROOT, load_line, throwaway_database

sys.path.insert(0, str(ROOT / "bench"))

import httpx
import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
from bench_ingest_fleet import simulate, threads_line
from sqlalchemy import func, select, text

from app.db import make_engine, make_sessionmaker, transaction
from app.migrate import upgrade
from app.models import Operator, Snapshot
from app.services.demo import fleet as demo
from app.services.snapshots import store
from app.services.tenancy import service as tenancy
from app.services.uploads.store import ingest_snapshots
from tests.support import server

TABLES = ("estimates", "snapshots", "deterioration_buckets", "filter_checkpoints", "events")


def renamed(plan: Any, table: pa.Table, k: int) -> tuple[Any, pa.Table]:
    """Copy ``k`` of the simulated fleet: the same records on tails and engines of its own."""
    suffix = f"-{k:03d}"
    plan = plan._replace(
        esns=tuple(e + suffix for e in plan.esns),
        tails=tuple(t + suffix for t in plan.tails),
        installations=tuple(i._replace(esn=i.esn + suffix, tail=i.tail + suffix)
                            for i in plan.installations),
        washes=tuple(w._replace(esn=w.esn + suffix) for w in plan.washes),
    )
    tails = pc.binary_join_element_wise(table["tail"], pa.scalar(suffix), "")
    return plan, table.set_column(table.schema.get_field_index("tail"), "tail", tails)


def parquet(table: pa.Table) -> bytes:
    sink = io.BytesIO()
    pq.write_table(table, sink)
    return sink.getvalue()


def load_copies(factory: Any, operator_id: int, type_id: int, plan: Any, base: pa.Table,
                copies: int) -> int:
    """``copies`` copies of the simulated fleet (``renamed``) on the operator, each through the
    product's bulk path in-process: its installations (the demo's ``_fleet``), the records'
    upload (``ingest_snapshots``), then the estimation it queues (``store.catch_up``); prints
    each copy's times; returns the records loaded."""
    load_s = estimate_s = 0.0
    t_all = time.perf_counter()
    for k in range(copies):
        plan_k, table_k = renamed(plan, base, k)
        body = parquet(table_k)
        with transaction(factory) as session:
            demo._fleet(session, operator_id, type_id, plan_k)
        t0 = time.perf_counter()
        with transaction(factory) as session:
            result = ingest_snapshots(session, operator_id=operator_id, api_key_id=None,
                                      body=body, content_format="parquet")
            assert not result.replayed
        t1 = time.perf_counter()
        with transaction(factory) as session:
            store.catch_up(session, operator_id, commit=session.commit)
        t2 = time.perf_counter()
        load_s += t1 - t0
        estimate_s += t2 - t1
        done = (k + 1) * base.num_rows
        print(f"  copy {k + 1}/{copies}: stored {base.num_rows:,} in {t1 - t0:.1f} s, "
              f"estimated in {t2 - t1:.1f} s; {done:,} records after "
              f"{time.perf_counter() - t_all:.0f} s ({load_line()})", flush=True)
    n = copies * base.num_rows
    print(f"loaded {n:,} records: store {load_s:.1f} s ({n / load_s:,.0f}/s), "
          f"estimation {estimate_s:.1f} s ({n / estimate_s:,.0f}/s)")
    return n


def rss_kb(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


class Peak:
    """The peak resident memory of a process, sampled every 5 ms while running."""

    def __init__(self, pid: int) -> None:
        self.pid, self.kb = pid, rss_kb(pid)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.wait(0.005):
            self.kb = max(self.kb, rss_kb(self.pid))

    def __enter__(self) -> Peak:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def sizes(url: str) -> list[tuple[str, int, int, int, int]]:
    """(table, rows, heap bytes, index bytes, total bytes incl. TOAST) per table."""
    engine = make_engine(url)
    out = []
    with engine.connect() as connection:
        for name in TABLES:
            rows = connection.execute(text(f"SELECT count(*) FROM {name}")).scalar_one()
            heap, index, total = connection.execute(text(
                f"SELECT pg_relation_size('{name}'), pg_indexes_size('{name}'), "
                f"pg_total_relation_size('{name}')")).one()
            out.append((name, int(rows), int(heap), int(index), int(total)))
    engine.dispose()
    return out


def measure(url: str, key: str, n: int, args: argparse.Namespace) -> None:
    """Sizes per row, then the fleet reads through ``fleethealth serve`` with its memory."""
    vacuum = make_engine(url).execution_options(isolation_level="AUTOCOMMIT")
    with vacuum.connect() as connection:
        connection.execute(text("VACUUM ANALYZE"))
    vacuum.dispose()
    print("\nsize per row (table + indexes + TOAST):")
    for name, rows, heap, index, total in sizes(url):
        per = total / rows if rows else float("nan")
        print(f"  {name:22s} {rows:>11,} rows  heap {heap / 1e6:9.1f} MB  indexes "
              f"{index / 1e6:8.1f} MB  total {total / 1e6:9.1f} MB  {per:7.1f} B/row")
    est = next(s for s in sizes(url) if s[0] == "estimates")
    per_estimate = est[4] / est[1]
    print(f"  target: estimates <= 150 B per record: {per_estimate:.1f} B "
          f"{'PASS' if per_estimate <= 150 else 'FAIL'}")

    with server.serving(url, Path(args.data_dir), port=args.port) as (process, base_url):
        with httpx.Client(base_url=base_url, timeout=600,
                          headers={"X-API-Key": key}) as client:
            reads = [("fleet status", "/api/v1/fleet/status", {}),
                     ("fleet status, 200 a page", "/api/v1/fleet/status", {"limit": 200}),
                     ("deterioration, week", "/api/v1/fleet/deterioration",
                      {"bucket": "week"}),
                     ("deterioration, month", "/api/v1/fleet/deterioration",
                      {"bucket": "month"})]
            for _label, path, params in reads:  # warm-up
                client.get(path, params=params).raise_for_status()
            rss0 = rss_kb(process.pid)
            print(f"\nreads through fleethealth serve at {n:,} records ({load_line()}); "
                  f"server RSS before {rss0 / 1024:.0f} MB")
            worst = 0.0
            with Peak(process.pid) as peak:
                for label, path, params in reads:
                    samples = []
                    for _ in range(args.repeat):
                        t = time.perf_counter()
                        r = client.get(path, params=params)
                        samples.append(time.perf_counter() - t)
                        r.raise_for_status()
                    p95 = float(np.percentile(samples, 95))
                    worst = max(worst, p95)
                    print(f"  GET {label:24s} median {1000 * np.median(samples):7.1f} ms "
                          f"p95 {1000 * p95:7.1f} ms  target <= 300 ms "
                          f"{'PASS' if p95 <= 0.300 else 'FAIL'}  ({len(r.content):,} B)")
            grown = (peak.kb - rss0) / 1024
            print(f"  server RSS peak during the reads {peak.kb / 1024:.0f} MB: "
                  f"+{grown:.0f} MB, target <= +200 MB {'PASS' if grown <= 200 else 'FAIL'}")


def existing(args: argparse.Namespace) -> None:
    """Sizes and reads of a database an earlier run of this bench filled (and left)."""
    os.environ["FLEETHEALTH_DATA_DIR"] = args.data_dir
    print(f"{load_line()}; {threads_line()} (the server: OMP_NUM_THREADS=1)")
    factory = make_sessionmaker(make_engine(args.existing))
    with transaction(factory) as session:
        operator = session.scalar(select(Operator).where(Operator.name == "Bench Storage Air"))
        assert operator is not None, "not a database of this bench"
        _row, key = tenancy.issue_api_key(session, operator=operator, role="analyst", name="r")
        n = session.scalar(select(func.count()).select_from(Snapshot)) or 0
    print(f"an earlier run's database: {n:,} records")
    measure(args.existing, key, n, args)
    print(f"done ({load_line()})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--records", type=int, default=2_000_000)
    ap.add_argument("--base", type=int, default=200_000, help="records simulated")
    ap.add_argument("--aircraft", type=int, default=25, help="aircraft simulated")
    ap.add_argument("--repeat", type=int, default=20)
    ap.add_argument("--port", type=int, default=None, help="the server's (default: a free one)")
    ap.add_argument("--seed", type=int, default=20260101)
    ap.add_argument("--data-dir", default="/tmp/fh-bench-storage",
                    help="the server's data directory (its engine caches are kept)")
    ap.add_argument("--keep", action="store_true",
                    help="leave the database filled (its URL is printed) for --existing")
    ap.add_argument("--existing", default=None,
                    help="measure a database this bench filled (its URL; a run stopped early)")
    args = ap.parse_args()
    if args.existing:
        existing(args)
        return
    os.environ["FLEETHEALTH_DATA_DIR"] = args.data_dir
    print(f"{load_line()}; {threads_line()} (the server: OMP_NUM_THREADS=1)")
    from app.services.snapshots import estimator

    started = time.perf_counter()
    estimator.builtin_schedule()
    estimator.builtin_trim_table()
    print(f"engine caches in {args.data_dir}: {time.perf_counter() - started:.1f} s")
    started = time.perf_counter()
    plan, base = simulate(args.aircraft, args.base, args.seed)
    copies = max(1, -(-args.records // base.num_rows))
    print(f"simulated {base.num_rows:,} records of {len(plan.esns)} engines in "
          f"{time.perf_counter() - started:.1f} s; {copies} copies: "
          f"{copies * base.num_rows:,} records")
    with throwaway_database("postgresql", prefix="h_storage_bench", keep=args.keep) as (
        url, _label
    ):
        if args.keep:
            print(f"database (kept): {url}")
        upgrade(url)
        factory = make_sessionmaker(make_engine(url))
        with transaction(factory) as session:
            operator = tenancy.create_operator(session, name="Bench Storage Air")
            _row, key = tenancy.issue_api_key(session, operator=operator, role="analyst",
                                              name="b")
            operator_id = operator.id
        with transaction(factory) as session:
            type_id, _design = demo._designs(session, operator_id, lambda _m: None)
        n = load_copies(factory, operator_id, type_id, plan, base, copies)
        measure(url, key, n, args)
        print(f"done ({load_line()})")


if __name__ == "__main__":
    main()
