"""A server killed (SIGKILL) in the middle of an estimation job: the restarted server takes the
job over at once and finishes it within 30 s, on SQLite and on PostgreSQL.

Real processes: ``fleethealth serve`` (its in-process job runner) on a fresh database, an
upload over HTTP that queues the estimation of its snapshots, SIGKILL while the job runs,
then a new ``fleethealth serve`` on the same database. The job is not requeued by the
heartbeat timeout (left at its default, far above the 30 s budget): the starting process sees
that the job's claimant process is gone and takes the job over.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx
import pyarrow as pa
import pytest
from sqlalchemy import select, text

from app.db import make_engine, make_sessionmaker, transaction
from app.migrate import upgrade
from app.models import EngineModel, EstimatorDesign, Job
from estimation.tuners import svd_vstar
from tests.conftest import BACKENDS, fresh_database_url
from tests.estimation.models import reference_model
from tests.support.fleet_fixture import csv_bytes, make_fleet, snapshot_rows

ROOT = Path(__file__).resolve().parents[3]
FINISH_WITHIN_S = 30.0
ROWS = 20_000


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@contextmanager
def _server(url: str, data_dir: Path) -> Iterator[tuple[subprocess.Popen[bytes], str]]:
    port = _free_port()
    env = {**os.environ, "FLEETHEALTH_DATABASE_URL": url, "FLEETHEALTH_DATA_DIR": str(data_dir),
           "FLEETHEALTH_LOG_LEVEL": "WARNING", "OMP_NUM_THREADS": "1"}
    command = [sys.executable, "-c", "from app.cli import main; main()", "serve", "--no-demo",
               "--skip-migrate", "--host", "127.0.0.1", "--port", str(port)]
    server = subprocess.Popen(command, env=env, cwd=ROOT, stdout=subprocess.DEVNULL)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                if httpx.get(f"{base}/health", timeout=1).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            assert server.poll() is None, "fleethealth serve exited"
            assert time.monotonic() < deadline, "fleethealth serve did not start"
            time.sleep(0.05)
        yield server, base
    finally:
        if server.poll() is None:
            server.terminate()
            server.wait(timeout=30)


def _add_design(session_factory: object, operator_id: int) -> None:
    """The reference linear model and an active six-tuner design on the fleet's engine type."""
    model = reference_model()
    with transaction(session_factory) as session:  # type: ignore[arg-type]
        kind = session.scalar(
            text("SELECT id FROM engine_types WHERE operator_id = :o").bindparams(o=operator_id)
        )
        row = EngineModel(
            operator_id=operator_id, engine_type_id=kind, name="reference", version=1,
            source="imported", format="fleethealth.linear-model/1", content=model.to_dict(),
            checksum="0" * 64, dt=model.dt, n_states=model.n_states,
            sensor_names=list(model.sensor_names), health_names=list(model.health_names),
            aux_names=list(model.aux_names),
        )
        session.add(row)
        session.flush()
        session.add(EstimatorDesign(
            operator_id=operator_id, engine_type_id=kind, engine_model_id=row.id, name="d",
            spec={}, status="ready", active=True, result={"vstar": svd_vstar(model, 6).tolist()},
        ))


def _rows() -> pa.Table:
    """The fixture's snapshots in the reference model's parameters (its type takes no other)."""
    rows = snapshot_rows(ROWS)
    return rows.select([c for c in rows.column_names if c not in ("P30", "T50")])


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_job_killed_mid_run_is_finished_within_30_s_of_the_restart(
    backend: str, tmp_path: Path
) -> None:
    urls = fresh_database_url(backend, tmp_path)
    url = next(urls)
    try:
        upgrade(url)
        engine = make_engine(url)
        factory = make_sessionmaker(engine)
        with transaction(factory) as session:
            fleet = make_fleet(session)
        _add_design(factory, fleet.operator_id)

        def estimation_job() -> Job | None:
            with transaction(factory, write=False) as session:
                return session.scalar(select(Job).where(
                    Job.operator_id == fleet.operator_id, Job.kind == "estimate_engines"
                ).order_by(Job.id.desc()).limit(1))

        with _server(url, tmp_path) as (server, base):
            response = httpx.post(
                f"{base}/api/v1/snapshots/file", content=csv_bytes(_rows()),
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
        with _server(url, tmp_path):
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
        with engine.connect() as connection:
            stored = connection.execute(text(
                "SELECT count(*) FROM estimates WHERE operator_id = :o"
            ), {"o": fleet.operator_id}).scalar_one()
        assert stored > 0
        engine.dispose()
    finally:
        urls.close()
