"""Snapshot uploads (JSON, CSV, Parquet), upload history, and an engine's stored snapshots."""

from __future__ import annotations

import io
import json
from typing import Annotated, Any

import pyarrow.compute as pc
import pyarrow.csv as pacsv
from fastapi import APIRouter, Query, Request, Response, status

from app.errors import InvalidInput, UnsupportedMediaType
from app.payloads import Body, ColumnMapping, IdempotencyKey, Payload, parse_mapping, run_upload
from app.schemas.fleet import IsoDatetime, Page, PageParams
from app.schemas.uploads import (
    EngineSnapshots,
    SnapshotBatch,
    UploadDetail,
    UploadEventOut,
    UploadOut,
)
from app.security import Analyst, CurrentPrincipal, DbSession
from app.services.jobs.queue import get_job_queue
from app.services.tenancy.service import Principal
from app.services.uploads import back_dating
from app.services.uploads import store as uploads_store
from app.services.uploads.store import UploadResult

router = APIRouter(prefix="/api/v1", tags=["uploads"])

def queue_estimation(request: Request, session: DbSession, principal: Principal,
                     result: UploadResult) -> None:
    """After a stored upload with new rows: queue the estimation job, dispatched on commit."""
    if result.replayed or not result.upload.affected:
        return
    get_job_queue(request).estimate(session, operator_id=principal.operator_id)


def upload_out(result: UploadResult, response: Response) -> UploadOut:
    response.status_code = status.HTTP_200_OK if result.replayed else status.HTTP_201_CREATED
    out = UploadOut.model_validate(result.upload)
    return out.model_copy(update={"replayed": result.replayed})


def _store_snapshots(
    request: Request,
    session: DbSession,
    principal: Principal,
    payload: Payload,
    idempotency_key: str | None,
    mapping: dict[str, str | None] | None,
) -> UploadResult:
    fmt = payload.content_format
    assert fmt is not None
    return run_upload(
        session,
        principal,
        kind="snapshots",
        payload=payload,
        idempotency_key=idempotency_key,
        store=lambda: uploads_store.ingest_snapshots(
            session,
            operator_id=principal.operator_id,
            api_key_id=principal.key_id,
            body=payload.body,
            content_format=fmt,
            mapping=mapping,
            idempotency_key=idempotency_key,
            origin=payload.origin,
            lateness=request.app.state.settings.upload_lateness,
        ),
    )


@router.post(
    "/snapshots",
    response_model=UploadOut,
    status_code=status.HTTP_201_CREATED,
    responses={
        200: {"description": "a repeat of an earlier upload: nothing new stored"},
        415: {"description": "the body is not declared as application/json"},
    },
    openapi_extra={
        "requestBody": {
            "required": True,
            "content": {"application/json": {"schema": SnapshotBatch.model_json_schema()}},
        }
    },
)
def upload_snapshots(
    request: Request,
    payload: Body,
    session: DbSession,
    principal: Analyst,
    response: Response,
    idempotency_key: IdempotencyKey = None,
) -> UploadOut:
    """Upload snapshots as JSON ``{"units"?, "columns"?, "snapshots": [...]}``, all or nothing."""
    if payload.content_format != "json":
        raise UnsupportedMediaType(
            "POST /api/v1/snapshots takes Content-Type application/json; "
            "CSV and Parquet files go to /api/v1/snapshots/file"
        )
    result = _store_snapshots(request, session, principal, payload, idempotency_key, None)
    queue_estimation(request, session, principal, result)
    return upload_out(result, response)


@router.post(
    "/snapshots/file",
    response_model=UploadOut,
    status_code=status.HTTP_201_CREATED,
    responses={200: {"description": "a repeat of an earlier upload: nothing new stored"}},
    openapi_extra={
        "requestBody": {
            "required": True,
            "content": {
                "text/csv": {"schema": {"type": "string"}},
                "application/vnd.apache.parquet": {
                    "schema": {"type": "string", "format": "binary"}
                },
                "multipart/form-data": {
                    "schema": {
                        "type": "object",
                        "properties": {"file": {"type": "string", "format": "binary"}},
                        "required": ["file"],
                    }
                },
            },
        }
    },
)
def upload_snapshot_file(
    request: Request,
    payload: Body,
    session: DbSession,
    principal: Analyst,
    response: Response,
    idempotency_key: IdempotencyKey = None,
    columns: ColumnMapping = None,
) -> UploadOut:
    """Upload a CSV or Parquet file of snapshots (raw body or multipart ``file``)."""
    if payload.content_format not in ("csv", "parquet"):
        raise UnsupportedMediaType(
            "send text/csv or application/vnd.apache.parquet (raw body or a multipart file)"
        )
    result = _store_snapshots(
        request, session, principal, payload, idempotency_key, parse_mapping(columns)
    )
    queue_estimation(request, session, principal, result)
    return upload_out(result, response)


