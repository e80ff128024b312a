"""Bulk reads of snapshots and bulk writes of estimates for the estimation pipeline.

An estimation job reads every new record of a batch of engines and writes one estimate row per
record. On PostgreSQL both move rows of one fixed width in PostgreSQL's binary encoding: the
read is one query for the whole batch whose rows (a missing sensor as NaN, the phase as a code,
the time in microseconds) are joined on the server into one bytea and parsed by one
``numpy.frombuffer``; the write is one binary ``COPY estimates FROM STDIN`` built by numpy
(the estimates in their stored form, ``EstimateLayout.encode``, have one width per layout).
No value passes through a Python object on either side. Other databases read with one
SELECT per engine and write with an executemany INSERT.
Records an upload committed in this process are taken from memory instead when they are all
there (``fresh_records``, handed in by the caller).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from contextlib import ExitStack
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from psycopg.copy import QueuedLibpqWriter
from sqlalchemy import func, insert, select
from sqlalchemy.orm import Session

from app.models import Snapshot
from app.models.estimates import STORED_PHASES, Estimate, EstimateLayout
from app.services.encoding.pgcopy import HEADER, PG_EPOCH_US, TRAILER, fixed_copy_rows
from app.signals import CONDITION_COLUMNS, PHASES, other_signal

_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
_MICROSECOND = timedelta(microseconds=1)
ESTIMATE_COLUMNS = ("recorded_at", "engine_id", "design_id", "seq", "packed")
_PHASE_INDEX = {name: i for i, name in enumerate(STORED_PHASES)}


@dataclass(frozen=True)
class Records:
    """One engine's records in time order, as columns.

    epoch [S] (seconds since 1970, UTC), phase [S] ("" where a record has none), conditions
    [S, 4] (alt_ft, mach, dtamb_k, power_pct; NaN where a record has none), y [S, ny] and
    u [S, nu] in stored units with NaN for a missing value (a column the design reads but
    snapshots do not store is all NaN).
    """

    epoch: np.ndarray
    phase: list[str]
    conditions: np.ndarray
    y: np.ndarray
    u: np.ndarray


def load_records(
    session: Session,
    wants: Sequence[tuple[int, datetime | None]],
    sensor_columns: Sequence[str],
    input_columns: Sequence[str],
    kept: pa.Table | None = None,
    expected: Mapping[int, int] | None = None,
) -> dict[int, Records]:
    """Each engine's records after its time (None: all of them), for (engine id, after) pairs.

    ``sensor_columns``/``input_columns`` name where each design signal is stored
    (``app.signals.stored_at``: a column, or ``other_signals.NAME``; "" = not stored).
    ``kept``: rows an upload committed in this process (``fresh_records``, sorted by engine
    and time, each other signal a column named as it is stored); an engine's records come
    from there when they are all there, else from the database. ``expected``: how many
    records engines are known to have after their time (the backlog's count); the others are
    counted in the database.
    """
    if not wants:
        return {}
    stored = list(dict.fromkeys(c for c in (*sensor_columns, *input_columns) if c))
    columns: dict[int, Columns] = {}
    if kept is not None:
        columns.update(_complete_kept(session, kept, wants, stored, expected or {}))
    rest = [w for w in wants if w[0] not in columns]
    if rest and session.connection().dialect.name == "postgresql":
        columns.update(_aggregated(session, rest, stored))
    else:
        columns.update({engine_id: _select(session, engine_id, after, stored)
                        for engine_id, after in rest})
    return {engine_id: _records(c, sensor_columns, input_columns)
            for engine_id, c in columns.items()}


def _records(
    columns: Columns, sensor_columns: Sequence[str], input_columns: Sequence[str]
) -> Records:
    epoch, phase, conditions, values = columns
    n = len(epoch)
    missing = np.full(n, np.nan)

    def stack(names: Sequence[str]) -> np.ndarray:
        if not names:
            return np.empty((n, 0))
        return np.column_stack([values[c] if c else missing for c in names]).reshape(
            n, len(names)
        )

    return Records(epoch, phase, conditions, stack(sensor_columns), stack(input_columns))


Columns = tuple[np.ndarray, list[str], np.ndarray, dict[str, np.ndarray]]


# Each engine with its "after" time, as a relation of the statement: two array parameters.
_WINDOW = "unnest(%(engine_ids)s::int4[], %(afters)s::timestamptz[]) AS w(engine_id, after)"


def _window_params(wants: Sequence[tuple[int, datetime | None]]) -> dict[str, list[Any]]:
    for engine_id, after in wants:
        if after is not None and after.tzinfo is None:
            raise ValueError(f"engine {engine_id}: {after!r} carries no time zone")
    return {"engine_ids": [int(e) for e, _after in wants],
            "afters": [after for _e, after in wants]}


def _count_after(
    session: Session, wants: Sequence[tuple[int, datetime | None]]
) -> dict[int, int]:
    """How many stored records each engine has after its time."""
    if not wants:
        return {}
    if session.connection().dialect.name == "postgresql":
        driver = session.connection().connection.driver_connection
        assert driver is not None
        with driver.cursor() as cursor:
            cursor.execute(
                f"SELECT w.engine_id, count(s.engine_id) FROM {_WINDOW} "
                "LEFT JOIN snapshots s ON s.engine_id = w.engine_id "
                "AND (w.after IS NULL OR s.recorded_at > w.after) GROUP BY w.engine_id",
                _window_params(wants),
            )
            return {int(e): int(n) for e, n in cursor.fetchall()}
    out = {}
    for engine_id, after in wants:
        query = select(func.count()).select_from(Snapshot).where(Snapshot.engine_id == engine_id)
        if after is not None:
            query = query.where(Snapshot.recorded_at > after)
        out[engine_id] = int(session.scalar(query) or 0)
    return out


def _complete_kept(
    session: Session, kept: pa.Table, wants: Sequence[tuple[int, datetime | None]],
    stored: Sequence[str], expected: Mapping[int, int],
) -> dict[int, Columns]:
    """From kept rows sorted by engine and time, the records of each engine that has them
    all (as many as ``expected`` says, else as the database counts after its time), as columns
    of the stored numbers."""
    engines = np.asarray(kept["engine_id"].to_numpy())
    micros = np.asarray(pc.cast(kept["recorded_at"], pa.int64()).to_numpy())
    ranges = {}
    for engine_id, after in wants:
        lo, hi = (int(i) for i in np.searchsorted(engines, [engine_id, engine_id + 1]))
        if lo == hi:
            continue
        if after is not None:
            cut = (after - _EPOCH) // _MICROSECOND
            lo += int(np.searchsorted(micros[lo:hi], cut, side="right"))
        ranges[engine_id] = (lo, hi)
    if not ranges:
        return {}
    counts = dict(expected)
    counts.update(_count_after(
        session, [w for w in wants if w[0] in ranges and w[0] not in expected]
    ))
    complete = {e: r for e, r in ranges.items() if counts.get(e) == r[1] - r[0]}
    return _table_columns(kept, complete, stored) if complete else {}


def _table_columns(
    table: pa.Table, ranges: Mapping[int, tuple[int, int]], stored: Sequence[str]
) -> dict[int, Columns]:
    """Rows ``lo:hi`` of ``table`` for each engine, as columns of the stored numbers."""
    micros = np.asarray(pc.cast(pc.cast(table["recorded_at"], pa.timestamp("us", tz="UTC")),
                                pa.int64()).to_numpy())
    phase = [p or "" for p in table["phase"].to_pylist()]
    n = table.num_rows
    values = {c: _floats(table, c) if c in table.column_names else np.full(n, np.nan)
              for c in (*CONDITION_COLUMNS, *stored)}
    conditions = np.column_stack([values[c] for c in CONDITION_COLUMNS])
    epoch = micros / 1e6
    return {
        engine_id: (epoch[lo:hi], phase[lo:hi], conditions[lo:hi],
                    {c: values[c][lo:hi] for c in stored})
        for engine_id, (lo, hi) in ranges.items()
    }


def _floats(table: pa.Table, column: str) -> np.ndarray:
    values = pc.cast(table[column], pa.float64())
    return np.asarray(values.to_numpy(zero_copy_only=False), dtype=float)  # null -> NaN


def _aggregated(
    session: Session, wants: Sequence[tuple[int, datetime | None]], stored: Sequence[str]
) -> dict[int, Columns]:
    """PostgreSQL: every engine's records as one bytea of fixed-width binary rows.

    Each row's fields go through the type's binary send function (big-endian, as in a binary
    COPY) and ``string_agg`` joins the rows on the server, so one value crosses the wire and
    one ``numpy.frombuffer`` reads it, then one sort puts them in order (a binary COPY TO
    sends a message a row: 0.6 s of Python for 100,000 rows).
    """
    phase = "CASE s.phase " + " ".join(
        f"WHEN '{name}' THEN {code}" for code, name in enumerate(PHASES)
    ) + " ELSE -1 END::int2"  # no phase: -1 (a NULL would drop the whole row from the bytea)
    fields = [
        ("engine_id", "int4send(s.engine_id)", ">i4"),
        ("micros", "int8send((extract(epoch FROM s.recorded_at) * 1000000)::int8)", ">i8"),
        ("phase", f"int2send({phase})", ">i2"),
    ]
    params: dict[str, Any] = dict(_window_params(wants))
    for c in (*CONDITION_COLUMNS, *stored):
        name = other_signal(c)
        if name is None:
            value = f"s.{c}"
        else:  # by name from the JSON document, the name a parameter
            key = f"signal_{len(params)}"
            params[key] = name
            value = f"(s.other_signals ->> %({key})s)::float8"
        fields.append((c, f"float8send(COALESCE({value}, 'NaN'))", ">f8"))
    # Unordered: the rows are put in order here (by engine and time, the table's key, so
    # the order is the same), not by a sort on the server (100,000 rows: 0.3 s there, spilled
    # to disk at the default work_mem; 10 ms here).
    query = (
        f"SELECT string_agg({' || '.join(sql for _n, sql, _w in fields)}, ''::bytea) "
        "FROM snapshots s "
        f"JOIN {_WINDOW} ON s.engine_id = w.engine_id "
        "WHERE w.after IS NULL OR s.recorded_at > w.after"
    )
    driver = session.connection().connection.driver_connection
    assert driver is not None
    with driver.cursor(binary=True) as cursor:
        cursor.execute(query, params)
        found = cursor.fetchone()
    payload = b"" if found is None or found[0] is None else bytes(found[0])
    dtype = np.dtype([(name, w) for name, _sql, w in fields])
    if len(payload) % dtype.itemsize:
        raise ValueError(f"rows of {dtype.itemsize} bytes expected, {len(payload)} bytes found")
    rows = np.frombuffer(payload, dtype=dtype)
    rows = rows[np.lexsort((rows["micros"], rows["engine_id"]))]
    engines = rows["engine_id"].astype(np.int64)
    phases = np.array([*PHASES, ""], dtype=object)  # -1: ""
    out: dict[int, Columns] = {}
    for engine_id, _after in wants:
        lo, hi = np.searchsorted(engines, [engine_id, engine_id + 1])
        part = rows[lo:hi]
        out[engine_id] = (
            part["micros"].astype(np.int64) / 1e6,
            phases[part["phase"]].tolist(),
            np.column_stack([part[c].astype(float) for c in CONDITION_COLUMNS]).reshape(
                len(part), len(CONDITION_COLUMNS)
            ),
            {c: part[c].astype(float) for c in stored},
        )
    return out


def _select(
    session: Session, engine_id: int, after: datetime | None, stored: Sequence[str]
) -> Columns:
    """Other databases: one engine's records in one SELECT, transposed once."""
    table = Snapshot.__table__
    columns = [table.c.recorded_at, table.c.phase]
    columns += [table.c[c] if other_signal(c) is None
                else table.c.other_signals[other_signal(c)].as_float()
                for c in (*CONDITION_COLUMNS, *stored)]
    query = select(*columns).where(table.c.engine_id == engine_id).order_by(table.c.recorded_at)
    if after is not None:
        query = query.where(table.c.recorded_at > after)
    rows = session.execute(query).tuples().all()
    n = len(rows)
    cols: list[Sequence[Any]] = list(zip(*rows, strict=True)) if n else [()] * len(columns)
    epoch = np.array([t.timestamp() for t in cols[0]], dtype=float)
    k = len(CONDITION_COLUMNS)
    conditions = np.array(cols[2 : 2 + k], dtype=float).reshape(k, n).T.copy()  # None: NaN
    values = {c: np.array(cols[2 + k + j], dtype=float) for j, c in enumerate(stored)}
    return epoch, [p or "" for p in cols[1]], conditions, values


def epoch_micros(epoch: np.ndarray) -> np.ndarray:
    """Seconds since 1970 (each the correctly rounded value of a whole number of
    microseconds, as ``load_records`` returns them) back to those microseconds."""
    return np.rint(np.asarray(epoch, float) * 1e6).astype(np.int64)


Block = tuple[int, int, np.ndarray, Sequence[str], np.ndarray]
"""Estimates of one engine: (engine id, first seq, epoch [n], phase [n], packed values
[n, width] as ``VALUE_DTYPE``)."""


class EstimateWriter:
    """Estimate rows written while they are computed, inside the session's transaction.

    On PostgreSQL one binary ``COPY estimates`` stays open from ``open`` to ``close``: blocks
    are encoded by numpy every ``FLUSH_ROWS`` rows and handed to psycopg's queued writer, whose
    thread sends them while the filter computes the next ones, so the server stores a batch's
    estimates alongside its computation instead of after it. The session's connection is busy
    meanwhile (no other statement until ``close``). Elsewhere the rows are INSERTed at ``close``.
    """

    FLUSH_ROWS = 20_000

    def __init__(self, session: Session, *, operator_id: int, design_id: int,
                 layout: EstimateLayout,
                 stored: Callable[[Sequence[Block], np.ndarray], None] | None = None) -> None:
        self.session = session
        self.stored = stored  # told each batch's blocks and their stored rows, as encoded
        self.operator_id = operator_id
        self.design_id = design_id
        self.layout = layout
        self.rows = 0
        self._pending: list[Block] = []
        self._pending_rows = 0
        self._copy: Any = None
        self._stack: ExitStack | None = None

    def __enter__(self) -> EstimateWriter:
        connection = self.session.connection()
        if connection.dialect.name == "postgresql":
            driver = connection.connection.driver_connection
            assert driver is not None
            statement = (
                f"COPY estimates ({', '.join(ESTIMATE_COLUMNS)}) FROM STDIN (FORMAT BINARY)"
            )
            self._stack = ExitStack()
            cursor = self._stack.enter_context(driver.cursor())
            self._copy = self._stack.enter_context(
                cursor.copy(statement, writer=QueuedLibpqWriter(cursor))
            )
            self._copy.write(HEADER)
        return self

    def add(self, block: Block) -> None:
        if not len(block[2]):
            return
        self._pending.append(block)
        self._pending_rows += len(block[2])
        self.rows += len(block[2])
        if self._copy is not None and self._pending_rows >= self.FLUSH_ROWS:
            self._flush()

    def _flush(self) -> None:
        if self._pending:
            self._copy.write(_copy_rows(self.design_id, self._pending,
                                        self._encoded(self._pending)))
        self._pending, self._pending_rows = [], 0

    def _encoded(self, blocks: Sequence[Block]) -> np.ndarray:
        stored = _stored(self.layout, blocks)
        if self.stored is not None:
            self.stored(blocks, stored)
        return stored

    def __exit__(self, kind: object, error: object, trace: object) -> None:
        if self._stack is None:
            if kind is None and self._pending:
                _insert_rows(self.session, self.design_id, self._pending,
                             self._encoded(self._pending))
            return
        try:
            if kind is None:
                self._flush()
                self._copy.write(TRAILER)
        finally:
            # An error inside aborts the COPY (psycopg), and the caller's transaction with it.
            self._stack.__exit__(kind, error, trace)  # type: ignore[arg-type]


def _stored(layout: EstimateLayout, blocks: Sequence[Block]) -> np.ndarray:
    """The blocks' estimates in their stored form: (rows, ``layout.stored_bytes``) uint8."""
    values = np.concatenate([np.asarray(b[4]) for b in blocks])
    phase = np.array([_PHASE_INDEX[p] for b in blocks for p in b[3]], dtype=np.int64)
    return layout.encode(values, phase)


def _insert_rows(session: Session, design_id: int, blocks: Sequence[Block],
                 stored: np.ndarray) -> None:
    rows = [
        {"engine_id": engine_id, "design_id": design_id, "seq": seq0 + j,
         "recorded_at": datetime.fromtimestamp(float(epoch[j]), UTC)}
        for engine_id, seq0, epoch, _phase, _values in blocks
        for j in range(len(epoch))
    ]
    for row, blob in zip(rows, stored, strict=True):
        row["packed"] = blob.tobytes()
    session.execute(insert(Estimate), rows)


def _copy_rows(design_id: int, blocks: Sequence[Block], stored: np.ndarray) -> bytes:
    """The blocks' rows of a binary COPY into ``estimates`` (no header or trailer): rows of
    one layout have one width, so one fixed-width record array holds them all."""
    engine = np.concatenate([np.full(len(b[2]), b[0], dtype=np.int64) for b in blocks])
    seq = np.concatenate([b[1] + np.arange(len(b[2]), dtype=np.int64) for b in blocks])
    micros = np.concatenate([epoch_micros(b[2]) for b in blocks]) - PG_EPOCH_US
    return fixed_copy_rows([
        ("recorded_at", micros.astype(">i8")),
        ("engine_id", engine.astype(">i4")),
        ("design_id", np.full(len(engine), design_id, dtype=">i4")),
        ("seq", seq.astype(">i4")),
        ("packed", stored),
    ])
