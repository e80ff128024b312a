"""A PostgreSQL outage under a stream of uploads loses no acknowledged row.

A private PostgreSQL (initdb in a temporary folder, its own port) serves the application while a
client uploads small batches one after another, each with its own Idempotency-Key. Midway the
server is stopped in immediate mode (as a crash would: no checkpoint, connections cut) and
started again. Meanwhile the API answers 503 with Retry-After; the client waits and retries the
same batch with the same key, as the documentation tells it to. At the end every acknowledged
batch is stored exactly once and nothing else is: 0 acknowledged rows lost, none duplicated.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
import time
import uuid
from collections.abc import Iterator
from datetime import timedelta
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import func, select

from app.config import Settings
from app.db import make_engine, make_sessionmaker
from app.main import create_app
from app.migrate import upgrade
from app.models import Snapshot
from tests.support.fleet_fixture import T0, json_body, make_fleet, snapshot_rows
from tests.support.server import free_port

BATCHES = 24
ROWS = 8
CUT_AFTER = 8  # batches acknowledged before the crash


def _binary(name: str) -> str | None:
    found = shutil.which(name)
    if found:
        return found
    for candidate in sorted(Path("/usr/lib/postgresql").glob(f"*/bin/{name}"), reverse=True):
        return str(candidate)
    return None


def _as_postgres(args: list[str]) -> list[str]:
    """PostgreSQL refuses to run as root: run its tools as the postgres user then."""
    if os.geteuid() != 0:
        return args
    runuser = shutil.which("runuser")
    if runuser is None:
        pytest.skip("running as root without runuser: cannot start a private PostgreSQL")
    return [runuser, "-u", "postgres", "--", *args]



class PrivatePostgres:
    def __init__(self, root: Path) -> None:
        self.data = root / "pgdata"
        self.port = free_port()
        self.pg_ctl = _binary("pg_ctl")
        self.url = f"postgresql+psycopg://postgres@127.0.0.1:{self.port}/postgres"

    def _ctl(self, *args: str) -> None:
        assert self.pg_ctl is not None
        subprocess.run(_as_postgres([self.pg_ctl, "-D", str(self.data), *args]), check=True,
                       capture_output=True, timeout=120)

    def start(self) -> None:
        self._ctl("-w", "-l", str(self.data / "server.log"), "-o",
                  f"-p {self.port} -k {self.data} -c listen_addresses=127.0.0.1 -c fsync=on",
                  "start")

    def crash(self) -> None:
        self._ctl("-m", "immediate", "-w", "stop")


@pytest.fixture
def private_postgres() -> Iterator[PrivatePostgres]:
    initdb = _binary("initdb")
    if initdb is None or _binary("pg_ctl") is None:
        pytest.skip("no initdb/pg_ctl on this machine: cannot start a private PostgreSQL")
    # Not under pytest's temporary root: the postgres user must be able to reach the folder.
    root = Path(tempfile.mkdtemp(prefix="fleethealth-pg-"))
    if os.geteuid() == 0:
        shutil.chown(root, "postgres")
    server = PrivatePostgres(root)
    subprocess.run(_as_postgres([initdb, "-D", str(server.data), "-A", "trust", "-U", "postgres",
                                 "--no-sync"]), check=True, capture_output=True, timeout=300)
    server.start()
    try:
        yield server
    finally:
        try:
            server.crash()
        except subprocess.CalledProcessError:
            pass  # already stopped
        shutil.rmtree(root, ignore_errors=True)


def _stored(url: str, operator_id: int) -> int:
    engine = make_engine(url)
    try:
        with make_sessionmaker(engine)() as session:
            return int(session.scalar(select(func.count()).select_from(Snapshot).where(
                Snapshot.operator_id == operator_id)) or 0)
    finally:
        engine.dispose()


def test_a_postgresql_crash_under_uploads_loses_no_acknowledged_row(
    private_postgres: PrivatePostgres, tmp_path: Path
) -> None:
    url = private_postgres.url
    upgrade(url)
    engine = make_engine(url, connect_args={"connect_timeout": 2})
    with make_sessionmaker(engine)() as session:
        fleet = make_fleet(session)
        session.commit()
    app = create_app(Settings(data_dir=tmp_path / "data", database_url=url, log_json=False),
                     engine)
    client = TestClient(app, raise_server_exceptions=False)

    acknowledged: list[int] = []  # batch numbers the API acknowledged (2xx)
    answers: dict[int, int] = {}  # status code -> how many times it was answered
    crashed_at = restarted_at = None
    for batch in range(BATCHES):
        start = T0 + timedelta(hours=batch)  # distinct records per batch
        body = json_body(snapshot_rows(ROWS, seed=batch, start=start))
        key = f"outage-{uuid.uuid4().hex}"
        if batch == CUT_AFTER:
            private_postgres.crash()
            crashed_at = time.monotonic()
        deadline = time.monotonic() + 120
        while True:
            if crashed_at is not None and restarted_at is None \
                    and time.monotonic() - crashed_at > 2.0:
                private_postgres.start()
                restarted_at = time.monotonic()
            response = client.post("/api/v1/snapshots", json=body,
                                   headers={**fleet.analyst, "Idempotency-Key": key})
            answers[response.status_code] = answers.get(response.status_code, 0) + 1
            if response.status_code in (200, 201):
                acknowledged.append(batch)
                break
            # The documented contract: 503 means nothing was stored; retry the same key.
            assert response.status_code == 503, response.text
            assert int(response.headers["Retry-After"]) > 0
            assert time.monotonic() < deadline, "the service did not recover"
            time.sleep(0.2)
    engine.dispose()

    assert restarted_at is not None
    assert answers.get(503, 0) >= 1, answers  # the outage was seen by the client
    assert acknowledged == list(range(BATCHES))
    assert _stored(url, fleet.operator_id) == BATCHES * ROWS  # none lost, none twice
