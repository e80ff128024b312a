"""Bulk snapshot ingest on PostgreSQL: HTTP end to end against a raw COPY of the same rows.

A real uvicorn server on 127.0.0.1 (in a thread) serves the app on a fresh PostgreSQL
database; an httpx client uploads N snapshots in one request (CSV, then Parquet): parse,
validate, resolve to ESNs, deduplicate, COPY, commit. The peer is a raw COPY of the same rows
(already resolved, pre-rendered CSV) into the same table, committed, in the same run. Each
repetition uses fresh timestamps, so every run stores every row. Estimation is not included
yet (it runs after the upload once the pipeline hooks in).

Targets (issue 5): >= 50,000 snapshots/s end to end, and >= 30 % of the raw COPY rate.

    /work/venv/bin/python bench/bench_ingest.py [--rows 100000] [--repeat 3]
"""

from __future__ import annotations

import argparse
import io
import os
import socket
import statistics
import sys
import threading
import time
import uuid
from datetime import UTC, datetime, timedelta
from pathlib import Path

import httpx
import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq
import uvicorn
from sqlalchemy import create_engine, text
from sqlalchemy.engine import make_url

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from app.config import Settings  # noqa: E402
from app.db import make_engine, make_sessionmaker, transaction  # noqa: E402
from app.main import create_app  # noqa: E402
from app.migrate import upgrade  # noqa: E402
from app.models.ingest import SNAPSHOT_COLUMNS  # noqa: E402
from app.services import fleet, tenancy  # noqa: E402
from app.services.ingest import SNAPSHOT_PG_TYPES, snapshot_table  # noqa: E402
from app.services.pgcopy import binary_copy_payload  # noqa: E402

POSTGRES_URL = os.environ.get(
    "FLEETHEALTH_TEST_POSTGRES_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/test"
)
T0 = datetime(2020, 1, 1, tzinfo=UTC)


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def build_fleet(url: str, tails: int) -> tuple[str, dict[tuple[str, int], tuple[int, int]], int]:
    """An operator, an analyst key and ``tails`` twin-engine aircraft with engines installed."""
    engine = make_engine(url)
    with transaction(make_sessionmaker(engine)) as session:
        operator = tenancy.create_operator(session, name="Bench Air")
        _row, key = tenancy.issue_api_key(session, operator=operator, role="analyst", name="b")
        kind = fleet.create_engine_type(session, operator_id=operator.id, name="generic")
        where: dict[tuple[str, int], tuple[int, int]] = {}
        for t in range(tails):
            tail = f"B{t:04d}"
            aircraft = fleet.create_aircraft(session, operator_id=operator.id, tail=tail)
            for position in (1, 2):
                row = fleet.create_engine(
                    session,
                    operator_id=operator.id,
                    esn=f"BE{t:04d}-{position}",
                    engine_type_id=kind.id,
                )
                fleet.install(
                    session,
                    operator_id=operator.id,
                    engine_id=row.id,
                    aircraft_id=aircraft.id,
                    position=position,
                    installed_at=T0 - timedelta(days=1),
                )
                where[(tail, position)] = (row.id, aircraft.id)
        operator_id = operator.id
    engine.dispose()
    return key, where, operator_id


