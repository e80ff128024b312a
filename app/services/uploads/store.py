"""Store a validated snapshot batch, all or nothing, and keep uploads idempotent.

An upload is identified twice: by the SHA-256 of its body and options (the same bytes twice
replay the first upload's result and store nothing) and by the client's ``Idempotency-Key``
(the same key with other content is a 409). Rows are resolved to the engine installed at their
tail, position and time (``fleet.resolve_engines``); a row that resolves nowhere rejects the
batch. Rows already stored under ``(engine_id, recorded_at)`` with the same values are skipped;
with other values they are a 409. New rows go in by COPY on PostgreSQL and executemany on
SQLite, inside the caller's transaction: the caller commits or rolls back everything.

The estimation pipeline starts from ``UploadResult.affected`` (stored on the upload row):
every engine with new rows and the earliest new ``recorded_at`` of each.
"""

from __future__ import annotations

import functools
import hashlib
import json
import sqlite3
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from datetime import UTC, datetime, timedelta
from typing import Any, NamedTuple, TypeVar

import numpy as np
import psycopg
import pyarrow as pa
import pyarrow.compute as pc
from psycopg.copy import QueuedLibpqWriter
from sqlalchemy import DateTime, select, type_coerce
from sqlalchemy import exc as sa_exc
from sqlalchemy.orm import Session

from app.db import record_after_rollback
from app.errors import Conflict, NotFound, ServiceError
from app.models import Aircraft, Engine, Snapshot, Upload
from app.models.ingest import SNAPSHOT_COLUMNS
from app.services import common, fresh_records
from app.services.encoding.json_numbers import number_objects
from app.services.encoding.pgcopy import HEADER, TRAILER, binary_copy_rows
from app.services.fleet import service as fleet
from app.services.fleet.parameter_sets import (
    CATALOGUE,
    ParameterSet,
    parameter_sets,
    stored_spec,
)
from app.services.snapshots import backlog
from app.services.uploads import back_dating, parameters
from app.services.uploads.origin import UploadOrigin, stamp
from app.services.uploads.parse import (
    MAX_ERRORS,
    SNAPSHOT_KEYS,
    ErrorLimitReached,
    ErrorLog,
    ParsedTable,
    RowError,
    UploadRejected,
    parse_body,
)
from app.signals import OPERATING_CONDITION, OTHER_SIGNALS, SIGNALS, other_signal, stored_at

COPY_BATCH_ROWS = 20_000
# Unique violations surface from SQLAlchemy, or from the drivers under COPY / executemany.
INTEGRITY_ERRORS = (sa_exc.IntegrityError, psycopg.IntegrityError, sqlite3.IntegrityError)
_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
_US = timedelta(microseconds=1)


@dataclass(frozen=True)
class AffectedEngine:
    """An engine that received new snapshots: the pipeline re-runs it from ``earliest``."""

    engine_id: int
    esn: str
    rows: int
    earliest: datetime
    latest: datetime

    def as_json(self) -> dict[str, Any]:
        data = asdict(self)
        data["earliest"] = self.earliest.isoformat()
        data["latest"] = self.latest.isoformat()
        return data

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> AffectedEngine:
        return cls(
            engine_id=int(data["engine_id"]),
            esn=str(data["esn"]),
            rows=int(data["rows"]),
            earliest=datetime.fromisoformat(data["earliest"]),
            latest=datetime.fromisoformat(data["latest"]),
        )


@dataclass(frozen=True)
class UploadResult:
    """The stored upload and whether this request replayed an earlier identical one."""

    upload: Upload
    replayed: bool

    @property
    def affected(self) -> list[AffectedEngine]:
        return [AffectedEngine.from_json(a) for a in self.upload.affected or []]


# ------------------------------------------------------------------------- idempotency


def content_checksum(body: bytes, *, kind: str, content_format: str, options: Any = None) -> str:
    """SHA-256 over the kind, format, options (column mapping, metadata) and the body."""
    digest = hashlib.sha256()
    header = json.dumps([kind, content_format, options], sort_keys=True, default=str)
    digest.update(header.encode())
    digest.update(b"\0")
    digest.update(body)
    return digest.hexdigest()


