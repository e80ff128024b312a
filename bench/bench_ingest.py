"""Bulk snapshot ingest on PostgreSQL: HTTP end to end against a raw COPY of the same rows.

The server is ``fleethealth serve`` in its own process, as deployed (uvicorn, the in-process
job runner, on a fresh PostgreSQL database); an httpx client in this process uploads N
snapshots in one request (CSV, then Parquet): parse, validate, resolve to ESNs, deduplicate,
COPY, commit. The peer is a raw COPY of the same rows (already resolved, pre-rendered CSV or
binary) into the same table, committed, in the same run. Each repetition uses fresh
timestamps, so every run stores every row.

Then end to end with estimation: a second operator whose engine type has an active design (the
reference linear model, six tuners) uploads N snapshots over HTTP (CSV), and the time runs
from the request to the end of the estimation job the upload queued, which the server's job
runner starts as the upload commits (filter, detection, isolation, estimates stored). Its
sensor values sit near the model's trims with sensor noise, so the detector runs as on a
healthy fleet.

With ``--sustained K``: a third operator uploads the same number of snapshots in K
consecutive uploads, back to back: the time from the first request to the last estimate
stored, ingest of one upload overlapping estimation of the one before.

Targets (issue 5): >= 50,000 snapshots/s end to end (parse + validate + store + estimate), and
>= 30 % of the raw COPY rate.

    .venv/bin/python bench/bench_ingest.py [--rows 100000] [--repeat 3] [--no-estimate]
"""

from __future__ import annotations

import argparse
import io
import os
import statistics
import sys
import time
import uuid
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq
from sqlalchemy import create_engine, text
from sqlalchemy.engine import make_url

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from _common import serving  # noqa: E402

from app.db import make_engine, make_sessionmaker, transaction  # noqa: E402
from app.migrate import upgrade  # noqa: E402
from app.models.ingest import SNAPSHOT_COLUMNS  # noqa: E402
from app.services.encoding.pgcopy import binary_copy_payload  # noqa: E402
from app.services.fleet import service as fleet  # noqa: E402
from app.services.snapshots import estimator  # noqa: E402
from app.services.tenancy import service as tenancy  # noqa: E402
from app.services.uploads.store import SNAPSHOT_PG_TYPES, snapshot_table  # noqa: E402
from tests.estimation.models import reference_model  # noqa: E402
from tests.support.fleet_fixture import add_reference_design  # noqa: E402

POSTGRES_URL = os.environ.get(
    "FLEETHEALTH_TEST_POSTGRES_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/test"
)
T0 = datetime(2020, 1, 1, tzinfo=UTC)


def build_fleet(
    url: str, tails: int, name: str = "Bench Air"
) -> tuple[str, dict[tuple[str, int], tuple[int, int]], int]:
    """An operator, an analyst key and ``tails`` twin-engine aircraft with engines installed."""
    engine = make_engine(url)
    with transaction(make_sessionmaker(engine)) as session:
        operator = tenancy.create_operator(session, name=name)
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


def add_design(url: str, operator_id: int) -> estimator.SnapshotEstimator:
    """The reference linear model and an active six-tuner design on the operator's engine type
    (the one ``build_fleet`` made); returns the estimator the pipeline will build from them."""
    result = add_reference_design(url, operator_id)
    return estimator.build_estimator(0, reference_model(), result)


def healthy_snapshots(
    n: int, tails: int, start: datetime, seed: int, est: estimator.SnapshotEstimator
) -> pa.Table:
    """``snapshots`` with the design's sensors and actuators at their trims plus 0.1 % noise,
    and no other signal."""
    rows = snapshots(n, tails, start, seed)
    rng = np.random.default_rng(seed + 10_000)
    g = est.schedule(np.zeros((1, 4)))
    by_column = {spec.column: name for name, spec in estimator.SNAPSHOT_SIGNALS.items()}
    for columns, trims in ((est.sensor_columns, g.y_trim[0]), (est.input_columns, g.u_trim[0])):
        for column, trim in zip(columns, trims, strict=True):
            if column:
                name = by_column[column]
                values = trim * (1.0 + 0.001 * rng.normal(size=n))
                at = rows.schema.get_field_index(name)
                rows = (rows.set_column(at, name, pa.array(values)) if at >= 0
                        else rows.append_column(name, pa.array(values)))
    # Only the engine type's parameters: its model's sensors and inputs (other signals of the
    # catalogue are refused for this type).
    mine = set(est.sensor_columns) | set(est.input_columns)
    return rows.select([name for name in rows.column_names
                        if name not in estimator.SNAPSHOT_SIGNALS
                        or estimator.SNAPSHOT_SIGNALS[name].column in mine])


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


