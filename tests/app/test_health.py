from __future__ import annotations

from pathlib import Path

from fastapi.testclient import TestClient
from sqlalchemy import Engine

from app.config import Settings
from app.main import create_app


def test_health_reports_the_database_backend(client: TestClient, db_engine: Engine) -> None:
    response = client.get("/health")
    assert response.status_code == 200
    assert response.json()["database"] == "ok"
    assert response.json()["backend"] == db_engine.dialect.name


def test_health_is_503_when_the_database_does_not_answer(tmp_path: Path) -> None:
    # Nothing listens on port 1: the database is unreachable.
    url = "postgresql+psycopg://postgres@127.0.0.1:1/none"
    settings = Settings(data_dir=tmp_path, database_url=url, log_json=False)
    with TestClient(create_app(settings)) as client:
        response = client.get("/health")
    assert response.status_code == 503
    assert response.json()["database"] == "unreachable"


def test_dashboard_and_docs_are_served(client: TestClient) -> None:
    assert client.get("/").status_code == 200
    assert "fleethealth" in client.get("/").text
    assert client.get("/docs").status_code == 200
    assert client.get("/openapi.json").json()["info"]["title"] == "fleethealth"


def test_every_response_carries_the_request_id(client: TestClient) -> None:
    sent = client.get("/health", headers={"x-request-id": "trace-42"})
    assert sent.headers["x-request-id"] == "trace-42"
    minted = client.get("/health").headers["x-request-id"]
    assert len(minted) == 32 and minted != "trace-42"