def find_replay(
    session: Session,
    *,
    operator_id: int,
    kind: str,
    checksum: str,
    idempotency_key: str | None,
) -> Upload | None:
    """The stored upload this request repeats, or None; 409 for a reused key on new content."""
    if idempotency_key is not None:
        earlier = session.scalar(
            select(Upload).where(
                Upload.operator_id == operator_id,
                Upload.idempotency_key == idempotency_key,
                Upload.status == "stored",
            )
        )
        if earlier is not None:
            if earlier.checksum != checksum:
                raise Conflict(
                    f"Idempotency-Key {idempotency_key!r} was used for different content "
                    f"(upload {earlier.id}); nothing was stored",
                    details=[{"upload_id": earlier.id, "reason": "idempotency key reused"}],
                )
            return earlier
    return session.scalar(
        select(Upload)
        .where(
            Upload.operator_id == operator_id,
            Upload.checksum == checksum,
            Upload.kind == kind,
            Upload.status == "stored",
        )
        .order_by(Upload.id)
        .limit(1)
    )


def stored_error(detail: dict[str, Any], fallback: str) -> dict[str, Any]:
    """A refusal's detail as kept with the upload: row, column and a reason always (the
    error's message where the detail has none, e.g. a chunk sent out of order), other keys
    as they were."""
    row = detail.get("row")
    column = detail.get("column")
    return {
        **detail,
        "row": row if isinstance(row, int) and not isinstance(row, bool) else None,
        "column": column if isinstance(column, str) else None,
        "reason": str(detail.get("reason") or fallback),
    }


def record_rejection(
    session: Session,
    *,
    operator_id: int,
    api_key_id: int | None,
    kind: str,
    content_format: str,
    checksum: str,
    idempotency_key: str | None,
    bytes_received: int,
    error: ServiceError,
    origin: UploadOrigin | None = None,
) -> Upload:
    """Keep a refused upload in the history (its rows are not stored), with its errors."""
    details = [
        stored_error(d, error.message) for d in error.details if isinstance(d, dict)
    ][:MAX_ERRORS]
    upload = Upload(
        operator_id=operator_id,
        api_key_id=api_key_id,
        kind=kind,
        content_format=content_format,
        checksum=checksum,
        idempotency_key=idempotency_key,
        status="rejected",
        bytes_received=bytes_received,
        message=error.message[:500],
        errors=details,
        affected=[],
    )
    stamp(session, upload, origin, api_key_id)
    session.add(upload)
    session.flush()
    return upload


T = TypeVar("T")


def store_or_reject(
    session: Session,
    *,
    operator_id: int,
    api_key_id: int | None,
    kind: str,
    content_format: str | None,
    body: bytes,
    idempotency_key: str | None,
    store: Callable[[], T],
    origin: UploadOrigin | None = None,
) -> T:
    """Run ``store``; a refused upload (a ``ServiceError`` other than ``NotFound``) is rolled
    back entirely by the request's unit of work, which then keeps it in the history
    (``record_rejection``) and commits that; the error's message names the upload."""
    try:
        return store()
    except ServiceError as exc:
        if isinstance(exc, NotFound):
            raise
        fmt = content_format or "unknown"
        error = exc  # ``exc`` is unbound once the except clause ends; the record runs later

        def record(rolled_back: Session) -> None:
            upload = record_rejection(
                rolled_back,
                operator_id=operator_id,
                api_key_id=api_key_id,
                kind=kind,
                content_format=fmt,
                checksum=content_checksum(body, kind=kind, content_format=fmt),
                idempotency_key=idempotency_key,
                bytes_received=len(body),
                error=error,
                origin=origin,
            )
            error.message = f"{error.message} [upload {upload.id}]"

        record_after_rollback(session, record)
        raise


# ------------------------------------------------------------------------------ ingest


