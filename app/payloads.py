"""Upload payloads of the REST API, shared by the snapshot and stream routes: the request body
(raw or a multipart ``file`` part) and its format, the Idempotency-Key header, the column
mapping, and storing an upload or keeping its rejection in the history."""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Annotated, TypeVar

from fastapi import Depends, Header, Query, Request
from sqlalchemy.orm import Session

from app.errors import InvalidInput, PayloadTooLarge
from app.limits import BodyTooLarge
from app.services.tenancy.service import Principal
from app.services.uploads import store as uploads_store
from app.services.uploads.origin import MAX_FILENAME, UploadOrigin, clean_filename

T = TypeVar("T")

MEDIA_FORMATS = {
    "text/csv": "csv",
    "application/csv": "csv",
    "application/vnd.apache.parquet": "parquet",
    "application/x-parquet": "parquet",
    "application/parquet": "parquet",
    "application/json": "json",
}
EXTENSION_FORMATS = {".csv": "csv", ".parquet": "parquet", ".pq": "parquet", ".json": "json"}


class Payload:
    """The request body (or the multipart ``file`` part), its format, and where it came from
    (the file's name and the declared source)."""

    def __init__(self, body: bytes, content_format: str | None,
                 origin: UploadOrigin | None = None) -> None:
        self.body = body
        self.content_format = content_format
        self.origin = origin or UploadOrigin()


FileName = Annotated[
    str | None,
    Query(
        alias="filename",
        max_length=4 * MAX_FILENAME,
        description="the file's name, for a raw body (a multipart part carries its own)",
    ),
]
Source = Annotated[
    str,
    Query(
        alias="source",
        pattern="^(browser|cli|api)$",
        description="who sends it: the uploads page (browser), the importer (cli) or api",
    ),
]


async def read_payload(request: Request, filename: FileName = None,
                       source: Source = "api") -> Payload:
    """Read the body in the event loop (the route itself runs in the threadpool); a bad file
    name is refused (422) before anything is stored."""
    try:
        payload = await _read_payload(request, clean_filename(filename))
    except BodyTooLarge:
        raise PayloadTooLarge("request body exceeds the limit") from None
    payload.origin = UploadOrigin(payload.origin.filename, source)
    return payload


async def _read_payload(request: Request, filename: str | None) -> Payload:
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
        return Payload(body, fmt, UploadOrigin(clean_filename(part.filename or None) or filename))
    return Payload(await request.body(), MEDIA_FORMATS.get(media), UploadOrigin(filename))


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
    session: Session,
    principal: Principal,
    *,
    kind: str,
    payload: Payload,
    idempotency_key: str | None,
    store: Callable[[], T],
) -> T:
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
        origin=payload.origin,
    )