def snapshots(n: int, tails: int, start: datetime, seed: int) -> pa.Table:
    """``n`` snapshots spread over every engine, one per engine per 10 minutes."""
    rng = np.random.default_rng(seed)
    slot = np.arange(n)
    engines = 2 * tails
    times = np.datetime64(start.replace(tzinfo=None), "us") + (slot // engines) * np.timedelta64(
        600, "s"
    )
    tail_index = (slot % engines) // 2
    return pa.table(
        {
            "recorded_at": pa.array(times, pa.timestamp("us", tz="UTC")),
            "tail": pa.array([f"B{t:04d}" for t in tail_index]),
            "position": pa.array(1 + slot % 2),
            "phase": pa.array(np.array(["takeoff", "climb", "cruise"])[slot % 3].tolist()),
            "flight_id": pa.array([f"FL{i // 6}" for i in range(n)]),
            "alt_ft": rng.uniform(0, 39000, n),
            "mach": rng.uniform(0, 0.85, n),
            "dtamb_k": rng.normal(0, 5, n),
            "power_pct": rng.uniform(60, 100, n),
            "Wf": rng.uniform(0.5, 2.0, n),
            "Nf": rng.uniform(2000, 2400, n),
            "Nc": rng.uniform(8500, 9100, n),
            "T24": rng.uniform(600, 650, n),
            "P24": rng.uniform(18, 22, n),
            "T30": rng.uniform(1300, 1600, n),
            "Ps30": rng.uniform(300, 540, n),
            "P30": rng.uniform(300, 560, n),
            "T48": rng.uniform(1600, 1900, n),
            "P50": rng.uniform(15, 20, n),
            "T50": rng.uniform(1300, 1450, n),
            "P15": rng.uniform(20, 22, n),
        }
    )


def raw_copy_body(
    rows: pa.Table,
    where: dict[tuple[str, int], tuple[int, int]],
    operator_id: int,
    upload_id: int,
    fmt: str = "csv",
) -> bytes:
    """The same rows as the snapshots table's columns, resolved, as a COPY payload in
    ``fmt`` (csv or binary); rendering is not timed."""
    keys = list(zip(rows["tail"].to_pylist(), rows["position"].to_pylist(), strict=True))
    resolved = rows.append_column("engine_id", pa.array([where[k][0] for k in keys])).append_column(
        "aircraft_id", pa.array([where[k][1] for k in keys])
    )
    resolved = resolved.set_column(
        resolved.column_names.index("position"), "position", resolved["position"].cast(pa.int16())
    )
    table = snapshot_table(resolved, operator_id=operator_id, upload_id=upload_id)
    if fmt == "binary":
        return binary_copy_payload(table, SNAPSHOT_PG_TYPES)
    sink = io.BytesIO()
    pacsv.write_csv(table, sink, pacsv.WriteOptions(include_header=False))
    return sink.getvalue()


