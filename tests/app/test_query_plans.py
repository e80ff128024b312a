"""Every query the API runs against a table that grows with the data is backed by an index:
PostgreSQL's plan for it, read with EXPLAIN, scans no such table from end to end.

The pages and uploads an operator uses are requested through the API on a small fleet with
estimates and events; every statement they send is recorded and explained with sequential
scans disabled (so on these few rows the planner still picks an index wherever one serves:
a "Seq Scan" that remains means no index can).
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from datetime import UTC, datetime, timedelta
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Connection, event, select

from app.models import Event
from tests.app.services.trends.test_trends import (
    LAYOUT,
    add_aircraft,
    add_engine,
    add_estimates,
    make_fleet,
)
from tests.support.builtin_fleet import coarse_schedule, seed_fleet, upload
from tests.support.fleet_fixture import csv_bytes

# Tables whose rows grow with the records uploaded (not with the fleet's size).
GROWING = ("snapshots", "estimates", "events", "filter_checkpoints", "deterioration_buckets",
           "estimation_backlog", "uploads", "stream_chunks", "stream_estimates", "egt_windows")
T0 = datetime(2026, 3, 1, tzinfo=UTC)


@pytest.fixture
def statements(connection: Connection) -> Iterator[list[tuple[str, Any]]]:
    seen: list[tuple[str, Any]] = []

    def record(_conn: Any, _cursor: Any, statement: str, parameters: Any, *_: Any) -> None:
        seen.append((statement, parameters))

    event.listen(connection, "before_cursor_execute", record)
    yield seen
    event.remove(connection, "before_cursor_execute", record)


def _leading_columns(connection: Connection) -> dict[str, tuple[str, str]]:
    """Index name -> (table, first column) of the growing tables' indexes."""
    rows = connection.exec_driver_sql(
        "SELECT i.relname, t.relname, a.attname FROM pg_index x "
        "JOIN pg_class i ON i.oid = x.indexrelid JOIN pg_class t ON t.oid = x.indrelid "
        "JOIN pg_attribute a ON a.attrelid = t.oid AND a.attnum = x.indkey[0]"
    ).all()
    return {index: (table, column) for index, table, column in rows if table in GROWING}


_INDEX_NODE = re.compile(r"(?:Index Scan|Index Only Scan) using (\S+) on (\S+)"
                         r"|Bitmap Index Scan on (\S+)")


def _unbacked(plan: str, leading: dict[str, tuple[str, str]]) -> list[str]:
    """What in ``plan`` reads a growing table whole: a sequential scan, or an index scan whose
    condition does not bound the index's first column (a walk over the whole index)."""
    problems = [f"Seq Scan on {t}" for t in GROWING if f"Seq Scan on {t}" in plan]
    lines = plan.splitlines()
    for k, line in enumerate(lines):
        found = _INDEX_NODE.search(line)
        if not found:
            continue
        index = found.group(1) or found.group(3)
        if index not in leading:
            continue
        table, column = leading[index]
        depth = len(line) - len(line.lstrip())
        condition = ""
        for detail in lines[k + 1:]:
            if "->" in detail or len(detail) - len(detail.lstrip()) <= depth:
                break
            if "Index Cond:" in detail:
                condition = detail
        if not re.search(rf"\b{column}\b", condition):
            problems.append(f"{index} on {table} without a condition on {column}")
    return problems


def _plan(connection: Connection, statement: str, parameters: Any) -> str:
    cursor = connection.connection.driver_connection.cursor()  # type: ignore[union-attr]
    try:
        cursor.execute("SET LOCAL enable_seqscan = off")
        cursor.execute("EXPLAIN " + statement, parameters)
        return "\n".join(row[0] for row in cursor.fetchall())
    finally:
        cursor.execute("SET LOCAL enable_seqscan = on")
        cursor.close()


