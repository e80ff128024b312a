"""Stream recordings: whole-flight files, live chunks in order, and their samples."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Annotated, Any

import pyarrow.csv as pacsv
import pyarrow.parquet as pq
from fastapi import APIRouter, Query, Request, Response, status

from app.errors import UnsupportedMediaType
from app.payloads import Body, ColumnMapping, IdempotencyKey, parse_mapping, run_upload
from app.schemas.fleet import IsoDatetime, Page, PageParams
from app.schemas.uploads import (
    MAX_CHUNK_INDEX,
    ChunkOut,
    LiveRecordingCreate,
    RecordingOut,
    StreamUploadOut,
    UploadOut,
)
from app.security import Analyst, CurrentPrincipal, DbSession
from app.services.jobs.queue import get_job_queue
from app.services.streams import recordings, retention, samples

router = APIRouter(prefix="/api/v1/streams", tags=["streams"])


def data_dir(request: Request) -> Path:
    return Path(request.app.state.settings.data_dir)


def _file_format(fmt: str | None) -> str:
    if fmt not in ("csv", "parquet"):
        raise UnsupportedMediaType(
            "send text/csv or application/vnd.apache.parquet (raw body or a multipart file)"
        )
    return fmt


@router.post("", response_model=StreamUploadOut, status_code=status.HTTP_201_CREATED)
def upload_stream(
    request: Request,
    payload: Body,
    session: DbSession,
    principal: Analyst,
    response: Response,
    tail: str | None = None,
    position: Annotated[int | None, Query(ge=1, le=4)] = None,
    started_at: IsoDatetime | None = None,
    flight_id: str | None = None,
    idempotency_key: IdempotencyKey = None,
    columns: ColumnMapping = None,
) -> StreamUploadOut:
    """A whole-flight recording (CSV or Parquet with ``time_s``); metadata as query
    parameters or in the Parquet file's ``fleethealth.manifest`` metadata."""
    fmt = _file_format(payload.content_format)
    meta = {
        k: v
        for k, v in {
            "tail": tail,
            "position": position,
            "started_at": started_at,
            "flight_id": flight_id,
        }.items()
        if v is not None
    }
    outcome: dict[str, Any] = {}

    def store() -> Any:
        upload, recording, replayed = recordings.upload_recording(
            session,
            operator_id=principal.operator_id,
            api_key_id=principal.key_id,
            data_dir=data_dir(request),
            body=payload.body,
            content_format=fmt,
            meta=meta,
            mapping=parse_mapping(columns),
            idempotency_key=idempotency_key,
        )
        outcome.update(upload=upload, recording=recording, replayed=replayed)
        return None

    run_upload(
        session,
        principal,
        kind="stream",
        payload=payload,
        idempotency_key=idempotency_key,
        store=store,
    )
    if not outcome["replayed"]:
        recording = outcome["recording"]
        get_job_queue(request).estimate_recording(
            session, operator_id=principal.operator_id, recording_id=recording.id,
            through_sample=recording.n_samples,
        )
        if outcome["upload"].affected:  # steady windows stored as the engine's records
            get_job_queue(request).estimate(session, operator_id=principal.operator_id)
    response.status_code = status.HTTP_200_OK if outcome["replayed"] else status.HTTP_201_CREATED
    upload = UploadOut.model_validate(outcome["upload"]).model_copy(
        update={"replayed": outcome["replayed"]}
    )
    return StreamUploadOut(
        upload=upload, recording=RecordingOut.model_validate(outcome["recording"])
    )


@router.post("/live", response_model=RecordingOut, status_code=status.HTTP_201_CREATED)
def open_live_recording(
    body: LiveRecordingCreate, session: DbSession, principal: Analyst
) -> RecordingOut:
    """Open a recording that live chunks append to (``POST /streams/{id}/chunks``)."""
    recording = recordings.open_recording(
        session,
        operator_id=principal.operator_id,
        meta=recordings.StreamMeta(body.tail, body.position, body.started_at, body.flight_id),
        dt_s=body.dt_s,
    )
    return RecordingOut.model_validate(recording)