def ingest_snapshots(
    session: Session,
    *,
    operator_id: int,
    api_key_id: int | None,
    body: bytes,
    content_format: str,
    mapping: Mapping[str, str | None] | None = None,
    idempotency_key: str | None = None,
    origin: UploadOrigin | None = None,
    lateness: timedelta = back_dating.LATENESS,
) -> UploadResult:
    """Parse, validate, resolve, deduplicate and store one snapshot upload; records
    recorded more than ``lateness`` before it arrived count as late (``rows_late``).

    Raises UploadRejected (422) naming rows, columns and reasons, or Conflict (409); in
    both cases nothing is stored (the caller rolls back and may ``record_rejection``).
    """
    options = {"mapping": dict(mapping)} if mapping else None
    checksum = content_checksum(
        body, kind="snapshots", content_format=content_format, options=options
    )
    earlier = find_replay(
        session,
        operator_id=operator_id,
        kind="snapshots",
        checksum=checksum,
        idempotency_key=idempotency_key,
    )
    if earlier is not None:
        return UploadResult(earlier, replayed=True)
    parsed = parse_body(body, content_format, kind="snapshots", mapping=mapping, by_type=True)
    typed = parameters.check_parameters(
        session, resolve_rows(session, operator_id=operator_id, parsed=parsed), parsed)
    rows = typed.table
    replay = functools.partial(
        find_replay, session, operator_id=operator_id, kind="snapshots", checksum=checksum,
        idempotency_key=idempotency_key,
    )
    try:
        # A savepoint: when a concurrent identical upload wins the race, this one's failed
        # insert is undone and the transaction can still read the winner (a replay).
        with session.begin_nested():
            fresh, duplicates = drop_stored(session, rows)
            if fresh.num_rows == 0:
                # Every row is stored: by an identical upload committed since the check above?
                earlier = replay()
                if earlier is not None:
                    return UploadResult(earlier, replayed=True)
            upload = _store_snapshots(
                session, fresh, operator_id=operator_id, api_key_id=api_key_id,
                content_format=content_format, checksum=checksum,
                idempotency_key=idempotency_key, rows_received=parsed.num_rows,
                duplicates=duplicates, bytes_received=len(body), origin=origin,
                lateness=lateness,
            )
    except INTEGRITY_ERRORS as exc:
        # A concurrent upload stored some of these rows (or took the key) first: the same
        # content is a replay of it (READ COMMITTED sees its commit now), other content a 409.
        earlier = replay()
        if earlier is not None:
            return UploadResult(earlier, replayed=True)
        raise Conflict(
            "another upload stored some of these snapshots or used this Idempotency-Key at "
            "the same time; nothing was stored, send it again",
            details=[{"reason": str(exc).splitlines()[0][:300]}],
        ) from None
    return UploadResult(upload, replayed=False)


def _store_snapshots(
    session: Session,
    fresh: pa.Table,
    *,
    operator_id: int,
    api_key_id: int | None,
    content_format: str,
    checksum: str,
    idempotency_key: str | None,
    rows_received: int,
    duplicates: int,
    bytes_received: int,
    origin: UploadOrigin | None = None,
    lateness: timedelta = back_dating.LATENESS,
) -> Upload:
    """Insert the upload row and its new snapshots, mark the engines' backlog; flag it
    back-dated when it reaches before an engine's last estimated record, and count its late
    records (``back_dating``)."""
    upload = Upload(
        operator_id=operator_id,
        api_key_id=api_key_id,
        kind="snapshots",
        content_format=content_format,
        checksum=checksum,
        idempotency_key=idempotency_key,
        status="stored",
        rows_received=rows_received,
        rows_stored=fresh.num_rows,
        rows_duplicate=duplicates,
        bytes_received=bytes_received,
        message=f"stored {fresh.num_rows} of {rows_received} snapshots"
        + (f" ({duplicates} were stored already)" if duplicates else ""),
        errors=[],
    )
    stamp(session, upload, origin, api_key_id)
    session.add(upload)
    session.flush()
    affected = record_affected(session, upload, fresh)
    upload.rows_late = back_dating.late_rows(fresh, upload.created_at, lateness)
    if fresh.num_rows:
        insert_snapshots(session, fresh, operator_id=operator_id, upload_id=upload.id)
        backlog.mark(session, operator_id, {a.engine_id: (a.earliest, a.rows)
                                            for a in affected})
    session.flush()
    return upload


