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
same rows); otherwise it reads the database. What a job takes is dropped; the rest is bounded
(``MAX_RECORDS``, oldest uploads dropped first) and gone with the process.

Where the jobs run in child processes of the server (``fleethealth serve``'s job host and its
engine-group workers, ``app.jobs.host``), the rows go to them through a spool directory of the
server's (``configure(spool=...)``, emptied at start): each committed upload's rows as one
Arrow file, written under a temporary name and renamed once the transaction has committed, so
a file there is always a whole committed upload. Every process of the host reads the files
(memory-mapped) for the engines it estimates, with the same completeness check. A file is
deleted once a job leaves none of its engines with work (``discard`` at the end of a job), as
soon as the stored rows of one of them move to another engine (an installation change), or
when the spool holds more than ``SPOOL_RECORDS`` rows. A file deleted early only sends a job to
the database.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import threading
from collections import OrderedDict
from collections.abc import Iterable, Iterator
from pathlib import Path

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.ipc as ipc
from sqlalchemy import event
from sqlalchemy.orm import Session, SessionTransaction

MAX_RECORDS = 500_000  # about 100 MB of snapshot columns at most
# The spool's bound (files, about 200 MB): uploads arriving back to back while a job runs
# wait there for its next pass.
SPOOL_RECORDS = 1_000_000

log = logging.getLogger("fleethealth.uploads")

_enabled = True  # off where jobs run in other processes (Celery): nothing would take them
_spool: Path | None = None  # where the job host's processes take them from (``configure``)
_lock = threading.Lock()
# (database url, upload id) -> the upload's stored rows and the engines they are of
_kept: OrderedDict[tuple[str, int], tuple[pa.Table, frozenset[int]]] = OrderedDict()


def spool_directory(data_dir: Path) -> Path:
    """The spool of a server's job host (``configure``) under its data directory."""
    return Path(data_dir) / "fresh-records"


def configure(*, enabled: bool, spool: Path | None = None, empty: bool = False) -> None:
    """Keep uploads' records or not (the app factory: not when jobs run under Celery); in
    the files of ``spool`` rather than in memory (the server, its job host and workers name
    the same one), emptied first with ``empty`` (the server, as it starts)."""
    global _enabled, _spool
    _enabled = enabled
    _spool = spool
    if not enabled:
        clear()
    if spool is not None:
        spool.mkdir(parents=True, exist_ok=True)
        if empty:
            for path in [*spool.glob("*.arrow"), *spool.glob("*.part")]:
                path.unlink(missing_ok=True)


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

    spool = _spool
    if spool is not None:
        # Written now, named as committed once the transaction is (``keep``).
        pending = _spool_path(spool, key, rows.num_rows)
        written = _write_spooled(pending.with_suffix(".part"), rows)

    def keep(_session: Session) -> None:
        nonlocal ended
        if ended:
            return
        ended = True
        if spool is not None:
            if written:
                with contextlib.suppress(OSError):  # a job reads the database then
                    os.replace(pending.with_suffix(".part"), pending)
                    _bound_spool(spool, key[0])
            return
        with _lock:
            _kept[key] = (rows, engines)
            total = sum(entry[0].num_rows for entry in _kept.values())
            while total > MAX_RECORDS:
                _old, (dropped, _e) = _kept.popitem(last=False)
                total -= dropped.num_rows

    def forget(_session: Session) -> None:
        nonlocal ended
        if not ended and spool is not None:
            pending.with_suffix(".part").unlink(missing_ok=True)
        ended = True  # rolled back: a later commit of this session is not this upload's

    # The rows belong to the innermost transaction (a savepoint where the caller opened one):
    # its rollback, or an enclosing one's, drops them even when the session later commits.
    inserted_in = session.get_nested_transaction() or session.get_transaction()

    def forget_savepoint(_session: Session, previous: SessionTransaction) -> None:
        nonlocal ended
        transaction = inserted_in
        while transaction is not None:
            if transaction is previous:
                if not ended and spool is not None:
                    pending.with_suffix(".part").unlink(missing_ok=True)
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
        held = sum(entry[0].num_rows for k, entry in _kept.items() if k[0] == database)
    if _spool is not None:
        held += sum(_spooled_rows(path) for path in _spooled(_spool, database))
    return held


