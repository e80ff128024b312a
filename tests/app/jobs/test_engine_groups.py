"""An estimation job spread over engine groups on PostgreSQL (``app.services.snapshots.groups``):
the groups run in real pool processes and the result equals the job estimating alone, row for
row; a worker killed while it holds its engines loses nothing (the job waits on the engines'
locks and estimates what the worker left). On SQLite the job estimates alone.

Real parts: a really-committing database, uploads through the app, the embedded default's
process pool (``app.jobs.engine_groups``), a Celery worker with two processes on Redis, SIGKILL.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import subprocess
import sys
import threading
import uuid
from collections.abc import Iterator, Sequence
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import select, text
from sqlalchemy.orm import Session, sessionmaker

from app.config import Settings
from app.db import make_engine, transaction
from app.jobs.engine_groups import PoolLauncher
from app.jobs.runner import run_pending
from app.main import create_app
from app.models import Engine, Job
from app.models.estimates import (
    DeteriorationBucket,
    Estimate,
    Event,
    FilterCheckpoint,
    FilterState,
    FleetPeriod,
)
from app.services.snapshots import backlog, groups, store
from app.services.snapshots.drifts import FleetDrifts
from tests.support.fleet_fixture import add_reference_design, csv_bytes, make_fleet, reference_rows
from tests.support.jobs import live_database, wait_until
from tests.support.paths import ROOT

pytestmark = pytest.mark.long(seconds=40)

ROWS = 6000


def test_split_balances_groups_by_new_records_and_keeps_each_engine_in_one() -> None:
    marks = {e: backlog.Mark(None, rows, ()) for e, rows in
             {1: 900, 2: 100, 3: 500, 4: 400, 5: None, 6: 100}.items()}
    parts = groups.split(marks, 3)
    assert sorted(e for p in parts for e in p) == [1, 2, 3, 4, 5, 6]
    mean = 2000 / 5  # engine 5's count is unknown: the mean of the known
    loads = sorted(sum(marks[e].rows or mean for e in p) for p in parts)
    assert loads == [700, 800, 900]  # largest first, each into the lightest group
    assert sorted(groups.split(marks, 10)) == [[1], [2], [3], [4], [5], [6]]
    assert groups.split({7: backlog.Mark(None, 3, ())}, 4) == [[7]]


Stored = tuple[dict[str, list[tuple]], list[tuple], list[tuple], list[tuple]]


def _stored(factory: sessionmaker[Session], operator_id: int) -> Stored:
    """Per ESN every estimate (seq, time, blob), checkpoint and filter state, the events,
    the engines' buckets and the fleet's periods: what must not depend on who estimated
    (the fleet's period sums are added in the order the groups commit: equal to rounding,
    ``_same``)."""
    with transaction(factory, write=False) as session:
        esn = dict(session.execute(
            select(Engine.id, Engine.esn).where(Engine.operator_id == operator_id)).all())
        per_engine: dict[str, list[tuple]] = {}
        for engine_id, name in esn.items():
            rows: list[tuple] = [
                (seq, t, bytes(blob)) for seq, t, blob in session.execute(
                    select(Estimate.seq, Estimate.recorded_at, Estimate.packed)
                    .where(Estimate.engine_id == engine_id).order_by(Estimate.seq))]
            rows += [(c.seq, c.last_recorded_at, c.state) for c in session.scalars(
                select(FilterCheckpoint).where(FilterCheckpoint.engine_id == engine_id)
                .order_by(FilterCheckpoint.seq))]
            rows += [(f.n_records, f.last_recorded_at, f.state) for f in session.scalars(
                select(FilterState).where(FilterState.engine_id == engine_id))]
            per_engine[name] = rows
        events = sorted((esn[e.engine_id], e.seq, e.detected_at, e.kind, e.fault, e.magnitude,
                         e.statistic) for e in session.scalars(
            select(Event).where(Event.operator_id == operator_id)))
        buckets = sorted((esn[b.engine_id], b.period, b.start, b.n, bytes(b.sums))
                         for b in session.scalars(select(DeteriorationBucket).where(
                             DeteriorationBucket.operator_id == operator_id)))
        periods = sorted((p.period, p.start, p.n_engines,
                          tuple(np.concatenate([np.frombuffer(p.sums, "<f8"),
                                                np.frombuffer(p.squares, "<f8")])))
                         for p in session.scalars(select(FleetPeriod).where(
                             FleetPeriod.operator_id == operator_id)))
    return per_engine, events, buckets, periods


def _same(got: Stored, expected: Stored) -> None:
    """Equal estimates, checkpoints, states, events and buckets; the fleet's periods of
    equal engine counts and sums equal to rounding."""
    assert got[:3] == expected[:3]
    assert [p[:3] for p in got[3]] == [p[:3] for p in expected[3]]
    np.testing.assert_allclose([p[3] for p in got[3]], [p[3] for p in expected[3]],
                               rtol=1e-12, atol=1e-9)


def _upload(url: str, tmp_path: Path, key: dict[str, str], rows: bytes) -> None:
    app = create_app(Settings(database_url=url, data_dir=tmp_path), make_engine(url))
    with TestClient(app) as client:
        response = client.post("/api/v1/snapshots/file", content=rows,
                               headers={**key, "Content-Type": "text/csv"})
        assert response.status_code == 201, response.text


def _estimation(factory: sessionmaker[Session], operator_id: int) -> Job:
    with transaction(factory, write=False) as session:
        job = session.scalar(select(Job).where(
            Job.operator_id == operator_id, Job.kind == "estimate_engines"
        ).order_by(Job.id.desc()).limit(1))
        assert job is not None
        return job


@pytest.fixture
def two_fleets(tmp_path: Path) -> Iterator[tuple[str, sessionmaker[Session], int, int]]:
    """A live PostgreSQL database with two operators of the same fleet and design, each sent
    the same upload; (url, factory, the first operator, the second)."""
    with live_database("postgresql", tmp_path) as (url, factory):
        ids = []
        body = csv_bytes(reference_rows(ROWS))
        for _ in range(2):
            with transaction(factory) as session:
                fleet = make_fleet(session)
            add_reference_design(url, fleet.operator_id)
            _upload(url, tmp_path, fleet.analyst, body)
            ids.append(fleet.operator_id)
        yield url, factory, ids[0], ids[1]


def _run_alone(factory: sessionmaker[Session]) -> None:
    groups.configure(None)
    run_pending(factory)


def _first_alone(factory: sessionmaker[Session], later: int) -> None:
    """Run every queued job alone but those of operator ``later``, which stay queued."""
    with transaction(factory) as session:
        session.execute(Job.__table__.update().where(Job.operator_id == later)
                        .values(status="cancelled"))
    _run_alone(factory)
    with transaction(factory) as session:
        session.execute(Job.__table__.update().where(Job.operator_id == later)
                        .values(status="queued"))


def test_engine_groups_in_pool_processes_equal_the_job_alone(
    two_fleets: tuple[str, sessionmaker[Session], int, int], tmp_path: Path
) -> None:
    url, factory, alone, spread = two_fleets
    pool = PoolLauncher(Settings(database_url=url, data_dir=tmp_path, estimation_workers=2))
    try:
        pool.start(wait=True)
        # The first operator's job alone; the second's spread over the job and a pool process.
        _first_alone(factory, spread)
        groups.configure(pool)
        run_pending(factory)
    finally:
        groups.configure(None)
        pool.stop()
    job = _estimation(factory, spread)
    assert job.status == "succeeded", job.error
    assert job.result is not None and job.result["groups"] == 2
    # Some engines were estimated by the pool, not by the job's own process.
    assert job.result["records"] < ROWS
    assert _estimation(factory, alone).result["records"] == ROWS  # type: ignore[index]
    expected, got = _stored(factory, alone), _stored(factory, spread)
    assert sum(len(v) for v in got[0].values()) > ROWS
    _same(got, expected)
    with transaction(factory, write=False) as session:
        assert backlog.pending(session, spread) == {}


def test_batches_cut_at_engines_or_new_records_and_keep_the_order(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    engines = [Engine(id=i) for i in range(1, 10)]
    rows = {1: 300, 2: 300, 3: 900, 4: None, 5: 200, 6: 100, 8: 5000, 9: 1}  # 4, 7: unknown
    monkeypatch.setattr(store, "BATCH_RECORDS", 1000)

    def ids(cut: list[list[Engine]]) -> list[list[int]]:
        return [[e.id for e in b] for b in cut]

    # An engine over the cap is a batch of its own; an unknown count adds nothing.
    assert ids(store.batches(engines, rows)) == [[1, 2], [3, 4], [5, 6, 7], [8], [9]]
    monkeypatch.setattr(store, "BATCH", 2)
    assert ids(store.batches(engines, rows)) == [[1, 2], [3, 4], [5, 6], [7, 8], [9]]
    assert store.batches([], rows) == []
    # Seven of 300 under a cap of 2,000: two batches of about 1,050, not 1,800 and 300.
    monkeypatch.setattr(store, "BATCH", 256)
    monkeypatch.setattr(store, "BATCH_RECORDS", 2000)
    even = {i: 300 for i in range(1, 8)}
    assert ids(store.batches(engines[:7], even)) == [[1, 2, 3, 4], [5, 6, 7]]
    monkeypatch.setattr(store, "BATCH", 2)
    assert ids(store.batches(engines[:3], {})) == [[1, 2], [3]]  # counts unknown: BATCH


def test_a_backlog_cut_into_batches_by_records_equals_one_batch(
    two_fleets: tuple[str, sessionmaker[Session], int, int], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The job alone over the same upload in one batch and in several (``BATCH_RECORDS``
    lowered): the same stored numbers."""
    _url, factory, whole, cut = two_fleets
    _first_alone(factory, cut)
    sizes: list[int] = []
    real = store.batches

    def counted(engines: Sequence[Engine], counts: dict[int, int | None]) -> list[list[Engine]]:
        out = real(engines, counts)
        sizes.extend(sum(counts.get(e.id) or 0 for e in b) for b in out)
        return out

    monkeypatch.setattr(store, "BATCH_RECORDS", ROWS // 4)
    monkeypatch.setattr(store, "batches", counted)
    _run_alone(factory)
    assert _estimation(factory, cut).status == "succeeded"
    assert len(sizes) >= 4 and sum(sizes) == ROWS
    _same(_stored(factory, cut), _stored(factory, whole))


def test_a_group_done_elsewhere_leaves_what_was_marked_since_to_the_next_pass(
    two_fleets: tuple[str, sessionmaker[Session], int, int],
) -> None:
    """The job's pass over its backlog estimates only what is left of that backlog: an engine
    another process estimated in the pass keeps what was marked on it since (an upload stored
    meanwhile) for the next pass, whose groups spread it, while a group no one did is done."""
    _url, factory, operator_id, _other = two_fleets
    with transaction(factory, write=False) as session:
        work = backlog.pending(session, operator_id)
    done, left = groups.split(work, 2)
    with factory() as session:  # another process estimates the first group ...
        assert store.run_group(session, operator_id, done)["engines"] == len(done)
    with transaction(factory) as session:  # ... and an upload marks its engines again
        backlog.mark(session, operator_id, {e: (None, None) for e in done})
    with factory() as session:
        skipped = store.estimate_group(session, operator_id, done, wait=True,
                                       commit=session.commit, leftover_of=work)
        assert skipped["engines"] == 0
        taken = store.estimate_group(session, operator_id, left, wait=True,
                                     commit=session.commit, leftover_of=work)
        assert taken["engines"] == len(left) and taken["records"] > 0
        assert sorted(backlog.pending(session, operator_id)) == sorted(done)
        # The next pass (here the job alone) takes the new marks.
        store.catch_up(session, operator_id, commit=session.commit)
        session.commit()
        assert backlog.pending(session, operator_id) == {}


class StuckWorker:
    """A launcher whose worker takes its groups' engines and dies holding them (SIGKILL by the
    test): the job must wait for them and estimate them itself."""

    workers = 2

    def __init__(self, url: str) -> None:
        self.url = url
        self.process: multiprocessing.process.BaseProcess | None = None
        self.holding = multiprocessing.get_context("spawn").Event()

    def launch(self, operator_id: int, parts: Sequence[Sequence[int]],
               drifts: FleetDrifts) -> None:
        context = multiprocessing.get_context("spawn")
        engines = sorted(e for p in parts for e in p)
        self.process = context.Process(target=_hold_engines, args=(self.url, engines,
                                                                   self.holding))
        self.process.start()
        assert self.holding.wait(60), "the worker never took its engines"


def _hold_engines(url: str, engine_ids: list[int], holding: Any) -> None:
    """A worker in the middle of its group: the engines' locks taken, its work not committed."""
    with groups.engine_locks(make_engine(url), engine_ids, wait=False) as held:
        assert held == engine_ids
        holding.set()
        threading.Event().wait(600)


def test_a_worker_killed_holding_its_engines_loses_nothing(
    two_fleets: tuple[str, sessionmaker[Session], int, int], tmp_path: Path
) -> None:
    url, factory, alone, spread = two_fleets
    _first_alone(factory, spread)
    stuck = StuckWorker(url)
    groups.configure(stuck)
    job_thread = threading.Thread(target=run_pending, args=(factory,))
    try:
        job_thread.start()
        started = datetime.now()
        while stuck.process is None or not stuck.holding.is_set():
            assert (datetime.now() - started).total_seconds() < 60
            threading.Event().wait(0.05)
        threading.Event().wait(1.0)  # the job's own group done, it waits on the worker's
        assert job_thread.is_alive(), "the job did not wait for the worker's engines"
        assert stuck.process.pid is not None
        os.kill(stuck.process.pid, signal.SIGKILL)
        stuck.process.join(10)
        job_thread.join(120)
        assert not job_thread.is_alive()
    finally:
        groups.configure(None)
        if stuck.process is not None and stuck.process.is_alive():
            stuck.process.kill()
    job = _estimation(factory, spread)
    assert job.status == "succeeded", job.error
    assert job.result is not None and job.result["records"] == ROWS  # all by the job itself
    _same(_stored(factory, spread), _stored(factory, alone))


def test_on_sqlite_the_job_estimates_alone(tmp_path: Path) -> None:
    with live_database("sqlite", tmp_path) as (url, factory):
        with transaction(factory) as session:
            assert groups.launcher_for(session) is None
            groups.configure(StuckWorker(url))
            try:
                assert groups.launcher_for(session) is None
            finally:
                groups.configure(None)


def test_under_celery_the_groups_go_to_the_worker_processes_as_tasks(
    two_fleets: tuple[str, sessionmaker[Session], int, int], tmp_path: Path
) -> None:
    """``fleethealth worker --concurrency 2``: the job runs in one worker process and sends its
    groups as ``estimate_group`` tasks, which the other process takes."""
    import redis

    from app.jobs.celery_app import CeleryDispatch
    from app.jobs.celery_tasks import celery
    from tests.app.jobs.test_celery_jobs import redis_unavailable_reason

    broker = str(celery.conf.broker_url)
    if (reason := redis_unavailable_reason(broker)) is not None:
        if os.environ.get("CI"):
            pytest.fail(f"CI must run the Celery tests, but {reason}")
        pytest.skip(reason)
    url, factory, alone, spread = two_fleets
    _first_alone(factory, spread)
    job_id = _estimation(factory, spread).id
    queue = f"fleethealth-test-{uuid.uuid4().hex[:12]}"
    env = {**os.environ, "FLEETHEALTH_DATABASE_URL": url, "FLEETHEALTH_REDIS_URL": broker,
           "FLEETHEALTH_DATA_DIR": str(tmp_path / "worker-data"), "FLEETHEALTH_LOG_JSON": "false",
           "FLEETHEALTH_ESTIMATION_WORKERS": "2", "OMP_NUM_THREADS": "1"}
    log_path = tmp_path / "worker.log"
    with log_path.open("w") as log:
        worker = subprocess.Popen(
            [sys.executable, "-c", "from app.cli import main; main()", "worker",
             "--concurrency", "2", "--queue", queue],
            cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT)
    try:
        CeleryDispatch(queue, celery).dispatch(job_id)
        wait_until(lambda: _estimation(factory, spread).status not in ("queued", "running"),
                   "the estimation job ended", timeout=300)
    finally:
        worker.terminate()
        try:
            worker.wait(timeout=30)
        except subprocess.TimeoutExpired:
            worker.kill()
            worker.wait(timeout=10)
        redis.Redis.from_url(broker).delete(queue, f"_kombu.binding.{queue}")
        print(log_path.read_text()[-4000:])
    job = _estimation(factory, spread)
    assert job.status == "succeeded", job.error
    assert job.result is not None and job.result["groups"] == 2
    assert job.result["records"] < ROWS  # the other worker process estimated some engines
    _same(_stored(factory, spread), _stored(factory, alone))
    with transaction(factory, write=False) as session:
        assert backlog.pending(session, spread) == {}


def test_engine_locks_take_those_free_or_wait_and_leave_none_held(tmp_path: Path) -> None:
    """The locks of a group: those free now (another process holds the rest), or all of them
    once their holder lets go (waiting), each engine's lock held once and none left after."""
    with live_database("postgresql", tmp_path) as (url, _factory):
        bind = make_engine(url)
        other = make_engine(url)
        try:
            def held_now() -> list[int]:
                with bind.connect() as connection:
                    return sorted(int(e) for e in connection.execute(text(
                        "SELECT objid FROM pg_locks WHERE locktype = 'advisory' "
                        "AND classid = :key AND database = (SELECT oid FROM pg_database "
                        "WHERE datname = current_database())"),
                        {"key": groups.ENGINE_LOCK}).scalars())

            with groups.engine_locks(other, [7, 3, 5], wait=False) as first:
                assert first == [3, 5, 7] and held_now() == [3, 5, 7]
                with groups.engine_locks(bind, [9, 5, 2, 3], wait=False) as rest:
                    assert rest == [2, 9]
                    assert held_now() == [2, 3, 5, 7, 9]
                assert held_now() == [3, 5, 7]
            assert held_now() == []

            holding, releasing = threading.Event(), threading.Event()

            def hold() -> None:
                with groups.engine_locks(other, [5, 7], wait=False) as mine:
                    assert mine == [5, 7]
                    holding.set()
                    threading.Event().wait(0.3)
                    releasing.set()

            holder = threading.Thread(target=hold)
            holder.start()
            assert holding.wait(30)
            with groups.engine_locks(bind, [7, 3, 5], wait=True) as all_of_them:
                assert releasing.is_set()  # not before the holder let go
                assert all_of_them == [3, 5, 7] and held_now() == [3, 5, 7]
            holder.join(30)
            assert held_now() == []
            with groups.engine_locks(bind, [], wait=True) as none:
                assert none == []
        finally:
            bind.dispose()
            other.dispose()