def end_to_end(
    url: str, base: str, args: argparse.Namespace, times: dict[str, list[float]], epoch: int
) -> None:
    """Upload over HTTP and wait for the estimation job the upload queued to end; adds the
    times to ``times``."""
    n = args.rows
    key, _where, operator_id = build_fleet(url, args.tails, name="Bench Estimate Air")
    est = add_design(url, operator_id)
    engine = create_engine(url)
    with httpx.Client(base_url=base, timeout=600, headers={"X-API-Key": key}) as client:
        for rep in range(args.repeat):
            epoch += 1
            rows = healthy_snapshots(n, args.tails, T0 + timedelta(days=400 * epoch), epoch, est)
            sink = io.BytesIO()
            pacsv.write_csv(rows, sink)
            started = time.perf_counter()
            response = client.post(
                "/api/v1/snapshots/file", content=sink.getvalue(),
                headers={"Content-Type": "text/csv"},
            )
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
                "WHERE g.operator_id = :o"), {"o": operator_id}
        ).scalar_one()
    engine.dispose()
    if estimated != args.repeat * n:
        raise SystemExit(f"{estimated} estimates stored, expected {args.repeat * n}")


def wait_for_jobs(engine: Any, operator_id: int, started: float) -> None:
    """Until the operator has no queued or running job (polled every 5 ms; the upload's job
    was queued in its transaction, so it is there once the response is)."""
    while True:
        with engine.connect() as connection:
            busy = connection.execute(text(
                "SELECT count(*) FROM jobs WHERE operator_id = :o AND status IN "
                "('queued', 'running')"), {"o": operator_id}).scalar_one()
        if not busy:
            return
        if time.perf_counter() - started > 600:
            raise SystemExit("the estimation job did not end")
        time.sleep(0.005)