def resolve_rows(session: Session, *, operator_id: int, parsed: ParsedTable) -> pa.Table:
    """Add ``engine_id`` and ``aircraft_id`` to every row (and its 1-based ``row``).

    A tail the operator does not have (another operator's tails included: they are not
    visible) or a position with no engine installed at the row's time rejects the upload.
    """
    table = parsed.table
    n = table.num_rows
    tails = table["tail"].combine_chunks()
    encoded = pc.dictionary_encode(tails)
    names = encoded.dictionary.to_pylist()
    codes = encoded.indices.to_numpy(zero_copy_only=False)
    aircraft: dict[str, int] = {
        tail: aircraft_id
        for tail, aircraft_id in session.execute(
            select(Aircraft.tail, Aircraft.id).where(
                Aircraft.operator_id == operator_id, Aircraft.tail.in_(names)
            )
        )
    }
    aircraft_of_code = np.array([aircraft.get(name, -1) for name in names], dtype=np.int64)
    aircraft_ids = aircraft_of_code[codes]
    positions = table["position"].to_numpy(zero_copy_only=False).astype(np.int64)
    times = table["recorded_at"].to_numpy(zero_copy_only=False).astype("datetime64[us]")
    engine_ids = fleet.resolve_engines_coded(session, operator_id, names, codes, positions, times)
    unresolved = engine_ids == fleet.NO_ENGINE
    if unresolved.any():
        tail_values = np.asarray(names, dtype=object)[codes]
        log = ErrorLog()
        try:
            for index in np.flatnonzero(unresolved):
                tail = tail_values[index]
                if aircraft_ids[index] < 0:
                    reason = f"no aircraft with tail {tail!r} in your fleet"
                    column = "tail"
                else:
                    when = _iso(times[index])
                    reason = (
                        f"no engine installed at {tail!r} position {positions[index]} at {when}"
                    )
                    column = "position"
                log.add(int(index) + 1, column, reason)
        except ErrorLimitReached:
            pass
        raise UploadRejected(log.errors, truncated=log.truncated)
    return (
        table.append_column("engine_id", pa.array(engine_ids))
        .append_column("aircraft_id", pa.array(aircraft_ids))
        .append_column("row", pa.array(np.arange(1, n + 1)))
    )


def _iso(value: np.datetime64) -> str:
    return np.datetime_as_string(value, unit="s") + "Z"


_COMPARED = ("aircraft_id", "position", "phase", "flight_id") + tuple(s.name for s in SIGNALS)
_ID_CHUNK = 5000
# Columns of resolved rows that are no signal (``resolve_rows``).
_RESOLVED = ("engine_id", "aircraft_id", "row")
_CATALOGUE_NAMES = frozenset(s.name for s in SIGNALS)


def other_signals(rows: pa.Table) -> list[str]:
    """The signal columns of ``rows`` outside the catalogue (stored in ``other_signals``)."""
    return [name for name in rows.column_names
            if name not in _CATALOGUE_NAMES and name not in SNAPSHOT_KEYS
            and name not in _RESOLVED]


