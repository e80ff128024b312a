"""Domain errors and the handlers that turn them, and validation errors, into clear JSON 4xx."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from fastapi import FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import HTMLResponse, JSONResponse
from sqlalchemy.exc import DataError, DBAPIError, OperationalError
from starlette.exceptions import HTTPException as StarletteHTTPException

log = logging.getLogger("fleethealth.errors")


class ServiceError(Exception):
    """Base of the errors a service raises for a client to read."""

    status_code = 400
    code = "bad_request"

    def __init__(self, message: str, *, details: list[dict[str, Any]] | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.details = details or []


class NotFound(ServiceError):
    status_code = 404
    code = "not_found"


class Conflict(ServiceError):
    status_code = 409
    code = "conflict"


class InvalidInput(ServiceError):
    """Input that parsed but makes no sense; ``details`` name row, column and reason."""

    status_code = 422
    code = "invalid_input"


class UnsupportedMediaType(ServiceError):
    status_code = 415
    code = "unsupported_media_type"


class PayloadTooLarge(ServiceError):
    status_code = 413
    code = "payload_too_large"


class Forbidden(ServiceError):
    status_code = 403
    code = "forbidden"


class Unauthorized(ServiceError):
    status_code = 401
    code = "unauthorized"


class ServiceUnavailable(ServiceError):
    """The database cannot be reached (or is locked past its busy timeout): try again later."""

    status_code = 503
    code = "service_unavailable"


# Seconds a client should wait before retrying after a 503 (sent as Retry-After).
RETRY_AFTER_S = 5
# SQLite's answer when another writer holds the file past the busy timeout.
_SQLITE_BUSY = ("database is locked", "database is busy")


def database_unavailable(exc: DBAPIError) -> bool:
    """True when ``exc`` says the database could not be reached or was busy, not that the
    statement was wrong: a lost or refused connection (PostgreSQL down, restarting, a network
    cut: psycopg's OperationalError, or a connection SQLAlchemy invalidated), or SQLite locked
    past its busy timeout. A statement error (no such table, syntax) stays a 500: retrying it
    cannot help."""
    if exc.connection_invalidated:
        return True
    if not isinstance(exc, OperationalError):
        return False
    orig = exc.orig
    module = type(orig).__module__ if orig is not None else ""
    if module.startswith("psycopg"):
        return True
    message = str(orig).lower()
    return any(text in message for text in _SQLITE_BUSY) or "unable to open database" in message


def error_body(
    code: str, message: str, details: list[dict[str, Any]] | None = None
) -> dict[str, Any]:
    return {"error": {"code": code, "message": message, "details": details or []}}


def is_api_path(path: str) -> bool:
    """Paths whose clients read JSON: the API and the service's health check."""
    return path.startswith("/api/") or path in ("/api", "/health")


def install_error_handlers(app: FastAPI, not_found_page: Path | None = None) -> None:
    """``not_found_page``: the HTML answered, with 404, for an unknown page outside the API."""

    @app.exception_handler(ServiceError)
    async def _service_error(_request: Request, exc: ServiceError) -> JSONResponse:
        return JSONResponse(
            error_body(exc.code, exc.message, exc.details), status_code=exc.status_code
        )

    @app.exception_handler(RequestValidationError)
    async def _validation_error(_request: Request, exc: RequestValidationError) -> JSONResponse:
        details = [
            {
                "location": [str(part) for part in err.get("loc", ())],
                "reason": err.get("msg", ""),
                "type": err.get("type", ""),
            }
            for err in exc.errors()
        ]
        first = details[0] if details else {"location": [], "reason": "invalid request"}
        message = f"{'.'.join(first['location']) or 'request'}: {first['reason']}"
        return JSONResponse(
            jsonable_encoder(error_body("validation_error", message, details)), status_code=422
        )

    @app.exception_handler(StarletteHTTPException)
    async def _http_error(
        request: Request, exc: StarletteHTTPException
    ) -> JSONResponse | HTMLResponse:
        if (exc.status_code == 404 and not_found_page is not None
                and not is_api_path(request.scope["path"])):
            return HTMLResponse(not_found_page.read_text(encoding="utf-8"), status_code=404)
        code = {404: "not_found", 405: "method_not_allowed", 401: "unauthorized"}.get(
            exc.status_code, "http_error"
        )
        return JSONResponse(
            error_body(code, str(exc.detail)), status_code=exc.status_code, headers=exc.headers
        )

    @app.exception_handler(DBAPIError)
    async def _database_error(request: Request, exc: DBAPIError) -> JSONResponse:
        if database_unavailable(exc):
            log.warning("database unavailable on %s %s: %s", request.method, request.url.path,
                        exc.orig)
            return JSONResponse(
                error_body(ServiceUnavailable.code,
                           "the database is unavailable; nothing was stored, retry later"),
                status_code=503, headers={"Retry-After": str(RETRY_AFTER_S)},
            )
        if isinstance(exc, DataError):
            # A value the database cannot hold (an integer beyond its range, a NUL byte in
            # text): the request's fault, refused whole by the rolled-back transaction.
            return JSONResponse(
                error_body("invalid_input", f"a value is out of the database's range: "
                           f"{str(exc.orig).splitlines()[0] if exc.orig else 'invalid value'}"),
                status_code=422,
            )
        log.exception("database error on %s %s", request.method, request.url.path)
        return JSONResponse(error_body("internal_error", "internal server error"), status_code=500)

    @app.exception_handler(OverflowError)
    async def _overflow(_request: Request, exc: OverflowError) -> JSONResponse:
        # SQLite's driver refuses Python integers beyond 64 bits before the statement runs.
        return JSONResponse(
            error_body("invalid_input", f"a number is out of range: {exc}"), status_code=422
        )

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return JSONResponse(error_body("internal_error", "internal server error"), status_code=500)
