"""Shared helpers of the benchmark scripts: import path, timing, the test model."""

from __future__ import annotations

import os
import sys
import tempfile
import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


def best_time(fn: Callable[[], object], repeat: int = 3) -> float:
    """Best wall time of ``repeat`` calls, seconds (the least disturbed run)."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def reference_design(extra_sensors: int = 0, m: int = 6):
    """The seed-002-like reference model of the tests and an SVD-tuner filter on it."""
    from estimation import tuners
    from tests.estimation.models import reference_model, reference_noise

    model = reference_model(extra_sensors=extra_sensors)
    noise = reference_noise(model)
    return model, noise, tuners.svd_tuners(model, m, noise["Q"], noise["Qh"], noise["Ph"])


POSTGRES_ADMIN_URL = os.environ.get(
    "FLEETHEALTH_TEST_POSTGRES_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/test"
)


@contextmanager
def throwaway_database(backend: str, prefix: str = "fh_bench") -> Iterator[tuple[str, str]]:
    """(url, label) of an empty database of its own for one bench run, removed after: a SQLite
    file in a temporary folder, or a database made on the machine's PostgreSQL server (named
    ``prefix`` and a random suffix)."""
    from sqlalchemy import create_engine, text
    from sqlalchemy.engine import make_url

    if backend == "sqlite":
        with tempfile.TemporaryDirectory(prefix="fh-bench-") as tmp:
            yield f"sqlite:///{tmp}/fleethealth.db", "SQLite (embedded default)"
        return
    name = f"{prefix}_{uuid.uuid4().hex[:10]}"
    admin = create_engine(POSTGRES_ADMIN_URL, isolation_level="AUTOCOMMIT")
    with admin.connect() as connection:
        connection.execute(text(f'CREATE DATABASE "{name}"'))
    try:
        yield make_url(POSTGRES_ADMIN_URL).set(database=name).render_as_string(
            hide_password=False), "PostgreSQL"
    finally:
        with admin.connect() as connection:
            connection.execute(text(f'DROP DATABASE "{name}" WITH (FORCE)'))
        admin.dispose()


def load_line() -> str:
    """The load average and the thread settings, for the first line of a bench's output."""
    a, b, c = os.getloadavg()
    return (f"load average {a:.2f} {b:.2f} {c:.2f}; {os.cpu_count()} cores; OMP/BLAS threads "
            f"{os.environ.get('OMP_NUM_THREADS', 'unset')}")


def run_on_backends(backends: str, run: Callable[[str, str], bool]) -> None:
    """``run(url, label)`` on a throw-away database of each of the comma-separated
    ``backends``, between the load line and the load at the end; PASS if every run passed."""
    print(load_line())
    ok = True
    for backend in backends.split(","):
        with throwaway_database(backend) as (url, label):
            ok &= run(url, label)
    print(f"load average at the end {os.getloadavg()[0]:.2f}")
    print("PASS" if ok else "FAIL")
