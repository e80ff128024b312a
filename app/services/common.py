"""Helpers every service shares: paging, ownership checks, conflicts, field errors, garbage
collector pauses."""

from __future__ import annotations

import gc
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from typing import Any, TypeVar

import numpy as np
from sqlalchemy import Select, func, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from app.errors import Conflict, InvalidInput, NotFound
from app.models.base import Base

RowT = TypeVar("RowT", bound=Base)


def field_error(field: str, reason: str, *, where: str = "body") -> InvalidInput:
    """422 naming one field, in the same shape as request validation errors."""
    return InvalidInput(
        f"{field}: {reason}", details=[{"location": [where, field], "reason": reason}]
    )


def paginate(
    session: Session, stmt: Select[Any], *, limit: int, offset: int
) -> tuple[list[Any], int]:
    """One page of ``stmt``'s rows (it must be ordered) and the total count."""
    total = session.scalar(select(func.count()).select_from(stmt.order_by(None).subquery()))
    rows = list(session.scalars(stmt.limit(limit).offset(offset)).unique())
    return rows, int(total or 0)


def owned(session: Session, model: type[RowT], operator_id: int, row_id: int, what: str) -> RowT:
    """The operator's row ``row_id`` of ``model`` or NotFound (also for another operator's)."""
    row = session.get(model, row_id)
    if row is None or getattr(row, "operator_id", None) != operator_id:
        raise NotFound(f"{what} {row_id} not found")
    return row


def referenced(
    session: Session, model: type[RowT], operator_id: int, row_id: int, field: str, what: str
) -> RowT:
    """A row named in a request body: a missing (or foreign) one is a 422 naming the field."""
    row = session.get(model, row_id)
    if row is None or getattr(row, "operator_id", None) != operator_id:
        raise field_error(field, f"no {what} {row_id} in your fleet")
    return row


def savepoints_hold(session: Session) -> bool:
    """Whether a SAVEPOINT nests inside the session's transaction.

    Not on a pysqlite connection in its default (legacy) transaction mode: there no BEGIN is
    sent before the first write, so an outermost SAVEPOINT opens the transaction and its
    RELEASE commits it, work of the request included.
    """
    connection = session.connection()
    if connection.dialect.name != "sqlite":
        return True
    return getattr(connection.connection.dbapi_connection, "isolation_level", "") is None


def flush_or_conflict(session: Session, message: str) -> None:
    """Flush; a uniqueness, reference or exclusion violation becomes 409.

    Inside a savepoint where savepoints hold (the session stays usable after the 409);
    elsewhere the failed flush leaves the request's transaction to be rolled back.
    """
    try:
        if savepoints_hold(session):
            with session.begin_nested():
                session.flush()
        else:
            session.flush()
    except IntegrityError as exc:
        raise Conflict(message, details=[{"reason": str(exc.orig).splitlines()[0]}]) from None


def delete_or_conflict(session: Session, row: Base, message: str) -> None:
    """Delete ``row``; if other rows still refer to it, 409 and nothing changes."""
    try:
        if savepoints_hold(session):
            with session.begin_nested():
                session.delete(row)
                session.flush()
        else:
            session.delete(row)
            session.flush()
    except IntegrityError:
        raise Conflict(message) from None


def apply_changes(row: Base, changes: Mapping[str, Any]) -> None:
    for name, value in changes.items():
        setattr(row, name, value)




@contextmanager
def no_gc_pauses() -> Iterator[None]:
    """The cyclic garbage collector off for a piece of work that allocates many small objects
    and creates no cycles worth finding (an estimation batch, the fleet status), while each
    full collection walks every object of the process (a third of a 1000-engine batch's time
    in a server process)."""
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()


def json_numbers_or_null(column: np.ndarray) -> list[float | None]:
    """JSON numbers rounded to four decimals; a missing value (NaN) becomes null."""
    rounded = np.round(column, 4)
    if not np.isnan(rounded).any():
        return rounded.tolist()
    return [None if np.isnan(v) else v for v in rounded.tolist()]
