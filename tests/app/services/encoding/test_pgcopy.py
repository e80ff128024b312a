"""Binary COPY payloads: loaded by PostgreSQL, they read back as the same values as the input."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import numpy as np
import pyarrow as pa
import pytest
from sqlalchemy import Connection

from app.services.encoding.pgcopy import binary_copy_payload

TYPES = {
    "a": "int4",
    "b": "int2",
    "c": "int8",
    "t": "timestamptz",
    "label": "text",
    "x": "float8",
    "note": "text",
}


def sample(n: int, seed: int = 0) -> pa.Table:
    rng = np.random.default_rng(seed)
    times = [
        datetime(1999, 12, 31, 23, 59, tzinfo=UTC) + timedelta(seconds=37 * i) for i in range(n)
    ]
    x = rng.normal(0, 1e6, n)
    return pa.table(
        {
            "a": pa.array(rng.integers(-(2**31), 2**31 - 1, n), pa.int64()),
            "b": pa.array(rng.integers(1, 5, n), pa.int16()),
            "c": pa.array(rng.integers(-(2**62), 2**62, n), pa.int64()),
            "t": pa.array(times, pa.timestamp("us", tz="UTC")),
            "label": pa.array([("takeoff", "climb", "crüise")[i % 3] for i in range(n)]),
            "x": pa.array(np.where(np.arange(n) % 5 == 2, np.nan, x), from_pandas=True),
            "note": pa.array([None if i % 4 == 1 else "é" * (i % 7) for i in range(n)]),
        }
    )


def test_binary_payload_round_trips_through_postgresql(connection: Connection) -> None:
    if connection.dialect.name != "postgresql":
        pytest.skip("binary COPY is PostgreSQL's")
    table = sample(2000)
    columns = ", ".join(f"{name} {kind}" for name, kind in TYPES.items())
    connection.exec_driver_sql(f"CREATE TEMP TABLE copied ({columns})")
    driver = connection.connection.driver_connection
    with driver.cursor() as cursor:
        with cursor.copy(f"COPY copied ({', '.join(TYPES)}) FROM STDIN (FORMAT binary)") as copy:
            copy.write(binary_copy_payload(table, TYPES))
    rows = connection.exec_driver_sql(f"SELECT {', '.join(TYPES)} FROM copied").all()
    expected = table.to_pylist()
    assert len(rows) == len(expected)
    for row, want in zip(rows, expected, strict=True):
        assert tuple(row) == tuple(want[name] for name in TYPES)


def test_an_empty_table_is_just_header_and_trailer() -> None:
    payload = binary_copy_payload(sample(0), TYPES)
    assert payload == b"PGCOPY\n\xff\r\n\x00" + bytes(8) + b"\xff\xff"
