"""Stream recordings: whole-flight files and live chunks, samples kept as Parquet files.

A recording is one engine on one flight at a fixed sample interval ``dt_s``. Its samples are
checked against the parameter set of the engine's type (``uploads.parameters.check_stream``: a
column the type does not have refuses the upload, naming the column and the type; declared units
are converted to the stored ones, the model file's for a type's own signals) and live under
``data_dir/recordings/<operator>/<recording>/chunk-000000.parquet, ...`` (time_s and the signals
in stored units, by the type's names); the database keeps the metadata, one row per chunk and
one upload row per request. A whole-flight file is chunk 0 of a closed recording. Live chunks
arrive in order (``chunk_index`` 0, 1, ...); each continues the time axis of the one before. A
chunk sent again with the same content is answered as before; other content under a received
index is a 409.

Files are written before the transaction commits, under names derived from the recording and
chunk index: a rolled-back request may leave a file that the next accepted chunk of that index
overwrites, and that no database row points to in the meantime.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.errors import Conflict, InvalidInput
from app.models import Engine, StreamChunk, StreamRecording, Upload
from app.models.base import utcnow
from app.services import common
from app.services.fleet import service as fleet
from app.services.streams import samples, steady
from app.services.uploads.parameters import check_stream
from app.services.uploads.parse import ParsedTable, RowError, UploadRejected, parse_body
from app.services.uploads.store import content_checksum, find_replay

RECORDINGS = "recordings"
MANIFEST_KEY = b"fleethealth.manifest"
DT_TOLERANCE = 1e-6  # relative


@dataclass(frozen=True)
class StreamMeta:
    """Who and when: the tail position (resolved to the engine installed then) and start."""

    tail: str
    position: int
    started_at: datetime
    flight_id: str | None = None


@dataclass(frozen=True)
class ChunkResult:
    recording: StreamRecording
    chunk: StreamChunk
    replayed: bool


def manifest_of(body: bytes) -> dict[str, Any]:
    """Metadata a simulator wrote into a Parquet file's key-value metadata, if any."""
    try:
        schema = pq.read_schema(pa.BufferReader(body))
    except (pa.ArrowException, OSError, ValueError):
        return {}
    raw = (schema.metadata or {}).get(MANIFEST_KEY)
    if raw is None:
        return {}
    try:
        manifest = json.loads(raw)
    except ValueError:
        return {}
    return manifest if isinstance(manifest, dict) else {}


def _dt_of(parsed: ParsedTable) -> float:
    t = parsed.table["time_s"].to_numpy(zero_copy_only=False)
    if t.shape[0] < 2:
        raise UploadRejected(
            [RowError(None, "time_s", "a recording needs at least two samples to fix its rate")]
        )
    return float(np.median(np.diff(t)))


def _write_chunk(path: Path, table: pa.Table) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_suffix(".partial")
    pq.write_table(table, partial)
    os.replace(partial, path)


def _resolve(session: Session, operator_id: int, meta: StreamMeta) -> tuple[Engine, int]:
    """(engine, aircraft_id) installed at the tail position when the recording started."""
    aircraft = fleet.find_aircraft(session, operator_id=operator_id, tail=meta.tail)
    if aircraft is None:
        raise InvalidInput(
            f"no aircraft with tail {meta.tail!r} in your fleet",
            details=[{"row": None, "column": "tail", "reason": "unknown tail"}],
        )
    engine = fleet.resolve_engine(session, operator_id, meta.tail, meta.position, meta.started_at)
    if engine is None:
        reason = (
            f"no engine installed at {meta.tail!r} position {meta.position} "
            f"at {meta.started_at.isoformat()}"
        )
        raise InvalidInput(reason, details=[{"row": None, "column": "position", "reason": reason}])
    return engine, aircraft.id


def _parse(
    session: Session, engine_type_id: int, body: bytes, content_format: str,
    mapping: Mapping[str, str | None] | None = None,
) -> ParsedTable:
    """A stream body read and checked against the engine type's parameter set, in stored
    units."""
    parsed = parse_body(body, content_format, kind="stream", mapping=mapping, by_type=True)
    return check_stream(session, engine_type_id, parsed)


def open_recording(
    session: Session, *, operator_id: int, meta: StreamMeta, dt_s: float
) -> StreamRecording:
    """A new open recording for the engine installed at the tail position at its start."""
    if meta.started_at.tzinfo is None:
        raise InvalidInput("started_at: give a time zone")
    engine, aircraft_id = _resolve(session, operator_id, meta)
    engine_id = engine.id
    taken = session.scalar(
        select(StreamRecording).where(
            StreamRecording.engine_id == engine_id,
            StreamRecording.started_at == meta.started_at,
        )
    )
    if taken is not None:
        raise Conflict(
            f"engine already has recording {taken.id} starting at {meta.started_at.isoformat()}"
        )
    recording = StreamRecording(
        operator_id=operator_id,
        engine_id=engine_id,
        aircraft_id=aircraft_id,
        position=meta.position,
        flight_id=meta.flight_id,
        started_at=meta.started_at,
        dt_s=dt_s,
        status="open",
        n_samples=0,
        n_chunks=0,
        signals=[],
        path="",
    )
    session.add(recording)
    session.flush()
    recording.path = f"{RECORDINGS}/{operator_id}/{recording.id}"
    return recording


