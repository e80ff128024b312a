"""Test-only job kinds and helpers shared by the job tests."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from pydantic import BaseModel, ConfigDict
from sqlalchemy import Connection, Engine, delete, func, select
from sqlalchemy.orm import Session, sessionmaker

from app.db import make_engine, make_sessionmaker, transaction
from app.migrate import upgrade
from app.models import ApiKey, Job, JobSchedule, Operator
from app.services.jobs.registry import JobRegistry, Progress
from app.services.tenancy import service as tenancy
from tests.conftest import BACKENDS, _backend_use, fresh_database_url


@pytest.fixture
def connection(db_engine: Engine) -> Iterator[Connection]:
    """The shared ``connection`` fixture, starting from no jobs and no schedules at all.

    Job tests count and run every queued job; rows that committing tests of other modules
    left in a shared database are deleted inside the rolled-back transaction.
    """
    _backend_use[db_engine.dialect.name] += 1
    with db_engine.connect() as connection:
        outer = connection.begin()
        connection.execute(delete(Job.__table__))
        connection.execute(delete(JobSchedule.__table__))
        yield connection
        outer.rollback()


class AddParameters(BaseModel):
    model_config = ConfigDict(extra="forbid")

    a: int
    b: int = 0


class NoteParameters(BaseModel):
    model_config = ConfigDict(extra="forbid")

    name: str


@dataclass
class Gates:
    """Events a waiting job and its test use to meet."""

    started: threading.Event = field(default_factory=threading.Event)
    release: threading.Event = field(default_factory=threading.Event)
    side_effects: list[str] = field(default_factory=list)


def make_registry(gates: Gates | None = None) -> JobRegistry:
    """A registry of test kinds: add, boom, wait, spin; each writes or reports something real."""
    gates = gates or Gates()
    registry = JobRegistry()

    @registry.job("add", parameters=AddParameters, description="a + b, in two progress steps")
    def add(
        session: Session, parameters: AddParameters, progress: Progress, *, operator_id: int
    ) -> dict[str, Any]:
        progress(0.5, "added a")
        return {"sum": parameters.a + parameters.b, "operator_id": operator_id}

    @registry.job("boom", parameters=NoteParameters, description="writes a row, then raises")
    def boom(
        session: Session, parameters: NoteParameters, progress: Progress, *, operator_id: int
    ) -> dict[str, Any]:
        session.add(Operator(name=parameters.name))
        session.flush()
        raise ValueError(f"boom after writing {parameters.name}")

    @registry.job("wait", parameters=NoteParameters, description="reports half, waits, writes")
    def wait(
        session: Session, parameters: NoteParameters, progress: Progress, *, operator_id: int
    ) -> dict[str, Any]:
        progress(0.5, f"half way: {parameters.name}")
        gates.started.set()
        if not gates.release.wait(timeout=30):
            raise TimeoutError("the test never released the job")
        session.add(Operator(name=parameters.name))
        return {"name": parameters.name}

    @registry.job("spin", parameters=NoteParameters, description="commits, reports, writes")
    def spin(
        session: Session, parameters: NoteParameters, progress: Progress, *, operator_id: int
    ) -> dict[str, Any]:
        # A first chunk committed, as long jobs do (it also frees SQLite's write lock, so the
        # progress reports below can be written).
        session.add(Operator(name=f"{parameters.name}: first chunk"))
        session.commit()
        gates.started.set()
        for step in range(3000):
            progress(step / 3000, f"step {step}")
            time.sleep(0.01)
        session.add(Operator(name=f"{parameters.name}: last chunk"))
        return {"steps": 3000}

    @registry.job("chunks", parameters=NoteParameters, description="read, report, write x3")
    def chunks(
        session: Session, parameters: NoteParameters, progress: Progress, *, operator_id: int
    ) -> dict[str, Any]:
        # The pipeline's shape: each chunk reads, reports, writes and commits.
        for chunk in range(3):
            before = session.scalar(select(func.count()).select_from(Operator))
            progress(chunk / 3, f"{parameters.name}: chunk {chunk}")
            session.add(Operator(name=f"{parameters.name} {chunk} after {before}"))
            session.commit()
            if chunk == 0:
                gates.started.set()
                if not gates.release.wait(timeout=30):
                    raise TimeoutError("the test never released the job")
        return {"chunks": 3}

    return registry


@pytest.fixture
def registry() -> JobRegistry:
    """The test kinds (``make_registry``)."""
    return make_registry()


@pytest.fixture
def jobs_client(app: FastAPI, registry: JobRegistry) -> Iterator[TestClient]:
    """A client of the app running the test kinds."""
    app.state.job_registry = registry
    with TestClient(app) as test_client:
        yield test_client


def make_operator(session: Session, name: str, role: str = "admin") -> tuple[Operator, str]:
    operator = tenancy.create_operator(session, name=name)
    _row, key = tenancy.issue_api_key(session, operator=operator, role=role, name=role)
    return operator, key


def add_key(session: Session, operator: Operator, role: str) -> str:
    _row, key = tenancy.issue_api_key(session, operator=operator, role=role, name=role)
    return key


def job_row(factory: sessionmaker[Session], job_id: int) -> Job:
    with transaction(factory) as session:
        job = session.get(Job, job_id)
        assert job is not None
        return job


def operator_exists(factory: sessionmaker[Session], name: str) -> bool:
    with transaction(factory) as session:
        return session.scalar(select(Operator.id).where(Operator.name == name)) is not None


def wait_until(condition: Callable[[], bool], what: str, timeout: float = 20.0) -> None:
    """Poll ``condition`` until true; fail naming ``what`` after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.02)


@contextmanager
def live_database(backend: str, tmp_path: Path) -> Iterator[tuple[str, sessionmaker[Session]]]:
    """A fresh migrated database that really commits (for threads and worker processes)."""
    urls = fresh_database_url(backend, tmp_path)
    url = next(urls)
    upgrade(url)
    engine = make_engine(url)
    try:
        yield url, make_sessionmaker(engine)
    finally:
        engine.dispose()
        urls.close()


Live = tuple[str, sessionmaker[Session]]


@pytest.fixture(scope="module", params=BACKENDS)
def live_module(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[Live]:
    """One really-committing database per backend for a test module (made once: it is slow)."""
    with live_database(request.param, tmp_path_factory.mktemp(f"live-{request.param}")) as live:
        yield live


@pytest.fixture
def live(live_module: Live) -> Iterator[Live]:
    """The module's live database, emptied of the rows job tests make after each test."""
    yield live_module
    with transaction(live_module[1]) as session:
        for table in (Job, JobSchedule, ApiKey, Operator):
            session.execute(delete(table))