@pytest.mark.parametrize("database_url", ["postgresql"], indirect=True)
def test_the_api_reads_growing_tables_through_indexes(
    connection: Connection, client: TestClient, session: Any,
    statements: list[tuple[str, Any]],
) -> None:
    fleet = make_fleet(session, "Plan Air")
    aircraft = add_aircraft(session, fleet, "F-PLAN")
    rng = np.random.default_rng(5)
    engines = []
    for esn in ("P1", "P2"):
        engine = add_engine(session, fleet, esn)
        times = [T0 + timedelta(hours=12 * k) for k in range(60)]
        add_estimates(session, fleet, engine, aircraft, rng.normal(size=(60, LAYOUT.width)),
                      times)
        engines.append(engine)
    session.add(Event(operator_id=fleet.operator_id, engine_id=engines[0].id,
                      design_id=fleet.design.id, seq=30, detected_at=T0 + timedelta(days=15),
                      kind="shift", status="open", magnitude=1.0, statistic=2.0, wssr={"HPC": 1.0},
                      shift={}))
    session.commit()
    headers = {"X-API-Key": fleet.key}
    statements.clear()
    engine_id = engines[0].id
    for path in (
        "/api/v1/fleet/status", "/api/v1/fleet/deterioration?bucket=week",
        "/api/v1/fleet/deterioration?bucket=month", "/api/v1/fleet/deterioration/slopes",
        f"/api/v1/engines/{engine_id}/trend",
        f"/api/v1/engines/{engine_id}/trend?health=change", f"/api/v1/engines/{engine_id}",
        "/api/v1/events", "/api/v1/events?status=active", f"/api/v1/events?engine_id={engine_id}",
        "/api/v1/uploads", f"/api/v1/aircraft/{aircraft.id}/engines",
        "/api/v1/fleet/data-coverage",
    ):
        response = client.get(path, headers=headers)
        assert response.status_code == 200, (path, response.text)
    # An installation recorded late: the snapshots of its tail position follow it.
    spare = add_engine(session, fleet, "P3")
    session.commit()
    response = client.post("/api/v1/installations", headers=headers, json={
        "engine_id": spare.id, "aircraft_id": aircraft.id, "position": 2,
        "installed_at": (T0 + timedelta(days=20)).isoformat()})
    assert response.status_code == 201, response.text
    rows = [{"recorded_at": (T0 + timedelta(days=40, minutes=k)).isoformat(), "tail": "F-PLAN",
             "position": 2, "phase": "cruise", "alt_ft": 35000.0, "mach": 0.8, "dtamb_k": 0.0,
             "power_pct": 90.0, "Nf": 2200.0 + k} for k in range(5)]
    import pyarrow as pa

    table = pa.Table.from_pylist(rows)
    response = client.post("/api/v1/snapshots/file", content=csv_bytes(table),
                           headers={**headers, "Content-Type": "text/csv"})
    assert response.status_code == 201, response.text

    scans, explained = _explain_all(connection, statements)
    assert explained > 10
    assert not scans, "\n\n".join(f"{t}: {s}\n{p}" for t, s, p in scans)


def _explain_all(
    connection: Connection, statements: list[tuple[str, Any]]
) -> tuple[list[tuple[str, str, str]], int]:
    """(problem, statement, plan) of each recorded read of a growing table that no index
    backs, and how many were explained."""
    leading = _leading_columns(connection)
    scans = []
    explained = 0
    for statement, parameters in statements:
        text = statement.lstrip().upper()
        if not text.startswith(("SELECT", "WITH", "UPDATE", "DELETE")):
            continue
        if not any(table in statement for table in GROWING):
            continue
        plan = _plan(connection, statement, parameters)
        explained += 1
        for problem in _unbacked(plan, leading):
            scans.append((problem, statement.split("\n")[0][:200], plan))
    return scans, explained


@pytest.mark.parametrize("database_url", ["postgresql"], indirect=True)
def test_egt_windows_are_kept_and_read_through_indexes(
    connection: Connection, session: Any, statements: list[tuple[str, Any]],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The built-in engine's fleet status: its EGT windows as the pipeline takes them, read
    from them, and read from the records when they are stale."""
    from sqlalchemy import delete

    from app.models.estimates import EgtWindow, FilterState
    from app.services.fleet import status
    from app.services.snapshots import egt, estimator

    monkeypatch.setattr(estimator, "builtin_schedule", coarse_schedule)
    operator_id, table = seed_fleet(session, "Plan Window Air")
    upload(session, operator_id, table)
    engines = list(session.scalars(select(FilterState.engine_id)).all())
    design_id = session.scalars(select(FilterState.design_id)).first()
    statements.clear()
    egt.refresh(session, design_id, engines)
    status.fleet_status(session, operator_id)
    kept = len(statements)
    session.execute(delete(EgtWindow))
    del statements[kept:]  # the test's own
    status.fleet_status(session, operator_id)
    texts = [s for s, _p in statements]
    assert any("egt_windows" in s for s in texts)
    assert sum("LATERAL" in s and "snapshots" in s for s in texts) == 2  # kept, then stale
    scans, explained = _explain_all(connection, statements)
    assert explained >= 4
    assert not scans, "\n\n".join(f"{t}: {s}\n{p}" for t, s, p in scans)