def drop_stored(session: Session, rows: pa.Table) -> tuple[pa.Table, int]:
    """Rows not stored yet, and how many were stored already with the same values.

    A stored row under the same (engine_id, recorded_at) with any other value is a 409: the
    upload would silently lose a correction, so the client has to say what it means.
    """
    engine_ids = rows["engine_id"].to_numpy(zero_copy_only=False)
    unique_ids = np.unique(engine_ids).tolist()
    lo = pc.min(rows["recorded_at"]).as_py()
    hi = pc.max(rows["recorded_at"]).as_py()
    columns = [getattr(Snapshot, s.column) for s in SIGNALS]
    stored: dict[tuple[int, int], tuple[Any, ...]] = {}
    for start in range(0, len(unique_ids), _ID_CHUNK):
        result = session.execute(
            select(
                Snapshot.engine_id,
                Snapshot.recorded_at,
                Snapshot.upload_id,
                Snapshot.aircraft_id,
                Snapshot.position,
                Snapshot.phase,
                Snapshot.flight_id,
                *columns,
                Snapshot.other_signals,
            ).where(
                Snapshot.engine_id.in_(unique_ids[start : start + _ID_CHUNK]),
                Snapshot.recorded_at >= lo,
                Snapshot.recorded_at <= hi,
            )
        )
        for row in result:
            stored[(row[0], (row[1] - _EPOCH) // _US)] = tuple(row[2:])
    if not stored:
        return rows, 0
    micros = pc.cast(rows["recorded_at"], pa.int64()).to_numpy(zero_copy_only=False)
    keys = list(zip(engine_ids.tolist(), micros.tolist(), strict=True))
    matched = [i for i, key in enumerate(keys) if key in stored]
    if not matched:
        return rows, 0
    others = other_signals(rows)
    present = [name for name in _COMPARED if name in rows.column_names] + others
    mine = rows.take(pa.array(matched)).select(present).to_pylist()
    conflicts: list[RowError] = []
    for index, values in zip(matched, mine, strict=True):
        theirs = stored[keys[index]]
        upload_id, their_values = theirs[0], dict(zip(_COMPARED, theirs[1:-1], strict=True))
        their_values.update({name: (theirs[-1] or {}).get(name) for name in others})
        # A column the upload does not have says nothing; one it has must match (null too).
        different = [name for name in present if values[name] != their_values[name]]
        if different and len(conflicts) < MAX_ERRORS:
            conflicts.append(
                RowError(
                    index + 1,
                    different[0],
                    f"a different snapshot of this engine at this time is stored already "
                    f"(upload {upload_id}; differs in {', '.join(different[:5])})",
                )
            )
    if conflicts:
        raise Conflict(
            f"upload conflicts with stored snapshots: row {conflicts[0].row}: "
            f"{conflicts[0].reason}; nothing was stored",
            details=[c.as_dict() for c in conflicts],
        )
    keep = np.ones(rows.num_rows, dtype=bool)
    keep[matched] = False
    return rows.filter(pa.array(keep)), len(matched)


def record_affected(session: Session, upload: Upload, rows: pa.Table) -> list[AffectedEngine]:
    """The engines that ``rows`` (stored by ``upload``) touch, written on the upload with how
    far each one's estimates went, and whether the upload is back-dated (holds records older
    than an engine's last estimated one)."""
    affected = summarise(session, rows)
    until = back_dating.estimated_until(session, (a.engine_id for a in affected))
    upload.affected = [
        {**a.as_json(), "estimated_until": until[a.engine_id].isoformat()}
        if a.engine_id in until else a.as_json()
        for a in affected
    ]
    upload.back_dated = any(
        a.engine_id in until and a.earliest < until[a.engine_id] for a in affected
    )
    return affected


def summarise(session: Session, rows: pa.Table) -> list[AffectedEngine]:
    """Per engine with new rows: count, earliest and latest recorded_at."""
    if rows.num_rows == 0:
        return []
    engine_ids = rows["engine_id"].to_numpy(zero_copy_only=False)
    micros = pc.cast(rows["recorded_at"], pa.int64()).to_numpy(zero_copy_only=False)
    ids, inverse, counts = np.unique(engine_ids, return_inverse=True, return_counts=True)
    earliest = np.full(ids.shape, np.iinfo(np.int64).max)
    latest = np.full(ids.shape, np.iinfo(np.int64).min)
    np.minimum.at(earliest, inverse, micros)
    np.maximum.at(latest, inverse, micros)
    esn: dict[int, str] = {
        engine_id: serial
        for engine_id, serial in session.execute(
            select(Engine.id, Engine.esn).where(Engine.id.in_(ids.tolist()))
        )
    }
    return [
        AffectedEngine(
            engine_id=int(i),
            esn=esn[int(i)],
            rows=int(c),
            earliest=_EPOCH + int(e) * _US,
            latest=_EPOCH + int(la) * _US,
        )
        for i, c, e, la in zip(ids, counts, earliest, latest, strict=True)
    ]


def snapshot_table(rows: pa.Table, *, operator_id: int, upload_id: int) -> pa.Table:
    """The rows as the ``snapshots`` table's columns, in ``SNAPSHOT_COLUMNS`` order: a column
    the rows do not have is null (the phase and operating condition of a type not scheduled on
    them too), signals outside the catalogue are one JSON object a row (``other_signals``)."""
    return _with_objects(_stored_columns(rows, operator_id=operator_id, upload_id=upload_id),
                         other_signals(rows))


def _stored_columns(rows: pa.Table, *, operator_id: int, upload_id: int) -> pa.Table:
    """``snapshot_table`` with each signal outside the catalogue as a column of numbers
    (named ``stored_at``, after the others) in place of ``other_signals``."""
    n = rows.num_rows
    columns: dict[str, pa.Array | pa.ChunkedArray] = {
        "operator_id": pa.array(np.full(n, operator_id, dtype=np.int64)),
        "engine_id": rows["engine_id"],
        "aircraft_id": rows["aircraft_id"],
        "position": rows["position"],
        "upload_id": pa.array(np.full(n, upload_id, dtype=np.int64)),
        "recorded_at": rows["recorded_at"],
        **{name: rows[name] if name in rows.column_names else pa.nulls(n, pa.string())
           for name in ("phase", "flight_id")},
    }
    for signal in SIGNALS:
        columns[signal.column] = (
            rows[signal.name] if signal.name in rows.column_names else pa.nulls(n, pa.float64())
        )
    order = [name for name in SNAPSHOT_COLUMNS if name != OTHER_SIGNALS]
    for name in other_signals(rows):
        columns[stored_at(name)] = pc.cast(rows[name], pa.float64())
        order.append(stored_at(name))
    return pa.table({name: columns[name] for name in order})


def _with_objects(table: pa.Table, others: list[str]) -> pa.Table:
    """``_stored_columns`` (or a slice of it) with its other signals joined into
    ``other_signals``, one JSON object a row (null for a row without any)."""
    places = {name: stored_at(name) for name in others}
    objects = number_objects({name: table[place] for name, place in places.items()},
                             table.num_rows)
    return table.drop_columns(list(places.values())).append_column(OTHER_SIGNALS, objects)


def insert_snapshots(session: Session, rows: pa.Table, *, operator_id: int, upload_id: int) -> None:
    """Insert new rows in the caller's transaction: COPY on PostgreSQL, executemany on SQLite;
    once it commits, the rows are kept in memory for the estimation job (``fresh_records``)."""
    # Kept with each other signal as a column of numbers (``stored_at``), as the pipeline
    # reads them; stored without a column no row has (the catalogue's rows: no JSON at all).
    table = _stored_columns(rows, operator_id=operator_id, upload_id=upload_id)
    fresh_records.keep_after_commit(session, upload_id, table)
    others = other_signals(rows)

    def stored(part: pa.Table) -> pa.Table:
        return _with_objects(part, others) if others else part

    connection = session.connection()
    if connection.dialect.name == "postgresql":
        # The JSON objects are written batch by batch, while the server stores the batch
        # before (``copy_binary``).
        copy_binary(connection.connection.driver_connection, "snapshots", table,
                    SNAPSHOT_PG_TYPES, stored)
    else:
        executemany_rows(connection.connection.driver_connection, "snapshots", stored(table))


# PostgreSQL types of SNAPSHOT_COLUMNS, for binary COPY.
SNAPSHOT_PG_TYPES = {
    "operator_id": "int4",
    "engine_id": "int4",
    "aircraft_id": "int4",
    "position": "int2",
    "upload_id": "int4",
    "recorded_at": "timestamptz",
    "phase": "text",
    "flight_id": "text",
    **{s.column: "float8" for s in SIGNALS},
    OTHER_SIGNALS: "jsonb",
}


def copy_binary(
    driver_connection: Any, table_name: str, table: pa.Table, pg_types: Mapping[str, str],
    stored: Callable[[pa.Table], pa.Table] | None = None,
) -> None:
    """Binary COPY of ``table`` through psycopg 3 (the server parses no text), each batch
    of rows made what is stored by ``stored`` first when given. psycopg's queued writer sends
    each batch from a thread while the next one is made and encoded, so the server stores
    rows while Python prepares the following ones."""
    finish = stored or (lambda part: part)
    names = ", ".join(finish(table.slice(0, 0)).column_names)
    statement = f"COPY {table_name} ({names}) FROM STDIN (FORMAT binary)"
    with driver_connection.cursor() as cursor:
        with cursor.copy(statement, writer=QueuedLibpqWriter(cursor)) as copy:
            copy.write(HEADER)
            for batch in table.to_batches(max_chunksize=COPY_BATCH_ROWS):
                copy.write(binary_copy_rows(finish(pa.Table.from_batches([batch])), pg_types))
            copy.write(TRAILER)


def executemany_rows(driver_connection: Any, table_name: str, table: pa.Table) -> None:
    """Insert ``table`` with one executemany (sqlite3); timestamps in SQLAlchemy's format."""
    columns: list[list[Any]] = []
    for name in table.column_names:
        column = table[name]
        if pa.types.is_timestamp(column.type):
            column = pc.strftime(column, "%Y-%m-%d %H:%M:%S")  # %S carries the microseconds
        columns.append(column.to_pylist())
    marks = ", ".join("?" for _ in table.column_names)
    cursor = driver_connection.cursor()
    try:
        cursor.executemany(
            f"INSERT INTO {table_name} ({', '.join(table.column_names)}) VALUES ({marks})",
            zip(*columns, strict=True),
        )
    finally:
        cursor.close()


# ------------------------------------------------------------------------------ reading


def list_uploads(
    session: Session,
    *,
    operator_id: int,
    limit: int,
    offset: int,
    status: str | None = None,
    kind: str | None = None,
) -> tuple[list[Upload], int]:
    stmt = select(Upload).where(Upload.operator_id == operator_id)
    if status is not None:
        stmt = stmt.where(Upload.status == status)
    if kind is not None:
        stmt = stmt.where(Upload.kind == kind)
    return common.paginate(session, stmt.order_by(Upload.id.desc()), limit=limit, offset=offset)


def get_upload(session: Session, *, operator_id: int, upload_id: int) -> Upload:
    return common.owned(session, Upload, operator_id, upload_id, "upload")


SNAPSHOT_OUTPUT = ("recorded_at", "tail", "position", "phase", "flight_id") + tuple(
    s.name for s in SIGNALS
)


class OutputSignal(NamedTuple):
    """A signal column of an engine's snapshots as given out: name, stored unit, selected."""

    name: str
    unit: str
    column: Any


def output_signals(params: ParameterSet) -> list[OutputSignal]:
    """The signal columns of an engine's snapshots as given out: every catalogue signal for a
    type whose signals are all the catalogue's (the built-in engine's, as always); else the
    operating condition and the type's own signals, in the units they are stored in."""
    if all(spec.name in CATALOGUE for spec in params.signals):
        return [OutputSignal(spec.name, spec.unit, getattr(Snapshot, spec.column))
                for spec in SIGNALS]
    out = [OutputSignal(spec.name, spec.unit, getattr(Snapshot, spec.column))
           for spec in OPERATING_CONDITION]
    for spec in params.signals:
        place = stored_at(spec.name)
        column = (getattr(Snapshot, place) if other_signal(place) is None
                  else Snapshot.other_signals[spec.name].as_float())
        out.append(OutputSignal(spec.name, stored_spec(spec).unit, column))
    return out


def engine_snapshots(
    session: Session,
    *,
    operator_id: int,
    engine_id: int,
    start: datetime | None = None,
    end: datetime | None = None,
    limit: int = 10_000,
) -> tuple[Engine, pa.Table, dict[str, str]]:
    """The engine's snapshots in [start, end), oldest first, at most ``limit``, as columns
    named as uploaded (``SNAPSHOT_OUTPUT`` for the built-in engine's signals, else the
    engine type's: ``output_signals``), in stored units; and the unit of each signal."""
    engine = fleet.get_engine(session, operator_id=operator_id, engine_id=engine_id)
    signals = output_signals(parameter_sets(session, [engine.engine_type_id])[
        engine.engine_type_id])
    names = ("recorded_at", "tail", "position", "phase", "flight_id",
             *(signal.name for signal in signals))
    stmt = (
        select(
            # Plain DateTime: Arrow takes the driver's values in bulk (aware on PostgreSQL,
            # naive UTC on SQLite) without a per-row Python conversion.
            type_coerce(Snapshot.recorded_at, DateTime(timezone=True)),
            Aircraft.tail,
            Snapshot.position,
            Snapshot.phase,
            Snapshot.flight_id,
            *[signal.column for signal in signals],
        )
        .outerjoin(Aircraft, Aircraft.id == Snapshot.aircraft_id)
        .where(Snapshot.engine_id == engine.id)
        .order_by(Snapshot.recorded_at)
        .limit(limit)
    )
    if start is not None:
        stmt = stmt.where(Snapshot.recorded_at >= start)
    if end is not None:
        stmt = stmt.where(Snapshot.recorded_at < end)
    rows = session.connection().execute(stmt).all()  # Core: no ORM row loading
    columns = list(zip(*rows, strict=True)) if rows else [() for _ in names]
    types = [pa.timestamp("us", tz="UTC"), pa.string(), pa.int16(), pa.string(), pa.string()]
    types += [pa.float64()] * len(signals)
    arrays = [pa.array(list(c), t) for c, t in zip(columns, types, strict=True)]
    units = {signal.name: signal.unit for signal in signals}
    return engine, pa.table(dict(zip(names, arrays, strict=True))), units
