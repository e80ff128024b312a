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


def test_jsonb_objects_of_numbers_round_trip_through_postgresql(connection: Connection) -> None:
    """``other_signals``: one JSON object of numbers a row (Arrow's shortest float text), NULL
    where a row has none, read back by name as the same floats."""
    if connection.dialect.name != "postgresql":
        pytest.skip("binary COPY is PostgreSQL's")
    from app.services.encoding.json_numbers import number_objects

    rng = np.random.default_rng(3)
    n = 500
    values = {name: np.where(rng.random(n) < 0.2, np.nan, rng.normal(0, 1e4, n) * 10.0 ** (
        rng.integers(-8, 8, n))) for name in ("N1", "EGT", 'odd "name"')}
    values["N1"][:5] = np.nan  # rows of no number at all
    values["EGT"][:5] = np.nan
    values['odd "name"'][:5] = np.nan
    objects = number_objects({k: pa.array(v, from_pandas=True) for k, v in values.items()}, n)
    connection.exec_driver_sql("CREATE TEMP TABLE objects (k int4, o jsonb)")
    table = pa.table({"k": pa.array(np.arange(n), pa.int32()), "o": objects})
    driver = connection.connection.driver_connection
    with driver.cursor() as cursor:
        with cursor.copy("COPY objects (k, o) FROM STDIN (FORMAT binary)") as copy:
            copy.write(binary_copy_payload(table, {"k": "int4", "o": "jsonb"}))
    for name, expected in values.items():
        got = connection.exec_driver_sql(
            "SELECT (o ->> %(name)s)::float8 FROM objects ORDER BY k", {"name": name}).scalars()
        assert np.array_equal(np.array([np.nan if v is None else v for v in got]), expected,
                              equal_nan=True)
    nulls = connection.exec_driver_sql("SELECT count(*) FROM objects WHERE o IS NULL").scalar()
    none = np.all([np.isnan(v) for v in values.values()], axis=0)
    assert none[:5].all() and nulls == int(none.sum())