@router.post("/{recording_id}/chunks", response_model=ChunkOut, status_code=status.HTTP_201_CREATED)
def append_chunk(
    recording_id: int,
    request: Request,
    payload: Body,
    session: DbSession,
    principal: Analyst,
    response: Response,
    index: Annotated[
        int, Query(ge=0, le=MAX_CHUNK_INDEX, description="chunk index: 0, 1, 2, ... in order")
    ],
) -> ChunkOut:
    """Append the next chunk (CSV or Parquet; chunked transfer encoding is fine)."""
    fmt = _file_format(payload.content_format)
    outcome: dict[str, Any] = {}

    def store() -> Any:
        outcome["result"] = recordings.append_chunk(
            session,
            operator_id=principal.operator_id,
            api_key_id=principal.key_id,
            data_dir=data_dir(request),
            recording_id=recording_id,
            chunk_index=index,
            body=payload.body,
            content_format=fmt,
        )
        return None

    run_upload(
        session, principal, kind="stream_chunk", payload=payload, idempotency_key=None, store=store
    )
    result: recordings.ChunkResult = outcome["result"]
    if not result.replayed:
        get_job_queue(request).estimate_recording(
            session, operator_id=principal.operator_id, recording_id=result.recording.id,
            through_sample=result.recording.n_samples,
        )
        chunk_upload = recordings.chunk_upload(session, result.chunk)
        if chunk_upload is not None and chunk_upload.affected:
            get_job_queue(request).estimate(session, operator_id=principal.operator_id)
    response.status_code = status.HTTP_200_OK if result.replayed else status.HTTP_201_CREATED
    return ChunkOut(
        recording=RecordingOut.model_validate(result.recording),
        chunk_index=result.chunk.chunk_index,
        n_samples=result.chunk.n_samples,
        upload_id=result.chunk.upload_id,
        replayed=result.replayed,
    )


@router.post("/{recording_id}/close", response_model=RecordingOut)
def close_recording(recording_id: int, session: DbSession, principal: Analyst) -> RecordingOut:
    recording = recordings.close_recording(
        session, operator_id=principal.operator_id, recording_id=recording_id
    )
    return RecordingOut.model_validate(recording)


@router.get("", response_model=Page[RecordingOut])
def list_recordings(
    session: DbSession,
    principal: CurrentPrincipal,
    page: Annotated[PageParams, Query()],
    engine_id: int | None = None,
) -> Page[RecordingOut]:
    rows, total = recordings.list_recordings(
        session,
        operator_id=principal.operator_id,
        limit=page.limit,
        offset=page.offset,
        engine_id=engine_id,
    )
    return Page.of([RecordingOut.model_validate(r) for r in rows], total, page)


@router.get("/{recording_id}", response_model=RecordingOut)
def get_recording(
    recording_id: int, session: DbSession, principal: CurrentPrincipal
) -> RecordingOut:
    recording = recordings.get_recording(
        session, operator_id=principal.operator_id, recording_id=recording_id
    )
    return RecordingOut.model_validate(recording)


@router.get(
    "/{recording_id}/samples",
    response_class=Response,
    responses={200: {"content": {"text/csv": {}, "application/vnd.apache.parquet": {}}}},
)
def recording_samples(
    recording_id: int,
    request: Request,
    session: DbSession,
    principal: CurrentPrincipal,
    fmt: Annotated[str, Query(alias="format", pattern="^(csv|parquet)$")] = "csv",
) -> Response:
    """The recording's samples in stored units, as CSV or Parquet; 410 when the stream sample
    retention (``stream_retention_days``) removed them."""
    recording = recordings.get_recording(
        session, operator_id=principal.operator_id, recording_id=recording_id
    )
    retention.check_kept(recording)  # 410 once the retention removed them
    table = samples.read_all(data_dir(request), recording)
    sink = io.BytesIO()
    if fmt == "csv":
        pacsv.write_csv(table, sink)
        media = "text/csv"
    else:
        pq.write_table(table, sink)
        media = "application/vnd.apache.parquet"
    return Response(sink.getvalue(), media_type=media)
