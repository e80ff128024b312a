"""Database engine and sessions. Services receive sessions; they never open or commit their own."""

from __future__ import annotations

import fcntl
import os
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


READ_PHASE = "fleethealth.read_phase"


@contextmanager
def read_phase(session: Session, enabled: bool = True) -> Iterator[bool]:
    """Run the statements inside as a read of one snapshot, without SQLite's write lock, and
    end that read at the close, so that the writes after it take the lock in a transaction of
    their own (for a job, BEGIN IMMEDIATE: see ``app.jobs.progress.SqliteTransactionWatch``).

    A job that reads much, computes long and then writes (the estimation of a batch of
    engines) would otherwise hold the one write lock of a SQLite file from its first read to
    its commit, and every upload would wait for the computation. Whatever the job read stays
    valid for its writes when the data it depends on only grows meanwhile, as the estimation
    backlog does (``app.services.snapshots.backlog``). The statements inside must not write.

    On SQLite, a transaction the session has open is committed first (callers pass
    ``enabled`` only where they own the commits: a job). Elsewhere, or not ``enabled``, a
    no-op: the reads join the session's transaction as usual. Yields whether the reads are
    apart from the writes that follow.
    """
    if not enabled or session.get_bind().dialect.name != "sqlite":
        yield False
        return
    if session.in_transaction():
        session.commit()
    session.info[READ_PHASE] = True
    try:
        yield True
    finally:
        del session.info[READ_PHASE]
    if session.in_transaction():
        session.commit()  # nothing was written: this only lets go of the snapshot


def in_read_phase(session: Session) -> bool:
    """Whether ``session`` is inside ``read_phase``."""
    return bool(session.info.get(READ_PHASE))


class WriteGate:
    """At most ``capacity`` writing transactions at a time on one database in this process,
    first come first served; on a SQLite file, also one at a time across processes.

    SQLite lets one writer in at a time; the others wait in its busy handler, which polls with
    sleeps growing to 100 ms. Under many concurrent writers that is unfair (a writer can lose
    every race for many seconds while others pass) and it wastes the gaps between writers.
    Writers of this process therefore queue here, in arrival order, before they take SQLite's
    write lock (capacity 1). The one whose turn it is then takes an exclusive ``flock`` on
    ``lock_file`` (the database's ``-writer`` file), where the writer of another process (the
    job process beside ``fleethealth serve``) waits in the kernel, woken the moment the lock
    is let go, instead of polling in SQLite's busy handler while this process's writers pass
    the lock from hand to hand. Each hold is one transaction, bounded by SQLite's own busy
    timeout. The busy handler stays the guard against writers that use no gate (the command
    line, migrations).

    PostgreSQL takes concurrent writers, but a write request is mostly Python work (parse,
    validate, resolve), and this process runs Python one thread at a time: sixteen uploads
    admitted at once share the interpreter and each takes sixteen times as long, while the
    pages being read wait behind them. A few at a time (``POSTGRES_WRITERS``), in order, finish
    sooner on average and leave readers their turn.
    """

    def __init__(self, capacity: int = 1, lock_file: Path | None = None) -> None:
        self._lock = threading.Lock()
        self._free = capacity
        self._waiting: deque[threading.Event] = deque()
        self._lock_file = lock_file
        self._fd: int | None = None

    def acquire(self, timeout: float) -> bool:
        """Wait for a turn, at most ``timeout`` seconds in this process's queue; False if none
        came."""
        with self._lock:
            if self._free > 0 and not self._waiting:
                self._free -= 1
                self._lock_across_processes()
                return True
            turn = threading.Event()
            self._waiting.append(turn)
        if not turn.wait(timeout):
            with self._lock:
                if not turn.is_set():
                    self._waiting.remove(turn)
                    return False
            # handed over just as the wait ran out
        self._lock_across_processes()
        return True

    def release(self) -> None:
        if self._fd is not None:
            fcntl.flock(self._fd, fcntl.LOCK_UN)
        self._pass_turn()

    def _lock_across_processes(self) -> None:
        if self._lock_file is None:
            return
        try:
            if self._fd is None:
                self._fd = os.open(self._lock_file, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o600)
            fcntl.flock(self._fd, fcntl.LOCK_EX)  # the GIL is let go while the kernel waits
        except OSError:
            self._pass_turn()
            raise

    def _pass_turn(self) -> None:
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
    SQLite file (and across processes), ``POSTGRES_WRITERS`` on PostgreSQL; None for an
    in-memory SQLite database."""
    if engine.dialect.name == "sqlite":
        if engine.url.database in (None, "", ":memory:"):
            return None
        path = Path(engine.url.database).resolve()
        key, capacity, lock_file = str(path), 1, path.with_name(path.name + "-writer")
    else:
        key, capacity = engine.url.render_as_string(hide_password=True), POSTGRES_WRITERS
        lock_file = None
    with _gates_lock:
        gate = _gates.get(key)
        if gate is None:
            gate = _gates[key] = WriteGate(capacity, lock_file)
        return gate


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
