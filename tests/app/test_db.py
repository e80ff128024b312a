"""Transactions behave alike on both backends: a rolled-back outer transaction undoes commits
made inside it as savepoints (what every test relies on), and a savepoint rolls back alone."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest
from sqlalchemy import Engine, func, select, text
from sqlalchemy.exc import OperationalError
from sqlalchemy.orm import Session

from app.db import (
    WriteGate,
    make_engine,
    make_sessionmaker,
    read_phase,
    record_after_rollback,
    transaction,
    write_gate,
    writing,
)
from app.models import Operator


def _operators(engine: Engine) -> int:
    with Session(engine) as session:
        return session.scalar(select(func.count()).select_from(Operator)) or 0


def test_commits_inside_an_outer_transaction_roll_back_with_it(db_engine: Engine) -> None:
    before = _operators(db_engine)
    with db_engine.connect() as connection:
        outer = connection.begin()
        with Session(connection, join_transaction_mode="create_savepoint") as session:
            session.add(Operator(name="Rolled Back Air"))
            session.commit()
            assert session.scalar(select(func.count()).select_from(Operator)) == before + 1
        outer.rollback()
    assert _operators(db_engine) == before


def test_a_savepoint_rolls_back_alone(db_engine: Engine) -> None:
    with db_engine.connect() as connection:
        outer = connection.begin()
        with Session(connection) as session:
            session.add(Operator(name="Kept Air"))
            session.flush()
            nested = session.begin_nested()
            session.add(Operator(name="Dropped Air"))
            session.flush()
            nested.rollback()
            names = set(session.scalars(select(Operator.name)))
            assert "Kept Air" in names and "Dropped Air" not in names
        outer.rollback()


def _file_engine(tmp_path: Path) -> Engine:
    from app.db import make_engine
    from app.migrate import upgrade

    url = f"sqlite:///{tmp_path / 'locks.sqlite3'}"
    upgrade(url)
    return make_engine(url)


def _insert_elsewhere(engine: Engine, name: str) -> None:
    with Session(engine) as other:
        other.add(Operator(name=name))
        other.commit()


def test_sqlite_deferred_read_then_write_fails_after_a_concurrent_commit(tmp_path: Path) -> None:
    # Why writers must say so: the stale-snapshot failure that ``writing`` prevents.
    engine = _file_engine(tmp_path)
    with Session(engine) as session:
        session.scalar(select(func.count()).select_from(Operator))
        _insert_elsewhere(engine, "Between Air")
        session.add(Operator(name="Late Air"))
        with pytest.raises(OperationalError, match="locked"):
            session.flush()
    engine.dispose()


def test_sqlite_writing_session_holds_the_lock_from_its_first_read(tmp_path: Path) -> None:
    engine = _file_engine(tmp_path)
    with Session(engine) as session:
        writing(session)
        session.scalar(select(func.count()).select_from(Operator))
        failures: list[BaseException] = []

        def competing_writer() -> None:
            try:
                with engine.connect() as connection:
                    connection.exec_driver_sql("PRAGMA busy_timeout = 100")
                    connection.execute(Operator.__table__.insert().values(name="Queued Air"))
                    connection.commit()
            except OperationalError as exc:
                failures.append(exc)

        thread = threading.Thread(target=competing_writer)
        thread.start()
        thread.join()
        assert failures and "locked" in str(failures[0])  # it had to wait: we hold the lock
        session.add(Operator(name="First Air"))
        session.commit()  # and our write goes through
    with Session(engine) as check:
        assert set(check.scalars(select(Operator.name))) == {"First Air"}
    engine.dispose()


def test_json_columns_read_back_what_was_written_floats_bit_for_bit(
    session: Session,
) -> None:
    """``json_text`` (the engines' JSON encoder) against ``json.dumps``, and through a JSON
    column of each backend: floats across the whole exponent range, -0.0, subnormals, big
    integers, non-ASCII text and integer keys come back as the standard encoder's would."""
    import json

    import numpy as np

    from app.db import json_text
    from app.models.estimates import FilterState

    rng = np.random.default_rng(7)
    floats = (rng.normal(size=5000) * 10.0 ** rng.integers(-300, 300, 5000)).tolist()
    document = {"floats": [*floats, -0.0, 5e-324, 1.7976931348623157e308], 3: "trois",
                "text": "é\u2028\"quoted\"", "big": 10**30, "none": None, "flag": True,
                "nested": {"P": rng.normal(size=(6, 6)).tolist()}}
    assert json.loads(json_text(document)) == json.loads(json.dumps(document))
    back = json.loads(json_text(document))["floats"]
    assert [x.hex() for x in back] == [x.hex() for x in document["floats"]]  # type: ignore[union-attr]

    fleet = make_fleet_for_state(session)
    state = FilterState(operator_id=fleet[0], engine_id=fleet[1], design_id=fleet[2],
                        layout={}, state={"floats": floats[:500]}, n_records=0)
    session.add(state)
    session.flush()
    session.expire(state)
    # JSONB keeps numbers as decimals: 1e300 reads back as the integer 10**300, whose float
    # is 1e300 again (readers of states convert with float()).
    assert [float(x).hex() for x in state.state["floats"]] == [x.hex() for x in floats[:500]]


def make_fleet_for_state(session: Session) -> tuple[int, int, int]:
    """An operator, an engine and a design to hang a filter state on."""
    from tests.app.services.trends.test_trends import add_engine, make_fleet

    fleet = make_fleet(session, "JSON Air")
    engine = add_engine(session, fleet, "J1")
    return fleet.operator_id, engine.id, fleet.design.id


def test_a_record_asked_for_survives_the_rollback_of_its_unit(tmp_path: Path) -> None:
    """``record_after_rollback``: the unit's work is rolled back, the record alone commits."""
    engine = make_engine(f"sqlite:///{tmp_path / 'unit.db'}")
    with engine.begin() as connection:
        connection.execute(text("CREATE TABLE notes (text TEXT)"))
    factory = make_sessionmaker(engine)

    def record(session: Session) -> None:
        session.execute(text("INSERT INTO notes VALUES ('refused')"))

    with pytest.raises(ValueError), transaction(factory) as session:
        session.execute(text("INSERT INTO notes VALUES ('work')"))
        record_after_rollback(session, record)
        raise ValueError("refused")
    with transaction(factory) as session:
        assert session.scalars(text("SELECT text FROM notes")).all() == ["refused"]
        session.execute(text("INSERT INTO notes VALUES ('next')"))
    with pytest.raises(ValueError), transaction(factory) as session:
        raise ValueError("nothing asked for")  # a later unit does not repeat the record
    with engine.connect() as connection:
        notes = connection.execute(text("SELECT text FROM notes")).scalars().all()
    assert notes == ["refused", "next"]
    engine.dispose()


def test_the_write_gate_admits_in_arrival_order_up_to_its_capacity() -> None:
    gate = WriteGate(capacity=2)
    assert gate.acquire(0.1) and gate.acquire(0.1)
    assert not gate.acquire(0.05)  # full: the wait runs out, and the turn is given up
    order: list[int] = []
    waiters = []
    for k in range(4):
        queued = threading.Event()

        def wait(k: int = k, queued: threading.Event = queued) -> None:
            queued.set()
            assert gate.acquire(5.0)
            order.append(k)
            gate.release()

        thread = threading.Thread(target=wait)
        thread.start()
        queued.wait()
        time.sleep(0.05)  # in the queue before the next one arrives
        waiters.append(thread)
    assert order == []  # both turns still held
    gate.release()  # one turn, passed from waiter to waiter in the order they came
    for thread in waiters:
        thread.join(5.0)
    assert order == [0, 1, 2, 3]
    gate.release()
    assert gate.acquire(0.1) and gate.acquire(0.1) and not gate.acquire(0.05)


def test_sqlite_read_phase_holds_no_lock_and_its_writes_follow_a_concurrent_commit(
    tmp_path: Path,
) -> None:
    """What a job reads in ``read_phase`` blocks no writer, and the writes after it do not
    fail for the snapshot having gone stale meanwhile (compare the deferred test above)."""
    engine = _file_engine(tmp_path)
    with Session(engine) as session:
        with read_phase(session) as apart:
            assert apart
            session.scalar(select(func.count()).select_from(Operator))
            with engine.connect() as other:  # a writer that would not wait at all
                other.exec_driver_sql("PRAGMA busy_timeout = 0")
                other.execute(Operator.__table__.insert().values(name="Between Air"))
                other.commit()
        assert not session.in_transaction()  # the read let go of its snapshot
        session.add(Operator(name="Late Air"))
        session.commit()
    assert _operators(engine) == 2
    engine.dispose()


def test_read_phase_is_a_no_op_where_not_enabled_or_not_sqlite(db_engine: Engine) -> None:
    with Session(db_engine) as session:
        session.scalar(select(func.count()).select_from(Operator))
        with read_phase(session, enabled=db_engine.dialect.name == "sqlite") as apart:
            # PostgreSQL, or disabled: the reads join the open transaction.
            assert apart == (db_engine.dialect.name == "sqlite")
            assert session.in_transaction() != apart
        session.rollback()


_HOLD_GATE = """
import sys, time
from app.db import make_engine, write_gate
gate = write_gate(make_engine(sys.argv[1]))
assert gate.acquire(5.0)
print("held", flush=True)
time.sleep(float(sys.argv[2]))
gate.release()
"""


def test_the_sqlite_write_gate_lets_one_writer_in_across_processes(tmp_path: Path) -> None:
    """A writer of another process (the job process beside the server) holds the file's
    write turn: this process's writer waits for it, and gets it the moment it is let go."""
    import subprocess
    import sys

    url = f"sqlite:///{tmp_path / 'gate.sqlite3'}"
    holder = subprocess.Popen([sys.executable, "-c", _HOLD_GATE, url, "0.6"],
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        gate = write_gate(make_engine(url))
        assert gate is not None
        t0 = time.perf_counter()
        assert gate.acquire(5.0)
        waited = time.perf_counter() - t0
        gate.release()
    finally:
        holder.wait(10)
    assert holder.returncode == 0
    assert 0.3 < waited < 5.0  # not before the other process let go
