"""Snapshot uploads (JSON, CSV, Parquet), upload history, and an engine's stored snapshots."""

from __future__ import annotations

import io
import json
from collections.abc import Callable
from datetime import datetime
from typing import Annotated, Any

import pyarrow.compute as pc
import pyarrow.csv as pacsv
from fastapi import APIRouter, Depends, Header, Query, Request, Response, status

from app.errors import InvalidInput, PayloadTooLarge, ServiceError
from app.limits import BodyTooLarge
from app.schemas.fleet import Page, PageParams
from app.schemas.uploads import EngineSnapshots, SnapshotBatch, UploadDetail, UploadOut
from app.security import Analyst, CurrentPrincipal, DbSession
from app.services.jobs.queue import get_job_queue
from app.services.tenancy.service import Principal
from app.services.uploads import store as uploads_store
from app.services.uploads.store import UploadResult

router = APIRouter(prefix="/api/v1", tags=["uploads"])

MEDIA_FORMATS = {
    "text/csv": "csv",
    "application/csv": "csv",
    "application/vnd.apache.parquet": "parquet",
    "application/x-parquet": "parquet",
    "application/parquet": "parquet",
    "application/json": "json",
}
EXTENSION_FORMATS = {".csv": "csv", ".parquet": "parquet", ".pq": "parquet", ".json": "json"}


class UnsupportedMediaType(ServiceError):
    status_code = 415
    code = "unsupported_media_type"


class Payload:
    """The request body (or the multipart ``file`` part) and its format."""

    def __init__(self, body: bytes, content_format: str | None) -> None:
        self.body = body
        self.content_format = content_format


async def read_payload(request: Request) -> Payload:
    """Read the body in the event loop (the route itself runs in the threadpool)."""
    try:
        return await _read_payload(request)
    except BodyTooLarge:
        raise PayloadTooLarge("request body exceeds the limit") from None


async def _read_payload(request: Request) -> Payload:
    media = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if media == "multipart/form-data":
        form = await request.form()
        part = form.get("file")
        if part is None or isinstance(part, str):
            raise InvalidInput('multipart upload needs a file part named "file"')
        body = await part.read()
        part_media = (part.content_type or "").split(";")[0].strip().lower()
        fmt = MEDIA_FORMATS.get(part_media)
        if fmt is None and part.filename:
            suffix = "." + part.filename.rsplit(".", 1)[-1].lower() if "." in part.filename else ""
            fmt = EXTENSION_FORMATS.get(suffix)
        return Payload(body, fmt)
    return Payload(await request.body(), MEDIA_FORMATS.get(media))


Body = Annotated[Payload, Depends(read_payload)]
IdempotencyKey = Annotated[
    str | None,
    Header(
        alias="Idempotency-Key",
        max_length=200,
        description="the same key twice stores once; with other content it is a 409",
    ),
]
ColumnMapping = Annotated[
    str | None,
    Query(
        alias="columns",
        description='JSON object renaming file columns, e.g. {"HPC_T": "T30[degC]", "x": null}',
    ),
]


def parse_mapping(text: str | None) -> dict[str, str | None] | None:
    if text is None:
        return None
    try:
        mapping = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InvalidInput(f"columns: not JSON: {exc}") from None
    if not isinstance(mapping, dict) or not all(
        isinstance(k, str) and (v is None or isinstance(v, str)) for k, v in mapping.items()
    ):
        raise InvalidInput("columns: must be a JSON object of names to names (or null)")
    return mapping


def run_upload(
    session: DbSession,
    principal: Principal,
    *,
    kind: str,
    payload: Payload,
    idempotency_key: str | None,
    store: Callable[[], UploadResult],
) -> UploadResult:
    """Run ``store``; a refused upload is rolled back entirely, then kept in the history."""
    return uploads_store.store_or_reject(
        session,
        operator_id=principal.operator_id,
        api_key_id=principal.key_id,
        kind=kind,
        content_format=payload.content_format,
        body=payload.body,
        idempotency_key=idempotency_key,
        store=store,
    )


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
        ),
    )


@router.post(
    "/snapshots",
    response_model=UploadOut,
    status_code=status.HTTP_201_CREATED,
    responses={200: {"description": "a repeat of an earlier upload: nothing new stored"}},
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
    if payload.content_format not in (None, "json"):
        raise UnsupportedMediaType("POST /api/v1/snapshots takes JSON; files go to /snapshots/file")
    payload.content_format = "json"
    result = _store_snapshots(session, principal, payload, idempotency_key, None)
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
    result = _store_snapshots(session, principal, payload, idempotency_key, parse_mapping(columns))
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
    """One upload with its row-level errors."""
    row = uploads_store.get_upload(session, operator_id=principal.operator_id, upload_id=upload_id)
    return UploadDetail.model_validate(row)


@router.get(
    "/engines/{engine_id}/snapshots",
    response_model=EngineSnapshots,
    responses={200: {"content": {"text/csv": {}}}},
)
def engine_snapshots(
    engine_id: int,
    session: DbSession,
    principal: CurrentPrincipal,
    start: datetime | None = None,
    end: datetime | None = None,
    limit: Annotated[int, Query(ge=1, le=100_000)] = 10_000,
    fmt: Annotated[str, Query(alias="format", pattern="^(json|csv)$")] = "json",
) -> Any:
    """The engine's stored snapshots in [start, end), oldest first (JSON or ``?format=csv``)."""
    for name, value in (("start", start), ("end", end)):
        if value is not None and value.tzinfo is None:
            raise InvalidInput(f"{name}: give a time zone (e.g. Z)")
    engine, table = uploads_store.engine_snapshots(
        session,
        operator_id=principal.operator_id,
        engine_id=engine_id,
        start=start,
        end=end,
        limit=limit,
    )
    if fmt == "csv":
        sink = io.BytesIO()
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
    body = EngineSnapshots(engine_id=engine.id, esn=engine.esn, count=len(records), snapshots=[])
    document = body.model_dump()
    document["snapshots"] = records
    # Built directly: ten thousand records need no per-field validation on the way out.
    return Response(json.dumps(document, allow_nan=False), media_type="application/json")
