"""Identical uploads sent at the same time: one stores, every other is the documented 200
replay of it (no 409), on PostgreSQL (concurrent writers) and SQLite (serialised writers)."""

from __future__ import annotations

import threading
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import func, select

from app.config import Settings
from app.db import make_engine, make_sessionmaker, transaction
from app.main import create_app
from app.migrate import upgrade
from app.models import Snapshot, Upload
from tests.conftest import BACKENDS, fresh_database_url
from tests.support.fleet_fixture import json_body, make_fleet, snapshot_rows

N_CLIENTS = 8


@pytest.fixture(params=BACKENDS)
def committed_url(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    """A database of its own: the uploads commit for real, from several threads."""
    generator = fresh_database_url(request.param, tmp_path)
    url = next(generator)
    upgrade(url)
    yield url
    generator.close()


@pytest.mark.parametrize("idempotency_key", [None, "same-key"])
def test_identical_concurrent_uploads_store_once_and_replay(
    committed_url: str, tmp_path: Path, idempotency_key: str | None
) -> None:
    engine = make_engine(committed_url)
    factory = make_sessionmaker(engine)
    with transaction(factory, write=True) as session:
        fleet = make_fleet(session)
    app = create_app(
        Settings(data_dir=tmp_path / "data", database_url=committed_url, log_json=False), engine
    )
    body = json_body(snapshot_rows(40, seed=3))
    headers = dict(fleet.analyst)
    if idempotency_key:
        headers["Idempotency-Key"] = idempotency_key
    start = threading.Barrier(N_CLIENTS)
    statuses: list[int] = []
    answers: list[dict] = []
    lock = threading.Lock()

    with TestClient(app) as client:

        def send() -> None:
            start.wait()
            response = client.post("/api/v1/snapshots", json=body, headers=headers)
            with lock:
                statuses.append(response.status_code)
                answers.append(response.json())

        threads = [threading.Thread(target=send) for _ in range(N_CLIENTS)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join(timeout=120)

    assert Counter(statuses) == {201: 1, 200: N_CLIENTS - 1}, answers
    upload_ids = {answer["id"] for answer in answers}
    assert len(upload_ids) == 1  # every replay names the one stored upload
    with transaction(factory) as session:
        stored = session.scalar(
            select(func.count()).select_from(Upload).where(
                Upload.operator_id == fleet.operator_id, Upload.status == "stored"
            )
        )
        snapshots = session.scalar(
            select(func.count()).select_from(Snapshot).where(
                Snapshot.operator_id == fleet.operator_id
            )
        )
    assert (stored, snapshots) == (1, 40)
    engine.dispose()
