"""Database engine and sessions. Services receive sessions; they never open or commit their own."""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from pydantic_core import to_json
from sqlalchemy import Engine, create_engine, event, text
from sqlalchemy.engine import make_url
from sqlalchemy.orm import Session, sessionmaker

from app.errors import ServiceUnavailable

# How long a writer waits for the database: SQLite's busy timeout, and the write gate's.
BUSY_TIMEOUT_S = 30.0


def make_engine(url: str, **kwargs: Any) -> Engine:
    """An engine for ``url``; SQLite files get WAL, foreign keys and a busy timeout."""
    parsed = make_url(url)
    if parsed.get_backend_name() == "sqlite":
        if parsed.database and parsed.database != ":memory:":
            Path(parsed.database).parent.mkdir(parents=True, exist_ok=True)
        engine = create_engine(
            url, connect_args={"check_same_thread": False, "timeout": BUSY_TIMEOUT_S},
            json_serializer=json_text, **kwargs,
        )
        event.listen(engine, "connect", _sqlite_pragmas)
        event.listen(engine, "begin", _sqlite_begin)
        return engine
    if parsed.get_backend_name() == "postgresql" and parsed.drivername == "postgresql":
        url = str(parsed.set(drivername="postgresql+psycopg"))
    return create_engine(url, pool_pre_ping=True, json_serializer=json_text, **kwargs)


def json_text(document: Any) -> str:
    """JSON columns' text: pydantic-core's encoder (shortest round-trip floats). It reads back
    as the same values as ``json.dumps`` writes, floats bit for bit, in a tenth of the time
    (an estimation job writes a filter state of a few hundred floats per engine)."""
    return to_json(document).decode()


def _sqlite_pragmas(dbapi_connection: Any, _record: Any) -> None:
    cursor = dbapi_connection.cursor()
    cursor.execute("PRAGMA journal_mode=WAL")
    cursor.execute("PRAGMA foreign_keys=ON")
    cursor.execute("PRAGMA synchronous=NORMAL")
    cursor.close()
    # pysqlite's own transaction handling sends no BEGIN before a SAVEPOINT, so releasing a
    # savepoint would commit for good. Take BEGIN over (SQLAlchemy's pysqlite recipe).
    dbapi_connection.isolation_level = None


SQLITE_BEGIN = "sqlite_begin"


def _sqlite_begin(connection: Any) -> None:
    # DEFERRED by default: readers never wait. A transaction that will write should say
    # IMMEDIATE (``writing``): a deferred one that reads, then writes after another connection
    # committed, fails at once with "database is locked" (its snapshot is stale).
    mode = connection.get_execution_options().get(SQLITE_BEGIN, "DEFERRED")
    connection.exec_driver_sql(f"BEGIN {mode}")


def writing(session: Session) -> Session:
    """Mark ``session``'s next transaction as one that writes: on SQLite it takes the write
    lock at its first statement (BEGIN IMMEDIATE), so concurrent writers queue instead of
    failing. Call before the session's first statement; a no-op elsewhere."""
    session.connection(execution_options={SQLITE_BEGIN: "IMMEDIATE"})
    return session


class WriteGate:
    """At most ``capacity`` writing transactions at a time on one database in this process,
    first come first served.

    SQLite lets one writer in at a time; the others wait in its busy handler, which polls with
    sleeps growing to 100 ms. Under many concurrent writers that is unfair (a writer can lose
    every race for many seconds while others pass) and it wastes the gaps between writers.
    Writers of this process therefore queue here, in arrival order, before they take SQLite's
    write lock (capacity 1); the busy handler stays the guard against other processes.

    PostgreSQL takes concurrent writers, but a write request is mostly Python work (parse,
    validate, resolve), and this process runs Python one thread at a time: sixteen uploads
    admitted at once share the interpreter and each takes sixteen times as long, while the
    pages being read wait behind them. A few at a time (``POSTGRES_WRITERS``), in order, finish
    sooner on average and leave readers their turn.
    """

    def __init__(self, capacity: int = 1) -> None:
        self._lock = threading.Lock()
        self._free = capacity
        self._waiting: deque[threading.Event] = deque()

    def acquire(self, timeout: float) -> bool:
        """Wait for a turn, at most ``timeout`` seconds; False if none came."""
        with self._lock:
            if self._free > 0 and not self._waiting:
                self._free -= 1
                return True
            turn = threading.Event()
            self._waiting.append(turn)
        if turn.wait(timeout):
            return True
        with self._lock:
            if turn.is_set():  # handed over just as the wait ran out
                return True
            self._waiting.remove(turn)
            return False

    def release(self) -> None:
        with self._lock:
            if self._waiting:
                self._waiting.popleft().set()  # the turn passes straight to the next in line
            else:
                self._free += 1


# Concurrent writing transactions per PostgreSQL database in one process (see WriteGate).
POSTGRES_WRITERS = 2
_gates: dict[str, WriteGate] = {}
_gates_lock = threading.Lock()


def write_gate(engine: Engine) -> WriteGate | None:
    """The write gate of ``engine``'s database in this process: one writer at a time on a
    SQLite file, ``POSTGRES_WRITERS`` on PostgreSQL; None for an in-memory SQLite database."""
    if engine.dialect.name == "sqlite":
        if engine.url.database in (None, "", ":memory:"):
            return None
        key, capacity = str(Path(engine.url.database).resolve()), 1
    else:
        key, capacity = engine.url.render_as_string(hide_password=True), POSTGRES_WRITERS
    with _gates_lock:
        return _gates.setdefault(key, WriteGate(capacity))


def make_sessionmaker(engine: Engine) -> sessionmaker[Session]:
    return sessionmaker(bind=engine, expire_on_commit=False)


@contextmanager
def transaction(factory: sessionmaker[Session], *, write: bool = True) -> Iterator[Session]:
    """One unit of work: commit on success, roll back on any error (then write and commit
    what ``record_after_rollback`` asked for).

    ``write`` (the default) marks its first transaction as one that writes (see ``writing``);
    pass ``write=False`` for a read-only unit that should never wait for a writer.
    """
    bind = factory.kw.get("bind")
    gate = write_gate(bind) if write and isinstance(bind, Engine) else None
    if gate is not None and not gate.acquire(BUSY_TIMEOUT_S):
        raise ServiceUnavailable(f"the database is busy: no write turn in {BUSY_TIMEOUT_S:.0f} s")
    try:
        session = factory()
        if write:
            writing(session)
        try:
            yield session
            session.commit()
        except BaseException:
            session.rollback()
            records = session.info.pop(AFTER_ROLLBACK, [])
            if records:
                for record in records:
                    record(session)
                session.commit()
            raise
        finally:
            session.close()
    finally:
        if gate is not None:
            gate.release()


AFTER_ROLLBACK = "fleethealth.after_rollback"


def record_after_rollback(session: Session, record: Callable[[Session], None]) -> None:
    """Have the unit of work that owns ``session`` (``transaction``: a request, a job) write
    ``record`` after it rolls back on the error now being raised, and commit that alone: the
    record of a failure that must outlive it (a refused upload in the upload history)."""
    session.info.setdefault(AFTER_ROLLBACK, []).append(record)


def ping(engine: Engine) -> None:
    """Raise if the database does not answer."""
    with engine.connect() as connection:
        connection.execute(text("SELECT 1"))
