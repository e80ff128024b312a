"""Shared fixtures: every database test runs on SQLite and on PostgreSQL.

PostgreSQL tests skip with a reason where no server answers, except under CI (``CI`` set),
where an unreachable server is an error: CI on this machine must run them.
"""

from __future__ import annotations

import os
import uuid
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import Connection, Engine, create_engine, text
from sqlalchemy.engine import make_url
from sqlalchemy.orm import Session, sessionmaker

from app.config import Settings
from app.db import make_engine
from app.main import create_app
from app.migrate import upgrade
from app.services import fresh_records

POSTGRES_URL = os.environ.get(
    "FLEETHEALTH_TEST_POSTGRES_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/test"
)
BACKENDS = ("sqlite", "postgresql")
BACKEND_PROPERTY = "database backend"
_backend_use: Counter[str] = Counter()


def postgres_unavailable_reason() -> str | None:
    """None when the PostgreSQL test server answers, else why not."""
    try:
        engine = create_engine(POSTGRES_URL, connect_args={"connect_timeout": 3})
        with engine.connect() as connection:
            connection.execute(text("SELECT 1"))
        engine.dispose()
    except Exception as exc:  # any failure to reach the server means: no PostgreSQL here
        return (
            f"no PostgreSQL at {make_url(POSTGRES_URL).render_as_string(hide_password=True)}: {exc}"
        )
    return None


def require_postgres() -> None:
    reason = postgres_unavailable_reason()
    if reason is None:
        return
    if os.environ.get("CI"):
        pytest.fail(f"CI must run the PostgreSQL tests, but {reason}")
    pytest.skip(reason)


def fresh_database_url(backend: str, tmp_dir: Path) -> Iterator[str]:
    """A brand-new empty database on ``backend``, dropped afterwards."""
    if backend == "sqlite":
        yield f"sqlite:///{tmp_dir / f'fleethealth-{uuid.uuid4().hex[:8]}.sqlite3'}"
        return
    require_postgres()
    name = f"fleethealth_test_{uuid.uuid4().hex[:12]}"
    admin = create_engine(POSTGRES_URL, isolation_level="AUTOCOMMIT")
    with admin.connect() as connection:
        connection.execute(text(f'CREATE DATABASE "{name}"'))
    try:
        yield make_url(POSTGRES_URL).set(database=name).render_as_string(hide_password=False)
    finally:
        with admin.connect() as connection:
            connection.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        admin.dispose()


@pytest.fixture(scope="session", params=BACKENDS)
def database_url(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[str]:
    """A migrated database per backend, shared by the session's tests (each rolls back)."""
    generator = fresh_database_url(request.param, tmp_path_factory.mktemp(request.param))
    url = next(generator)
    upgrade(url)
    yield url
    generator.close()


@pytest.fixture(scope="session")
def db_engine(database_url: str) -> Iterator[Engine]:
    engine = make_engine(database_url)
    yield engine
    engine.dispose()


@pytest.fixture
def connection(db_engine: Engine, request: pytest.FixtureRequest) -> Iterator[Connection]:
    """A connection inside an outer transaction that is rolled back after the test."""
    request.node.user_properties.append((BACKEND_PROPERTY, db_engine.dialect.name))
    with db_engine.connect() as connection:
        outer = connection.begin()
        yield connection
        outer.rollback()
        fresh_records.clear()  # what the test committed inside the rolled-back transaction


@pytest.fixture
def session_factory(connection: Connection) -> sessionmaker[Session]:
    # Every commit inside the test becomes a SAVEPOINT release; the outer rollback undoes all.
    return sessionmaker(
        bind=connection, join_transaction_mode="create_savepoint", expire_on_commit=False
    )


@pytest.fixture
def session(session_factory: sessionmaker[Session]) -> Iterator[Session]:
    with session_factory() as session:
        yield session


@pytest.fixture
def settings(tmp_path: Path, database_url: str) -> Settings:
    return Settings(data_dir=tmp_path / "data", database_url=database_url, log_json=False)


@pytest.fixture
def app(settings: Settings, db_engine: Engine, session_factory: sessionmaker[Session]) -> FastAPI:
    application = create_app(settings, db_engine)
    application.state.sessionmaker = session_factory
    return application


@pytest.fixture
def client(app: FastAPI) -> Iterator[TestClient]:
    with TestClient(app) as test_client:
        yield test_client


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The files marked ``long`` first, longest first, the rest in their order. The test
    processes (``pytest -n``, ``--dist loadfile --no-loadscope-reorder``) are handed files in
    this order as they free up, so a long file is never the last one handed out while the
    other process idles (longest first: the usual greedy split of jobs over two workers)."""

    first: dict[Path, int] = {}
    for index, item in enumerate(items):
        first.setdefault(item.path, index)
    position = {id(item): index for index, item in enumerate(items)}

    def order(item: pytest.Item) -> tuple[float, int]:
        mark = item.get_closest_marker("long")
        if mark is None:
            return (0.0, position[id(item)])  # where pytest put it
        return (-float(mark.kwargs["seconds"]), first[item.path])

    items.sort(key=order)  # stable: a long file's tests stay in their order


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    """Counts the backends from the reports, which reach the controlling process from every
    worker when the suite runs in parallel (``pytest -n``)."""
    if report.when == "call":
        _backend_use.update(value for name, value in report.user_properties
                            if name == BACKEND_PROPERTY)


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    ran = ", ".join(f"{name} ({count} tests)" for name, count in sorted(_backend_use.items()))
    terminalreporter.write_line(f"database backends that ran: {ran or 'none'}")