@router.get("/uploads", response_model=Page[UploadOut])
def list_uploads(
    session: DbSession,
    principal: CurrentPrincipal,
    page: Annotated[PageParams, Query()],
    upload_status: Annotated[
        str | None, Query(alias="status", pattern="^(stored|rejected)$")
    ] = None,
    kind: Annotated[str | None, Query(pattern="^(snapshots|stream|stream_chunk)$")] = None,
) -> Page[UploadOut]:
    """Upload history, newest first."""
    rows, total = uploads_store.list_uploads(
        session,
        operator_id=principal.operator_id,
        limit=page.limit,
        offset=page.offset,
        status=upload_status,
        kind=kind,
    )
    return Page.of([UploadOut.model_validate(r) for r in rows], total, page)


@router.get("/uploads/{upload_id}", response_model=UploadDetail)
def get_upload(upload_id: int, session: DbSession, principal: CurrentPrincipal) -> UploadDetail:
    """One upload with its row-level errors and the events it caused."""
    row = uploads_store.get_upload(session, operator_id=principal.operator_id, upload_id=upload_id)
    detail = UploadDetail.model_validate(row)
    events = [UploadEventOut.model_validate(e) for e in back_dating.caused_events(session, row)]
    return detail.model_copy(update={"events": events})


@router.get("/events/{event_id}/uploads", response_model=list[UploadOut])
def event_uploads(
    event_id: int, session: DbSession, principal: CurrentPrincipal
) -> list[UploadOut]:
    """The uploads that caused an event: the one its record came from, and back-dated ones
    whose re-run reached it (docs/upload-format.md)."""
    rows = back_dating.uploads_of_event(session, principal.operator_id, event_id)
    return [UploadOut.model_validate(r) for r in rows]


@router.get(
    "/engines/{engine_id}/snapshots",
    response_model=EngineSnapshots,
    responses={200: {"content": {"text/csv": {}}}},
)
def engine_snapshots(
    engine_id: int,
    session: DbSession,
    principal: CurrentPrincipal,
    start: IsoDatetime | None = None,
    end: IsoDatetime | None = None,
    limit: Annotated[int, Query(ge=1, le=100_000)] = 10_000,
    fmt: Annotated[str, Query(alias="format", pattern="^(json|csv)$")] = "json",
) -> Any:
    """The engine's stored snapshots in [start, end), oldest first (JSON or ``?format=csv``)."""
    for name, value in (("start", start), ("end", end)):
        if value is not None and value.tzinfo is None:
            raise InvalidInput(f"{name}: give a time zone (e.g. Z)")
    engine, table, units = uploads_store.engine_snapshots(
        session,
        operator_id=principal.operator_id,
        engine_id=engine_id,
        start=start,
        end=end,
        limit=limit,
    )
    if fmt == "csv":
        sink = io.BytesIO()
        if tuple(table.column_names) != uploads_store.SNAPSHOT_OUTPUT:
            # An engine type's own signals: each header with its unit (``EGT[degC]``), so the
            # file reads back as an upload of that type.
            table = table.rename_columns([f"{name}[{units[name]}]" if units.get(name) else name
                                          for name in table.column_names])
        pacsv.write_csv(table, sink)
        return Response(
            sink.getvalue(),
            media_type="text/csv",
            headers={"Content-Disposition": f'attachment; filename="{engine.esn}-snapshots.csv"'},
        )
    # ISO 8601 in UTC, formatted column-wise ("%S" carries the microseconds).
    iso = pc.binary_join_element_wise(
        pc.strftime(table["recorded_at"], "%Y-%m-%dT%H:%M:%S"), "Z", ""
    )
    records = table.set_column(0, "recorded_at", iso).to_pylist()
    body = EngineSnapshots(engine_id=engine.id, esn=engine.esn, count=len(records),
                           units=units, snapshots=[])
    document = body.model_dump()
    document["snapshots"] = records
    # Built directly: ten thousand records need no per-field validation on the way out.
    return Response(json.dumps(document, allow_nan=False), media_type="application/json")