def take(session: Session, engine_ids: Iterable[int]) -> pa.Table | None:
    """Every kept row of these engines, sorted by engine and time, removed from the store
    (the spool's files stay: the host's other processes read them too); None when there is
    none."""
    engine_ids = set(engine_ids)
    parts = _remove(session, engine_ids)
    if _spool is not None:
        parts += _read_spooled(_spool, _database(session), engine_ids)
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


def discard(session: Session, engine_ids: Iterable[int], *, moved: bool = False) -> None:
    """Drop what is kept of these engines (the job found nothing to do with it: no active
    design, or already estimated; or their stored rows ``moved`` to other engines), so it does
    not sit in memory until evicted. In the spool an upload's file goes once none of its
    engines is left, or at once when rows of one of them moved (the file no longer holds
    what is stored)."""
    engine_ids = set(engine_ids)
    _remove(session, engine_ids)
    if _spool is None:
        return
    for path, _table, inside in _spooled_of(_spool, _database(session), engine_ids):
        if (pc.any if moved else pc.all)(inside).as_py():
            path.unlink(missing_ok=True)


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


def _database_key(database: str) -> str:
    return hashlib.sha256(database.encode()).hexdigest()[:16]


def _spool_path(spool: Path, key: tuple[str, int], rows: int) -> Path:
    """An upload's file: its database, upload id and row count in the name."""
    return spool / f"{_database_key(key[0])}-{key[1]}-{rows}.arrow"


def _spooled(spool: Path, database: str) -> list[Path]:
    """The committed uploads' files of ``database``, oldest upload first."""
    paths = spool.glob(f"{_database_key(database)}-*.arrow")
    return sorted(paths, key=lambda p: int(p.stem.split("-")[1]))


def _spooled_rows(path: Path) -> int:
    return int(path.stem.split("-")[2])


def _write_spooled(path: Path, rows: pa.Table) -> bool:
    try:
        with ipc.new_file(str(path), rows.schema) as writer:
            writer.write_table(rows)
        return True
    except OSError as exc:  # a full disk: the job reads the database
        log.warning("upload rows not spooled for the estimation job: %s", exc)
        path.unlink(missing_ok=True)
        return False


def _bound_spool(spool: Path, database: str) -> None:
    """Delete the oldest uploads' files beyond ``SPOOL_RECORDS`` rows."""
    paths = _spooled(spool, database)
    total = sum(_spooled_rows(p) for p in paths)
    for path in paths:
        if total <= SPOOL_RECORDS:
            break
        path.unlink(missing_ok=True)
        total -= _spooled_rows(path)


def _open_spooled(path: Path) -> pa.Table | None:
    """A spooled upload's rows (memory-mapped), None when the file is gone."""
    try:
        return ipc.open_file(pa.memory_map(str(path))).read_all()
    except (OSError, pa.ArrowInvalid):
        return None


def _spooled_of(spool: Path, database: str, engine_ids: set[int],
                ) -> Iterator[tuple[Path, pa.Table, pa.BooleanArray]]:
    """Each spooled upload of ``database`` still there, oldest first: its file, its rows and
    which of them are of these engines."""
    wanted = pa.array(sorted(engine_ids), pa.int64())
    for path in _spooled(spool, database):
        table = _open_spooled(path)
        if table is not None:
            yield path, table, pc.is_in(pc.cast(table["engine_id"], pa.int64()),
                                        value_set=wanted)


def _read_spooled(spool: Path, database: str, engine_ids: set[int]) -> list[pa.Table]:
    """The spooled rows of these engines, upload by upload (the files stay)."""
    return [table.filter(inside) for _path, table, inside in _spooled_of(spool, database,
                                                                          engine_ids)
            if pc.any(inside).as_py()]
