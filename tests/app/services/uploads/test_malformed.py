"""Malformed and hostile input: every kind answers a clear 4xx, never a 5xx, and stores nothing.

The cases are those an attacker or a broken client sends: numbers beyond 64 bits, JSON nested
thousands of levels deep, lone surrogates and NUL bytes in text, times at the calendar's edge,
giant CSV fields, binary garbage sent as CSV, over-long identifiers. Each runs on SQLite and on
PostgreSQL (the two fail in different places)."""

from __future__ import annotations

import json
from collections.abc import Iterator

import pytest
from fastapi.testclient import TestClient
from sqlalchemy.orm import Session

from tests.support.fleet_fixture import (
    Fleet,
    counts,
    csv_bytes,
    json_body,
    make_fleet,
    snapshot_rows,
)

JSON = {"Content-Type": "application/json"}
CSV = {"Content-Type": "text/csv"}


@pytest.fixture
def fleet_data(session: Session) -> Fleet:
    return make_fleet(session)


def _record(fleet: Fleet, **changes: object) -> bytes:
    body = json_body(snapshot_rows(2))
    body["snapshots"][0].update(changes)
    return json.dumps(body).encode()


def _raw_record(fleet: Fleet, field: str, raw: str) -> bytes:
    """A JSON body whose first record's ``field`` is the raw JSON text ``raw``."""
    body = json_body(snapshot_rows(2))
    body["snapshots"][0][field] = "@@RAW@@"
    return json.dumps(body).encode().replace(b'"@@RAW@@"', raw.encode())


def _cases(fleet: Fleet) -> Iterator[tuple[str, str, bytes, dict[str, str]]]:
    """(case, path, body, headers)."""
    js, post = JSON, "/api/v1/snapshots"
    yield "integer beyond int64 in position", post, _raw_record(fleet, "position", "9" * 30), js
    yield "integer beyond int64 in a sensor", post, _raw_record(fleet, "T30", "1" + "0" * 400), js
    yield "float overflow in a sensor", post, _raw_record(fleet, "T30", "1e999"), js
    yield "JSON nested 2,000 deep", post, b"[" * 2000 + b"]" * 2000, js
    deep = b'{"snapshots": ' + b"[" * 100_000 + b"]" * 100_000 + b"}"
    yield "JSON nested 100,000 deep", post, deep, js
    yield "position as digits beyond int64", post, _record(fleet, position="9" * 30), js
    yield "lone surrogate in flight_id", post, _raw_record(fleet, "flight_id", '"\\ud800"'), js
    yield "NUL byte in flight_id", post, _record(fleet, flight_id="F\u0000X"), js
    yield "flight_id over 64 characters", post, _record(fleet, flight_id="F" * 100_000), js
    yield "year 9999 at -14:00", post, _record(fleet, recorded_at="9999-12-31T23:59:59-14:00"), js
    yield "year 0001 at +14:00", post, _record(fleet, recorded_at="0001-01-01T00:00:00+14:00"), js
    yield "tail with NUL", post, _record(fleet, tail="N1\u000001"), js
    yield "not UTF-8", post, b'{"snapshots": [{"tail": "\xff\xfe"}]}', js
    yield "a JSON string, not an object", post, b'"snapshots"', js
    yield "empty body", post, b"", js
    table = snapshot_rows(3)
    good = csv_bytes(table)
    header, first, *rest = good.split(b"\n")
    yield "CSV field over 128 KiB", "/api/v1/snapshots/file", header + b"\n" + first.replace(
        b"N101", b"N" * 200_000, 1) + b"\n" + b"\n".join(rest), CSV
    yield "binary garbage as CSV", "/api/v1/snapshots/file", bytes(range(256)) * 64, CSV
    yield "NUL bytes in CSV", "/api/v1/snapshots/file", good.replace(b"N101", b"N1\x0001"), CSV
    yield "text/plain on the JSON route", post, _record(fleet), {"Content-Type": "text/plain"}
    yield "no content type on the JSON route", post, _record(fleet), {}


def test_malformed_bodies_get_4xx_and_store_nothing(
    client: TestClient, session: Session, fleet_data: Fleet
) -> None:
    failures = []
    for case, path, body, headers in _cases(fleet_data):
        before = counts(session, fleet_data.operator_id)
        try:
            response = client.post(path, content=body,
                                   headers={**fleet_data.analyst, **headers})
        except Exception as exc:  # the test client re-raises a server error: report it
            failures.append((case, "server error", repr(exc)[:200]))
            session.rollback()
            continue
        if not 400 <= response.status_code < 500:
            failures.append((case, response.status_code, response.text[:200]))
            continue
        error = response.json()["error"]
        if not error["message"]:
            failures.append((case, "no message"))
        if counts(session, fleet_data.operator_id) != before:
            failures.append((case, "stored something"))
    for f in failures:
        print("FAIL", f)
    assert not failures, len(failures)
