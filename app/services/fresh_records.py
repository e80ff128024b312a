"""Records of just-committed snapshot uploads, kept in this process for the estimation job.

An upload's rows are parsed, validated and resolved in memory, stored, and the estimation job
that follows needs the same numbers back. When that job runs in the process that stored them
(the in-process job runner), it takes them from here instead of reading them back from the
database: on 100,000 records that read is 0.3-0.6 s, a third of the job.

Kept rows are exactly the stored rows (the upload's new rows after deduplication, the
columns of the ``snapshots`` table, values as COPYed, and each signal outside the catalogue
as a column of its own, ``app.signals.stored_at``), registered only once their transaction
has committed. A job uses them for an engine only when they are complete: as many as the
engine's backlog marks count when it continues from its filter state, else as many as the
database counts after its restart point (kept rows are stored rows, so equal counts mean the
same rows); otherwise it reads the database, as a job in another process always does. What a
job takes is dropped; the rest is bounded (``MAX_RECORDS``, oldest uploads dropped first) and
gone with the process.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Iterable

import pyarrow as pa
import pyarrow.compute as pc
from sqlalchemy import event
from sqlalchemy.orm import Session, SessionTransaction

MAX_RECORDS = 500_000  # about 100 MB of snapshot columns at most

_enabled = True  # off where jobs run in other processes (Celery): nothing would take them
_lock = threading.Lock()
# (database url, upload id) -> the upload's stored rows and the engines they are of
_kept: OrderedDict[tuple[str, int], tuple[pa.Table, frozenset[int]]] = OrderedDict()


def configure(*, enabled: bool) -> None:
    """Keep uploads' records or not (the app factory: not when jobs run under Celery)."""
    global _enabled
    _enabled = enabled
    if not enabled:
        clear()


def _database(session: Session) -> str:
    return session.connection().engine.url.render_as_string(hide_password=True)


def keep_after_commit(session: Session, upload_id: int, rows: pa.Table) -> None:
    """Keep ``rows`` (columns of ``snapshots``, at least engine_id and recorded_at) for the
    estimation job once the session's transaction commits; nothing if it rolls back."""
    if not _enabled or rows.num_rows == 0 or rows.num_rows > MAX_RECORDS:
        return
    key = (_database(session), upload_id)
    engines = frozenset(pc.unique(rows["engine_id"]).to_pylist())
    ended = False

    def keep(_session: Session) -> None:
        nonlocal ended
        if ended:
            return
        ended = True
        with _lock:
            _kept[key] = (rows, engines)
            total = sum(entry[0].num_rows for entry in _kept.values())
            while total > MAX_RECORDS:
                _old, (dropped, _e) = _kept.popitem(last=False)
                total -= dropped.num_rows

    def forget(_session: Session) -> None:
        nonlocal ended
        ended = True  # rolled back: a later commit of this session is not this upload's

    # The rows belong to the innermost transaction (a savepoint where the caller opened one):
    # its rollback, or an enclosing one's, drops them even when the session later commits.
    inserted_in = session.get_nested_transaction() or session.get_transaction()

    def forget_savepoint(_session: Session, previous: SessionTransaction) -> None:
        nonlocal ended
        transaction = inserted_in
        while transaction is not None:
            if transaction is previous:
                ended = True
                return
            transaction = transaction.parent

    event.listen(session, "after_commit", keep)
    event.listen(session, "after_rollback", forget)
    event.listen(session, "after_soft_rollback", forget_savepoint)


def kept_rows(session: Session) -> int:
    """How many rows are kept for the session's database."""
    database = _database(session)
    with _lock:
        return sum(entry[0].num_rows for k, entry in _kept.items() if k[0] == database)


def take(session: Session, engine_ids: Iterable[int]) -> pa.Table | None:
    """Every kept row of these engines, sorted by engine and time, removed from the store
    (None when there is none)."""
    parts = _remove(session, engine_ids)
    if not parts:
        return None
    # Uploads of engine types with signals of their own carry other columns: unified, a
    # column an upload lacks is null there.
    table = pa.concat_tables(parts, promote_options="default") if len(parts) > 1 else parts[0]
    table = table.set_column(
        table.schema.get_field_index("engine_id"), "engine_id",
        pc.cast(table["engine_id"], pa.int64()),
    ).set_column(
        table.schema.get_field_index("recorded_at"), "recorded_at",
        pc.cast(table["recorded_at"], pa.timestamp("us", tz="UTC")),
    )
    return table.take(pc.sort_indices(
        table, sort_keys=[("engine_id", "ascending"), ("recorded_at", "ascending")]
    ))


def discard(session: Session, engine_ids: Iterable[int]) -> None:
    """Drop what is kept of these engines (the job found nothing to do with it: no active
    design, or already estimated), so it does not sit in memory until evicted."""
    _remove(session, engine_ids)


def _remove(session: Session, engine_ids: Iterable[int]) -> list[pa.Table]:
    wanted_ids = set(engine_ids)
    wanted = pa.array(sorted(wanted_ids), pa.int64())
    database = _database(session)
    parts: list[pa.Table] = []
    with _lock:
        for key in [k for k in _kept if k[0] == database]:
            table, engines = _kept[key]
            if engines.isdisjoint(wanted_ids):
                continue
            if engines <= wanted_ids:
                parts.append(table)
                del _kept[key]
                continue
            inside = pc.is_in(pc.cast(table["engine_id"], pa.int64()), value_set=wanted)
            parts.append(table.filter(inside))
            _kept[key] = (table.filter(pc.invert(inside)), engines - wanted_ids)
    return parts


def clear() -> None:
    """Forget everything kept (and what a test's rolled-back transaction committed inside
    it: tests clear after each one)."""
    with _lock:
        _kept.clear()