def _append(
    session: Session,
    data_dir: Path,
    recording: StreamRecording,
    parsed: ParsedTable,
    *,
    checksum: str,
    upload: Upload,
) -> StreamChunk:
    """Check the chunk continues the recording's time axis, write it, count it."""
    t = parsed.table["time_s"].to_numpy(zero_copy_only=False)
    if t.shape[0] >= 2:
        dt = float(np.median(np.diff(t)))
        if abs(dt - recording.dt_s) > DT_TOLERANCE * recording.dt_s:
            raise UploadRejected(
                [
                    RowError(
                        2,
                        "time_s",
                        f"sample interval {dt:g} s differs from the recording's "
                        f"{recording.dt_s:g} s",
                    )
                ]
            )
    expected = recording.n_samples * recording.dt_s
    if recording.n_chunks and abs(t[0] - expected) > DT_TOLERANCE * max(recording.dt_s, 1.0):
        raise UploadRejected(
            [
                RowError(
                    1,
                    "time_s",
                    f"chunk starts at {t[0]:g} s; the recording continues at {expected:g} s",
                )
            ]
        )
    index = recording.n_chunks
    _write_chunk(samples.chunk_path(data_dir, recording, index), parsed.table)
    chunk = StreamChunk(
        recording_id=recording.id,
        chunk_index=index,
        upload_id=upload.id,
        checksum=checksum,
        first_sample=recording.n_samples,
        n_samples=parsed.num_rows,
    )
    session.add(chunk)
    recording.n_samples += parsed.num_rows
    recording.n_chunks += 1
    recording.signals = sorted(set(recording.signals) | set(parsed.signals))
    session.flush()
    return chunk


def _upload_row(
    *,
    operator_id: int,
    api_key_id: int | None,
    kind: str,
    content_format: str,
    checksum: str,
    idempotency_key: str | None,
    body: bytes,
    rows: int,
    recording_id: int,
) -> Upload:
    return Upload(
        operator_id=operator_id,
        api_key_id=api_key_id,
        kind=kind,
        content_format=content_format,
        checksum=checksum,
        idempotency_key=idempotency_key,
        status="stored",
        rows_received=rows,
        rows_stored=rows,
        rows_duplicate=0,
        bytes_received=len(body),
        message=f"stored {rows} samples",
        errors=[],
        affected=[],
        recording_id=recording_id,
    )


def upload_recording(
    session: Session,
    *,
    operator_id: int,
    api_key_id: int | None,
    data_dir: Path,
    body: bytes,
    content_format: str,
    meta: Mapping[str, Any],
    mapping: Mapping[str, str | None] | None = None,
    idempotency_key: str | None = None,
) -> tuple[Upload, StreamRecording, bool]:
    """Store a whole-flight file as a closed recording; (upload, recording, replayed).

    ``meta`` holds tail, position, started_at, flight_id (query parameters); what is missing
    there is taken from the file's manifest (Parquet key-value metadata).
    """
    merged = {**(manifest_of(body) if content_format == "parquet" else {}), **meta}
    stream_meta = _stream_meta(merged)
    options = {"meta": {k: str(v) for k, v in sorted(merged.items())}, "mapping": mapping}
    checksum = content_checksum(body, kind="stream", content_format=content_format, options=options)
    earlier = find_replay(
        session,
        operator_id=operator_id,
        kind="stream",
        checksum=checksum,
        idempotency_key=idempotency_key,
    )
    if earlier is not None and earlier.recording_id is not None:
        recording = session.get(StreamRecording, earlier.recording_id)
        if recording is not None:
            return earlier, recording, True
    # The engine first: its type decides which columns the samples may carry.
    engine, _aircraft = _resolve(session, operator_id, stream_meta)
    parsed = _parse(session, engine.engine_type_id, body, content_format, mapping)
    recording = open_recording(
        session, operator_id=operator_id, meta=stream_meta, dt_s=_dt_of(parsed)
    )
    upload = _upload_row(
        operator_id=operator_id,
        api_key_id=api_key_id,
        kind="stream",
        content_format=content_format,
        checksum=checksum,
        idempotency_key=idempotency_key,
        body=body,
        rows=parsed.num_rows,
        recording_id=recording.id,
    )
    session.add(upload)
    session.flush()
    _append(session, data_dir, recording, parsed, checksum=checksum, upload=upload)
    recording.status = "closed"
    recording.closed_at = utcnow()
    steady.summarise_windows(session, data_dir, recording, upload, 0)
    return upload, recording, False