def sustained(
    url: str, args: argparse.Namespace, times: dict[str, list[float]], epoch: int
) -> None:
    """Uploads back to back into a server whose in-process job runner estimates them as they
    commit (``fleethealth serve``): the time from the first request to the last estimate
    stored, for ``args.rows`` snapshots in ``args.sustained`` uploads per repetition."""
    n, k = args.rows, args.sustained
    key, _where, operator_id = build_fleet(url, args.tails, name="Bench Sustained Air")
    est = add_design(url, operator_id)
    engine = create_engine(url)

    def stored() -> int:
        with engine.connect() as connection:
            return int(connection.execute(text(
                "SELECT count(*) FROM estimates e JOIN engines g ON g.id = e.engine_id "
                "WHERE g.operator_id = :o"), {"o": operator_id}
            ).scalar_one())

    def idle() -> bool:
        with engine.connect() as connection:
            return not connection.execute(text(
                "SELECT count(*) FROM jobs WHERE operator_id = :o AND status IN "
                "('queued', 'running')"), {"o": operator_id}).scalar_one()

    try:
        with serving(url) as base, httpx.Client(base_url=base, timeout=600,
                                                 headers={"X-API-Key": key}) as client:
            for rep in range(args.repeat):
                epoch += 1
                rows = healthy_snapshots(n, args.tails, T0 + timedelta(days=400 * epoch),
                                         epoch, est)
                # Consecutive slices: each upload continues every engine's history.
                bodies = []
                for part in range(k):
                    sink = io.BytesIO()
                    pacsv.write_csv(rows.slice(part * n // k, n // k), sink)
                    bodies.append(sink.getvalue())
                goal = stored() + n
                started = time.perf_counter()
                for body in bodies:
                    client.post("/api/v1/snapshots/file", content=body,
                                headers={"Content-Type": "text/csv"}).raise_for_status()
                posted = time.perf_counter()
                while stored() < goal or not idle():
                    if time.perf_counter() - started > 600:
                        raise SystemExit("sustained: estimates did not arrive")
                    time.sleep(0.02)
                done = time.perf_counter()
                times.setdefault(f"http csv + estimate, {k} uploads", []).append(done - started)
                print(f"  sustained {rep + 1}: {k} uploads posted in {posted - started:.3f} s, "
                      f"last estimate stored at {done - started:.3f} s")
    finally:
        engine.dispose()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=100_000)
    ap.add_argument("--tails", type=int, default=50)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-estimate", action="store_true", help="ingest alone")
    ap.add_argument("--sustained", type=int, default=0,
                    help="uploads per repetition into a server with its job runner (0: skip)")
    args = ap.parse_args()

    name = f"fleethealth_bench_{uuid.uuid4().hex[:8]}"
    admin = create_engine(POSTGRES_URL, isolation_level="AUTOCOMMIT")
    with admin.connect() as connection:
        connection.execute(text(f'CREATE DATABASE "{name}"'))
    url = make_url(POSTGRES_URL).set(database=name).render_as_string(hide_password=False)
    try:
        upgrade(url)
        key, where, operator_id = build_fleet(url, args.tails)
        with serving(url) as base:
            measure(url, base, key, where, operator_id, args)
    finally:
        with admin.connect() as connection:
            connection.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        admin.dispose()


def measure(
    url: str, base: str, key: str, where: dict[tuple[str, int], tuple[int, int]],
    operator_id: int, args: argparse.Namespace,
) -> None:
    """Every measurement against the server at ``base``, then the table of results."""

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
        f"PostgreSQL, fleethealth serve at {base}"
    )
    times: dict[str, list[float]] = {
        "http csv": [],
        "http parquet": [],
        "raw COPY csv": [],
        "raw COPY bin": [],
    }
    sizes: dict[str, int] = {}
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
    if not args.no_estimate:
        end_to_end(url, base, args, times, epoch)
        if args.sustained:
            sustained(url, args, times, epoch + 10 * args.repeat)

    # The peer is the faster raw COPY of the two formats.
    raw_rate = max(n / statistics.median(times[k]) for k in ("raw COPY csv", "raw COPY bin"))
    print(
        f"  {'path':<13} {'median s':>9} {'best s':>8} {'snapshots/s':>12} "
        f"{'% of COPY':>9} {'body MB':>8}"
    )
    results = {}
    for label, values in times.items():
        if label.startswith("  "):
            continue  # parts of the end-to-end figure, shown below
        rate = n / statistics.median(values)
        results[label] = rate
        print(
            f"  {label:<13} {statistics.median(values):9.3f} {min(values):8.3f} "
            f"{rate:12,.0f} {100 * rate / raw_rate:8.1f}% {sizes.get(label, 0) / 1e6:8.1f}"
        )
    # Both peers: the CSV COPY loads the rows as uploaded; the binary COPY loads them
    # re-encoded in PostgreSQL's own format, the fastest a table can be filled.
    peers = {k: n / statistics.median(times[k]) for k in ("raw COPY csv", "raw COPY bin")}
    for label in [k for k in results if k.startswith("http")]:
        rate = results[label]
        for peer, peer_rate in peers.items():
            ok = rate >= 50_000 and rate >= 0.3 * peer_rate
            print(
                f"target {label}: >= 50,000 snapshots/s and >= 30 % of {peer}: "
                f"{rate:,.0f}/s, {100 * rate / peer_rate:.0f} % -> {'PASS' if ok else 'FAIL'}"
            )
    if not args.no_estimate:
        for label in [k for k in times if k.startswith("  estimate")]:
            rate = n / statistics.median(times[label])
            print(f"  {label.strip():<22} alone: {statistics.median(times[label]):7.3f} s, "
                  f"{rate:,.0f} records/s")


if __name__ == "__main__":
    main()
