"""A server killed (SIGKILL) in the middle of an estimation job: the restarted server takes the
job over at once and finishes it within 30 s, on SQLite and on PostgreSQL.

Real processes: ``fleethealth serve`` (its in-process job runner) on a fresh database, an
upload over HTTP that queues the estimation of its snapshots, SIGKILL while the job runs,
then a new ``fleethealth serve`` on the same database. The job is not requeued by the
heartbeat timeout (left at its default, far above the 30 s budget): the starting process sees
that the job's claimant process is gone and takes the job over.
"""

from __future__ import annotations

import signal
import time
from pathlib import Path

import httpx
import pytest
from sqlalchemy import select, text

from app.db import transaction
from app.models import Job
from tests.conftest import BACKENDS
from tests.support.fleet_fixture import (
    add_reference_design,
    csv_bytes,
    make_fleet,
    reference_rows,
)
from tests.support.jobs import live_database
from tests.support.server import serving

pytestmark = pytest.mark.long(seconds=35)

ROOT = Path(__file__).resolve().parents[3]
FINISH_WITHIN_S = 30.0
ROWS = 20_000


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_job_killed_mid_run_is_finished_within_30_s_of_the_restart(
    backend: str, tmp_path: Path
) -> None:
    with live_database(backend, tmp_path) as (url, factory):
        with transaction(factory) as session:
            fleet = make_fleet(session)
        add_reference_design(url, fleet.operator_id)

        def estimation_job() -> Job | None:
            with transaction(factory, write=False) as session:
                return session.scalar(select(Job).where(
                    Job.operator_id == fleet.operator_id, Job.kind == "estimate_engines"
                ).order_by(Job.id.desc()).limit(1))

        with serving(url, tmp_path) as (server, base):
            response = httpx.post(
                f"{base}/api/v1/snapshots/file", content=csv_bytes(reference_rows(ROWS)),
                headers={**fleet.analyst, "Content-Type": "text/csv"}, timeout=120,
            )
            assert response.status_code == 201, response.text
            deadline = time.monotonic() + 60
            while (job := estimation_job()) is None or job.status != "running":
                assert job is None or job.status == "queued", (job.status, job.error)
                assert time.monotonic() < deadline, "the job never ran"
                time.sleep(0.02)
            started = time.monotonic()
            time.sleep(0.5)  # into the job's work
            job = estimation_job()
            assert job is not None and job.status == "running", "the job ended before the kill"
            ran = time.monotonic() - started
            server.send_signal(signal.SIGKILL)
            server.wait(timeout=10)

        job_id, killed_by = job.id, job.worker
        restarted = time.monotonic()
        taken_over = None
        with serving(url, tmp_path):
            answering = time.monotonic() - restarted
            while True:
                job = estimation_job()
                assert job is not None and job.id == job_id
                if taken_over is None and job.status == "running" and job.worker != killed_by:
                    taken_over = time.monotonic() - restarted
                if job.status in ("succeeded", "failed", "cancelled"):
                    break
                assert time.monotonic() - restarted < 120, f"job still {job.status}"
                time.sleep(0.05)
            took = time.monotonic() - restarted
        assert job.status == "succeeded", job.error
        print(f"killed after {ran:.1f} s of work; after the restart: answering at "
              f"{answering:.1f} s, job taken over at {taken_over} s, finished at {took:.1f} s")
        assert took <= FINISH_WITHIN_S, f"finished {took:.1f} s after the restart"
        with factory.kw["bind"].connect() as connection:
            stored = connection.execute(text(
                "SELECT count(*) FROM estimates e JOIN engines g ON g.id = e.engine_id "
                "WHERE g.operator_id = :o"
            ), {"o": fleet.operator_id}).scalar_one()
        assert stored > 0