def _stream_meta(meta: Mapping[str, Any]) -> StreamMeta:
    missing = [k for k in ("tail", "position", "started_at") if meta.get(k) in (None, "")]
    if missing:
        raise InvalidInput(
            f"recording metadata missing: {', '.join(missing)} (query parameters or manifest)",
            details=[{"row": None, "column": k, "reason": "missing"} for k in missing],
        )
    started = meta["started_at"]
    if isinstance(started, str):
        try:
            started = datetime.fromisoformat(started.replace("Z", "+00:00"))
        except ValueError:
            raise InvalidInput(f"started_at: {started!r} is not an ISO 8601 time") from None
    if not isinstance(started, datetime) or started.tzinfo is None:
        raise InvalidInput("started_at: give a time zone (e.g. 2026-03-01T08:00:00Z)")
    try:
        position = int(meta["position"])
    except (TypeError, ValueError):
        raise InvalidInput(f"position: {meta['position']!r} is not an integer") from None
    if not 1 <= position <= 4:
        raise InvalidInput(f"position: {position} is outside 1..4")
    flight = meta.get("flight_id")
    return StreamMeta(str(meta["tail"]), position, started, None if flight is None else str(flight))


def append_chunk(
    session: Session,
    *,
    operator_id: int,
    api_key_id: int | None,
    data_dir: Path,
    recording_id: int,
    chunk_index: int,
    body: bytes,
    content_format: str,
) -> ChunkResult:
    """Append chunk ``chunk_index`` of a live recording (the next one, or a resend)."""
    recording = common.owned(session, StreamRecording, operator_id, recording_id, "recording")
    checksum = content_checksum(
        body,
        kind="stream_chunk",
        content_format=content_format,
        options={"recording": recording.id, "chunk": chunk_index},
    )
    received = session.scalar(
        select(StreamChunk).where(
            StreamChunk.recording_id == recording.id, StreamChunk.chunk_index == chunk_index
        )
    )
    if received is not None:
        if received.checksum != checksum:
            raise Conflict(
                f"chunk {chunk_index} of recording {recording.id} was received with other "
                "content; nothing was stored"
            )
        return ChunkResult(recording, received, replayed=True)
    if recording.status != "open":
        raise Conflict(f"recording {recording.id} is closed")
    if chunk_index != recording.n_chunks:
        raise Conflict(
            f"recording {recording.id} expects chunk {recording.n_chunks} next, "
            f"not chunk {chunk_index}",
            details=[{
                "column": "index", "expected_chunk_index": recording.n_chunks,
                "reason": f"chunk {chunk_index} is out of order: {recording.n_chunks} comes next",
            }],
        )
    engine = session.get(Engine, recording.engine_id)
    assert engine is not None
    parsed = _parse(session, engine.engine_type_id, body, content_format)
    upload = _upload_row(
        operator_id=operator_id,
        api_key_id=api_key_id,
        kind="stream_chunk",
        content_format=content_format,
        checksum=checksum,
        idempotency_key=None,
        body=body,
        rows=parsed.num_rows,
        recording_id=recording.id,
    )
    session.add(upload)
    session.flush()
    chunk = _append(session, data_dir, recording, parsed, checksum=checksum, upload=upload)
    steady.summarise_windows(session, data_dir, recording, upload, chunk.first_sample)
    return ChunkResult(recording, chunk, replayed=False)


def close_recording(session: Session, *, operator_id: int, recording_id: int) -> StreamRecording:
    recording = common.owned(session, StreamRecording, operator_id, recording_id, "recording")
    if recording.status == "open":
        recording.status = "closed"
        recording.closed_at = utcnow()
        session.flush()
    return recording


def get_recording(session: Session, *, operator_id: int, recording_id: int) -> StreamRecording:
    return common.owned(session, StreamRecording, operator_id, recording_id, "recording")


def list_recordings(
    session: Session,
    *,
    operator_id: int,
    limit: int,
    offset: int,
    engine_id: int | None = None,
) -> tuple[list[StreamRecording], int]:
    stmt = select(StreamRecording).where(StreamRecording.operator_id == operator_id)
    if engine_id is not None:
        stmt = stmt.where(StreamRecording.engine_id == engine_id)
    stmt = stmt.order_by(StreamRecording.started_at.desc(), StreamRecording.id.desc())
    return common.paginate(session, stmt, limit=limit, offset=offset)


def chunk_upload(session: Session, chunk: StreamChunk) -> Upload | None:
    """The upload that carried a chunk (its ``affected``: the steady windows it stored)."""
    return None if chunk.upload_id is None else session.get(Upload, chunk.upload_id)
