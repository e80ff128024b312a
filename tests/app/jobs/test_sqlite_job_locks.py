"""On the embedded SQLite default, an estimation job holds the file's one write lock only
while it writes: its reads and its computation leave writers free (an upload is not kept
waiting for a filter run), and its writes queue with theirs in the write gate."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest
from sqlalchemy import func, select

from app.db import make_engine, make_sessionmaker, transaction
from app.jobs.kinds import load_kinds
from app.jobs.runner import Runner
from app.migrate import upgrade
from app.models import Snapshot
from app.models.estimates import Estimate
from app.services.jobs.store import queue_estimation
from app.services.snapshots import store
from app.services.uploads.store import ingest_snapshots
from tests.support.fleet_fixture import add_reference_design, csv_bytes, make_fleet, reference_rows
from tests.support.jobs import job_row, wait_until


def test_an_estimation_job_computes_without_the_write_lock(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "jobs.sqlite3"
    url = f"sqlite:///{path}"
    upgrade(url)
    engine = make_engine(url)
    factory = make_sessionmaker(engine)
    with transaction(factory) as session:
        fleet = make_fleet(session)
        ingest_snapshots(session, operator_id=fleet.operator_id, api_key_id=None,
                         body=csv_bytes(reference_rows(400)), content_format="csv")
    add_reference_design(url, fleet.operator_id)

    # While the filters run, another writer must get in. It waits up to 2 s: the runner's
    # other threads may hold the write lock for milliseconds (with no wait at all the writer
    # once met such a turn under load), while a lock held by the job itself would never be
    # released, since the job's thread is the one waiting here.
    writes_during_compute: list[str] = []
    real_run_filters = store.run_filters

    def run_filters_beside_a_writer(*args, **kwargs):  # type: ignore[no-untyped-def]
        other = sqlite3.connect(path, timeout=2.0)
        try:
            other.execute("INSERT INTO operators (name, created_at) VALUES ('Beside Air', "
                          "CURRENT_TIMESTAMP)")
            other.commit()
            writes_during_compute.append("written")
        except sqlite3.OperationalError as exc:
            writes_during_compute.append(str(exc))
        finally:
            other.close()
        return real_run_filters(*args, **kwargs)

    monkeypatch.setattr(store, "run_filters", run_filters_beside_a_writer)
    kinds = load_kinds()
    with transaction(factory) as session:
        job_id = queue_estimation(session, operator_id=fleet.operator_id, job_registry=kinds).id
    runner = Runner(factory, kinds, workers=1, poll_seconds=0.05)
    runner.start()
    try:
        runner.dispatch(job_id)
        wait_until(lambda: job_row(factory, job_id).status in ("succeeded", "failed"),
                   "the estimation job")
    finally:
        runner.stop()
    row = job_row(factory, job_id)
    assert (row.status, row.error) == ("succeeded", None)
    assert writes_during_compute and set(writes_during_compute) == {"written"}
    with transaction(factory, write=False) as session:
        n_snapshots = session.scalar(select(func.count()).select_from(Snapshot))
        n_estimates = session.scalar(select(func.count()).select_from(Estimate))
    assert n_snapshots and n_estimates == n_snapshots  # and the job's writes went through
    engine.dispose()
