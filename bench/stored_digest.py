"""Digests of what the estimation stores for ``bench_ingest_fleet.py``'s records, to show that a
change to the estimation's code leaves every stored number as it was, bit for bit.

On a throw-away PostgreSQL database, the bench's operator (the demo's engine type, designs and
fleet) is sent the bench's warm-up records and then its ``--rows`` records through
``ingest_snapshots``, each followed by the estimation they queue (``store.catch_up``) in this
process: in two engine groups, as the job spreads them over two processes (here every group
in turn by the job's own process, in the job's order), or with ``--single`` in one call. The
CPU seconds of the second estimation are printed, then per table the row count and an MD5 of
its rows as JSON (sorted; ids and timestamps of the write left out): estimates, events, filter
states, checkpoints, deterioration periods, fleet periods, EGT windows, the backlog and the
alert levels. Run it on the code before and after a change and compare the lines:

    .venv/bin/python bench/stored_digest.py [--single] [--rows 100000]
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Sequence

import bench_ingest_fleet as fleet_bench  # imports _common first: BLAS pinned before numpy
from _common import throwaway_database
from sqlalchemy import text

from app.db import make_engine, make_sessionmaker
from app.migrate import upgrade
from app.services import fresh_records
from app.services.snapshots import estimator, groups, store
from app.services.snapshots.drifts import FleetDrifts
from app.services.uploads.store import ingest_snapshots

# Every column of these tables but those left out goes into the digests.
TABLES = ("estimates", "events", "filter_states", "filter_checkpoints",
          "deterioration_buckets", "fleet_periods", "egt_windows", "estimation_backlog",
          "engine_alert_levels")
LEFT_OUT = ("id", "created_at", "updated_at", "acknowledged_at")


class NoWorkers:
    """A launcher with a second worker that never starts a group: the job does both."""

    workers = 2

    def launch(self, operator_id: int, parts: Sequence[Sequence[int]],
               drifts: FleetDrifts) -> None:
        pass


def digests(url: str) -> list[str]:
    engine = make_engine(url)
    lines = []
    with engine.connect() as connection:
        for table in TABLES:
            columns = [c for c in connection.execute(text(
                "SELECT column_name FROM information_schema.columns WHERE table_name = :t "
                "ORDER BY ordinal_position"), {"t": table}).scalars() if c not in LEFT_OUT]
            digest, count = connection.execute(text(
                "SELECT md5(coalesce(string_agg(x, E'\\n' ORDER BY x), '')), count(*) FROM "
                f"(SELECT row_to_json(s)::text AS x FROM (SELECT {', '.join(columns)} "
                f"FROM {table}) s) q")).one()
            lines.append(f"{table:24s} {count:8d} {digest}")
    engine.dispose()
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=100_000)
    ap.add_argument("--warm", type=int, default=2000)
    ap.add_argument("--aircraft", type=int, default=25)
    ap.add_argument("--seed", type=int, default=20260101)
    ap.add_argument("--single", action="store_true", help="one estimation call, no groups")
    ap.add_argument("--data-dir", default="/tmp/fh-bench-fleet")
    args = ap.parse_args()
    os.environ["FLEETHEALTH_DATA_DIR"] = args.data_dir
    estimator.builtin_schedule()
    estimator.builtin_trim_table()
    plan, table = fleet_bench.simulate(args.aircraft, args.rows + args.warm, args.seed)
    groups.configure(None if args.single else NoWorkers())
    try:
        with throwaway_database("postgresql") as (url, _label):
            upgrade(url)
            _key, operator_id, _design_s = fleet_bench.build_operator(url, plan)
            factory = make_sessionmaker(make_engine(url))
            for part in (table.slice(0, args.warm), table.slice(args.warm)):
                with factory() as session:
                    ingest_snapshots(session, operator_id=operator_id, api_key_id=None,
                                     body=fleet_bench.csv_bodies(part, part.num_rows)[0],
                                     content_format="csv")
                    session.commit()
                with factory() as session:
                    started = time.process_time()
                    counts = store.catch_up(session, operator_id, commit=session.commit)
                    session.commit()
                    cpu = time.process_time() - started
            print(f"estimation of {args.rows} records: {cpu:.2f} s CPU, {counts}")
            print("\n".join(digests(url)))
    finally:
        groups.configure(None)
        fresh_records.clear()


if __name__ == "__main__":
    main()
