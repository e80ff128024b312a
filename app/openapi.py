"""The OpenAPI document with every error status a route can answer.

FastAPI documents a route's success and its 422; the errors raised by services
(app.errors), by authentication (app.security) and by the body limit (app.limits) are
added here, each with the shared error body, so a client (or a schema checker) finds every
status code it can receive.
"""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi
from pydantic import BaseModel, Field

WRITE_METHODS = frozenset({"POST", "PUT", "PATCH", "DELETE"})
ERROR_REF = {"$ref": "#/components/schemas/ErrorResponse"}

# Why a route can answer each status, in the words of its documentation.
REASONS = {
    400: "the request body could not be read (not JSON, or not UTF-8)",
    401: "missing, unknown or revoked API key",
    403: "the API key's role is below what this action needs",
    404: "a referenced resource does not exist or belongs to another operator",
    409: "the request conflicts with what is stored",
    413: "the request body exceeds the server's limit",
    415: "the request body's content type is not accepted here",
    422: "invalid input: the details name the field and the reason",
}


class ErrorInfo(BaseModel):
    code: str = Field(description="machine-readable error code, e.g. not_found")
    message: str
    details: list[dict[str, Any]] = Field(
        default_factory=list, description="per-field reasons: location or row/column, reason"
    )


class ErrorResponse(BaseModel):
    """Every 4xx and 5xx the API answers has this body."""

    error: ErrorInfo


def error_statuses(method: str, operation: dict[str, Any]) -> list[int]:
    """The error statuses an operation can answer beyond the global 503, read from what the
    operation declares: its API-key security, its path parameters, its method."""
    statuses = {422}
    if operation.get("security"):
        # app.security: no or a revoked key (401), a role below the route's minimum (403).
        statuses |= {401, 403}
    if any(parameter.get("in") == "path" for parameter in operation.get("parameters", [])):
        statuses.add(404)
    if "requestBody" in operation:
        statuses.add(400)  # FastAPI's answer to a body it cannot parse
    if method.upper() in WRITE_METHODS:
        # A body may name another resource (404), clash with what is stored (409), exceed
        # the body limit (app.limits, 413) or come in a type the route does not read (415).
        statuses |= {404, 409, 413, 415}
    return sorted(statuses)


def install_openapi(app: FastAPI) -> None:
    """Replace ``app.openapi`` by one that documents every route's error statuses."""

    def openapi() -> dict[str, Any]:
        if app.openapi_schema:
            return app.openapi_schema
        document = get_openapi(
            title=app.title, version=app.version, summary=app.summary,
            description=app.description, routes=app.routes,
        )
        schemas = document.setdefault("components", {}).setdefault("schemas", {})
        error_schema = ErrorResponse.model_json_schema(
            ref_template="#/components/schemas/{model}"
        )
        schemas.update(error_schema.pop("$defs", {}))
        schemas["ErrorResponse"] = error_schema
        for operations in document["paths"].values():
            for method, operation in operations.items():
                responses = operation.setdefault("responses", {})
                for status in error_statuses(method, operation):
                    entry = responses.setdefault(str(status), {})
                    # 422 included: the validation body is ours (app.errors), not FastAPI's.
                    entry["description"] = REASONS[status]
                    entry["content"] = {"application/json": {"schema": ERROR_REF}}
                unavailable = responses.get("503", {})
                unavailable.setdefault("content", {"application/json": {"schema": ERROR_REF}})
        app.openapi_schema = document
        return document

    app.openapi = openapi  # type: ignore[method-assign]