def raw_copy(url: str, body: bytes, fmt: str = "csv") -> float:
    """Seconds for COPY of ``body`` into snapshots and the commit."""
    import psycopg

    conninfo = make_url(url).set(drivername="postgresql").render_as_string(hide_password=False)
    with psycopg.connect(conninfo) as connection:
        started = time.perf_counter()
        with connection.cursor() as cursor:
            with cursor.copy(
                f"COPY snapshots ({', '.join(SNAPSHOT_COLUMNS)}) FROM STDIN WITH (FORMAT {fmt})"
            ) as copy:
                for offset in range(0, len(body), 1 << 20):
                    copy.write(body[offset : offset + (1 << 20)])
        connection.commit()
        return time.perf_counter() - started


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=100_000)
    ap.add_argument("--tails", type=int, default=50)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()

    name = f"fleethealth_bench_{uuid.uuid4().hex[:8]}"
    admin = create_engine(POSTGRES_URL, isolation_level="AUTOCOMMIT")
    with admin.connect() as connection:
        connection.execute(text(f'CREATE DATABASE "{name}"'))
    url = make_url(POSTGRES_URL).set(database=name).render_as_string(hide_password=False)
    server = None
    try:
        upgrade(url)
        key, where, operator_id = build_fleet(url, args.tails)
        settings = Settings(
            database_url=url, log_json=False, log_level="WARNING", data_dir=Path("/tmp/fh-bench")
        )
        port = free_port()
        server = uvicorn.Server(
            uvicorn.Config(create_app(settings), host="127.0.0.1", port=port, log_level="warning")
        )
        thread = threading.Thread(target=server.run, daemon=True)
        thread.start()
        while not server.started:
            time.sleep(0.05)

        # A placeholder upload row for the raw COPY's foreign key.
        with create_engine(url).begin() as connection:
            upload_id = connection.execute(
                text(
                    "INSERT INTO uploads (operator_id, created_at, kind, content_format, checksum,"
                    " status, rows_received, rows_stored, rows_duplicate, bytes_received,"
                    " message, errors, affected) VALUES (:o, now(), 'snapshots', 'csv', 'raw',"
                    " 'stored', 0, 0, 0, 0, 'raw COPY peer', '[]', '[]') RETURNING id"
                ),
                {"o": operator_id},
            ).scalar_one()

        n = args.rows
        print(
            f"bulk snapshot ingest: {n} snapshots per request, {2 * args.tails} engines, "
            f"PostgreSQL, uvicorn on 127.0.0.1:{port}"
        )
        times: dict[str, list[float]] = {
            "http csv": [],
            "http parquet": [],
            "raw COPY csv": [],
            "raw COPY bin": [],
        }
        sizes: dict[str, int] = {}
        base = f"http://127.0.0.1:{port}"
        with httpx.Client(base_url=base, timeout=600, headers={"X-API-Key": key}) as client:
            warm = snapshots(1000, args.tails, T0 - timedelta(hours=12), seed=99)
            sink = io.BytesIO()
            pacsv.write_csv(warm, sink)
            client.post(
                "/api/v1/snapshots/file",
                content=sink.getvalue(),
                headers={"Content-Type": "text/csv"},
            ).raise_for_status()
            epoch = 0
            for rep in range(args.repeat):
                for label in times:
                    epoch += 1
                    rows = snapshots(n, args.tails, T0 + timedelta(days=400 * epoch), seed=epoch)
                    if label.startswith("raw COPY"):
                        fmt = "binary" if label.endswith("bin") else "csv"
                        body = raw_copy_body(rows, where, operator_id, upload_id, fmt)
                        sizes[label] = len(body)
                        times[label].append(raw_copy(url, body, fmt))
                        continue
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
                    response = client.post(
                        "/api/v1/snapshots/file", content=body, headers={"Content-Type": media}
                    )
                    elapsed = time.perf_counter() - started
                    response.raise_for_status()
                    stored = response.json()["rows_stored"]
                    if stored != n:
                        raise SystemExit(f"{label}: stored {stored} of {n} rows")
                    times[label].append(elapsed)
                print(
                    f"  repetition {rep + 1}: "
                    + ", ".join(f"{k} {v[-1]:.3f} s" for k, v in times.items())
                )
        with create_engine(url).connect() as connection:
            total = connection.execute(text("SELECT count(*) FROM snapshots")).scalar_one()
        expected = 1000 + len(times) * args.repeat * n
        if total != expected:
            raise SystemExit(f"table holds {total} rows, expected {expected}")

        # The peer is the faster raw COPY of the two formats.
        raw_rate = max(n / statistics.median(times[k]) for k in ("raw COPY csv", "raw COPY bin"))
        print(
            f"  {'path':<13} {'median s':>9} {'best s':>8} {'snapshots/s':>12} "
            f"{'% of COPY':>9} {'body MB':>8}"
        )
        results = {}
        for label, values in times.items():
            rate = n / statistics.median(values)
            results[label] = rate
            print(
                f"  {label:<13} {statistics.median(values):9.3f} {min(values):8.3f} "
                f"{rate:12,.0f} {100 * rate / raw_rate:8.1f}% {sizes[label] / 1e6:8.1f}"
            )
        for label in ("http csv", "http parquet"):
            rate = results[label]
            ok = rate >= 50_000 and rate >= 0.3 * raw_rate
            print(
                f"target {label}: >= 50,000 snapshots/s and >= 30 % of raw COPY: "
                f"{rate:,.0f}/s, {100 * rate / raw_rate:.0f} % -> {'PASS' if ok else 'FAIL'}"
            )
    finally:
        if server is not None:
            server.should_exit = True
            time.sleep(0.5)
        with admin.connect() as connection:
            connection.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        admin.dispose()


if __name__ == "__main__":
    main()
