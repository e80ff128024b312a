"""Validation errors, domain errors and oversized bodies come back as clear JSON 4xx."""

from __future__ import annotations

from collections.abc import Iterator

from fastapi import FastAPI
from fastapi.testclient import TestClient
from pydantic import BaseModel

from app.errors import Conflict, install_error_handlers
from app.limits import BodyLimitMiddleware


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
