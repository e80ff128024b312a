"""Transactions behave alike on both backends: a rolled-back outer transaction undoes commits
made inside it as savepoints (what every test relies on), and a savepoint rolls back alone."""

from __future__ import annotations

from sqlalchemy import Engine, func, select
from sqlalchemy.orm import Session

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
