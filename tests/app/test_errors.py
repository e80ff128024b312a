"""Validation errors, domain errors and oversized bodies come back as clear JSON 4xx."""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from pathlib import Path

from fastapi import FastAPI
from fastapi.testclient import TestClient
from pydantic import BaseModel
from sqlalchemy.orm import Session

from app.errors import RETRY_AFTER_S, Conflict, install_error_handlers
from app.limits import BodyLimitMiddleware
from app.services.tenancy.service import create_operator, issue_api_key


class Reading(BaseModel):
    sensor: str
    value: float


def _app(max_bytes: int = 1000) -> FastAPI:
    app = FastAPI()
    install_error_handlers(app)
    app.add_middleware(BodyLimitMiddleware, max_bytes=max_bytes)

    @app.post("/readings")
    def post_reading(reading: Reading) -> Reading:
        if reading.sensor == "T30":
            raise Conflict("T30 exists already")
        return reading

    return app


def test_validation_error_names_the_field_and_reason() -> None:
    response = TestClient(_app()).post("/readings", json={"sensor": "T30", "value": "hot"})
    assert response.status_code == 422
    error = response.json()["error"]
    assert error["code"] == "validation_error"
    assert error["details"][0]["location"] == ["body", "value"]
    assert "value" in error["message"] and "number" in error["message"]


def test_domain_error_keeps_its_status_and_message() -> None:
    response = TestClient(_app()).post("/readings", json={"sensor": "T30", "value": 1.0})
    assert response.status_code == 409
    assert response.json()["error"] == {
        "code": "conflict",
        "message": "T30 exists already",
        "details": [],
    }


def test_body_over_the_limit_is_413_with_content_length() -> None:
    response = TestClient(_app(max_bytes=100)).post(
        "/readings", content=b"x" * 101, headers={"content-type": "application/json"}
    )
    assert response.status_code == 413
    assert response.json()["error"]["code"] == "payload_too_large"


def test_body_over_the_limit_is_413_when_chunked_without_content_length() -> None:
    def chunks() -> Iterator[bytes]:
        for _ in range(10):
            yield b"y" * 50

    response = TestClient(_app(max_bytes=100)).post(
        "/readings", content=chunks(), headers={"content-type": "application/json"}
    )
    assert response.status_code == 413


def test_body_under_the_limit_passes() -> None:
    response = TestClient(_app(max_bytes=100)).post(
        "/readings", json={"sensor": "Nc", "value": 2.0}
    )
    assert response.status_code == 200
    assert response.json() == {"sensor": "Nc", "value": 2.0}


def test_unknown_route_is_json_404(client: TestClient) -> None:
    response = client.get("/api/v1/no-such-thing")
    assert response.status_code == 404


def test_database_outage_answers_503_with_retry_after(tmp_path: Path) -> None:
    """A database that refuses connections (PostgreSQL down or restarting) is a retryable 503,
    not a 500, on reads and on uploads alike."""
    from app.config import Settings
    from app.db import make_engine
    from app.main import create_app

    settings = Settings(data_dir=tmp_path)
    # Nothing listens on port 9 of the loopback: every connection is refused.
    engine = make_engine("postgresql+psycopg://postgres@127.0.0.1:9/none",
                         connect_args={"connect_timeout": 2})
    client = TestClient(create_app(settings, engine=engine), raise_server_exceptions=False)
    headers = {"X-API-Key": "fh_anything"}
    for method, path, body in (("get", "/api/v1/aircraft", None),
                               ("post", "/api/v1/snapshots", b"[]")):
        kwargs = {"headers": headers}
        if body is not None:
            kwargs["content"] = body
            kwargs["headers"] = {**headers, "Content-Type": "application/json"}
        response = getattr(client, method)(path, **kwargs)
        assert response.status_code == 503, response.text
        assert response.headers["Retry-After"] == str(RETRY_AFTER_S)
        assert response.json()["error"]["code"] == "service_unavailable"
    health = client.get("/health")
    assert health.status_code == 503


def test_ids_and_offsets_beyond_the_integer_range_are_422(
    client: TestClient, session: Session
) -> None:
    """Path ids and query offsets past int64 answer 4xx on both databases, never 500."""
    operator = create_operator(session, name=f"Range Air {uuid.uuid4().hex[:8]}")
    _row, key = issue_api_key(session, operator=operator, role="admin", name="range")
    session.commit()
    client.headers["X-API-Key"] = key
    for path in ("/api/v1/aircraft/9223372036854775808", "/api/v1/engines/99999999999999999999",
                 "/api/v1/events/-9223372036854775809"):
        response = client.get(path)
        assert 400 <= response.status_code < 500, (path, response.status_code, response.text)
    response = client.get("/api/v1/aircraft", params={"offset": 10**20})
    assert 400 <= response.status_code < 500, response.text


def test_openapi_documents_the_retryable_503_on_every_route(client: TestClient) -> None:
    paths = client.get("/openapi.json").json()["paths"]
    operations = [(path, op) for path, item in paths.items() for op in item.values()]
    assert len(operations) > 20
    for path, op in operations:
        assert "503" in op["responses"], op.get("operationId")
        if path != "/health":  # the probe's 503 is its own answer: the database is down
            assert "Retry-After" in op["responses"]["503"]["headers"], path
