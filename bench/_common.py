"""Shared helpers of the benchmark scripts: import path, BLAS threads, timing, the test model,
throw-away databases, ``fleethealth serve`` on a socket, simulated stream flights, the demo's
design.

Importing this module pins BLAS and OpenMP to one thread (``THREAD_VARIABLES``, for this
process and the servers and workers it starts): a bench imports it before numpy (``import
_common`` sorts first), and ``load_line`` states the setting and says so if numpy came first.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from sqlalchemy.orm import Session

    from app.models import EstimatorDesign

THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
PINNED_LATE = "numpy" in sys.modules  # numpy's BLAS reads the variables when it loads
for _name in THREAD_VARIABLES:
    os.environ[_name] = "1"

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
def throwaway_database(
    backend: str, prefix: str = "fh_bench", keep: bool = False
) -> Iterator[tuple[str, str]]:
    """(url, label) of an empty database of its own for one bench run, removed after: a SQLite
    file in a temporary folder, or a database made on the machine's PostgreSQL server (named
    ``prefix`` and a random suffix; left in place with ``keep``, for a later run to measure)."""
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
        if not keep:
            with admin.connect() as connection:
                connection.execute(text(f'DROP DATABASE "{name}" WITH (FORCE)'))
        admin.dispose()


def load_line() -> str:
    """The load average and the thread settings, for the first line of a bench's output."""
    a, b, c = os.getloadavg()
    threads = ", ".join(f"{k}={os.environ.get(k, 'unset')}" for k in THREAD_VARIABLES)
    late = " (NOT in effect here: numpy was loaded before bench/_common.py)" if PINNED_LATE else ""
    return f"load average {a:.2f} {b:.2f} {c:.2f}; {os.cpu_count()} cores; {threads}{late}"


def cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of a process and its descendants that still run, and of
    the children they waited for."""
    return sum(cpu_by_process(pid).values())


def cpu_by_process(pid: int) -> dict[int, float]:
    """``process_cpu`` of a process and of each of its descendants, by process id."""
    return {p: process_cpu(p) for p in [pid, *children(pid)]}


def process_cpu(pid: int) -> float:
    """User + system CPU seconds of one process and the children it waited for (0 if it
    is gone)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return sum(int(f) for f in fields[11:15]) / os.sysconf("SC_CLK_TCK")


def postgres_backends(engine: Any) -> list[int]:
    """Process ids of the database's other PostgreSQL backends (a server on this machine)."""
    from sqlalchemy import text

    with engine.connect() as connection:
        return [int(p) for p in connection.execute(text(
            "SELECT pid FROM pg_stat_activity WHERE datname = current_database() "
            "AND pid <> pg_backend_pid()")).scalars()]


def children(pid: int) -> list[int]:
    """Every descendant process of ``pid`` (children of any of its threads)."""
    found: list[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            found += [int(c) for c in (task / "children").read_text().split()]
        except OSError:
            continue
    return found + [g for c in found for g in children(c)]


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


BENCH_DATA = Path("/tmp/fh-bench")  # the served data directories' parent and the pool cache


@contextmanager
def serving(url: str, port: int | None = None, data_dir: Path | None = None,
            schedule_cache: Path | None = None) -> Iterator[str]:
    """``fleethealth serve`` on the migrated database ``url`` in its own process (no demo, its
    job runner on), on ``port`` (a free one if None); yields its base URL and stops it after.
    ``data_dir``: the server's data directory (a temporary one under ``BENCH_DATA`` if None,
    removed after); ``schedule_cache``: a folder of the built-in engine's cached schedule and
    trim table, linked in as the data directory's ``cache`` so the server does not build them."""
    from tests.support import server

    BENCH_DATA.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="served-", dir=BENCH_DATA) as tmp:
        root = Path(tmp) if data_dir is None else data_dir
        if schedule_cache is not None and not (root / "cache").exists():
            root.mkdir(parents=True, exist_ok=True)
            (root / "cache").symlink_to(schedule_cache.resolve(), target_is_directory=True)
        with server.serving(url, root, port=port) as (_process, base):
            yield base


def simulated_streams(aircraft: int, seconds: float, seed: int, rate_hz: float = 20.0,
                      folder: Path | None = None) -> list[tuple[Path, dict[str, object]]]:
    """Whole-flight stream files of the built-in engine as ``fleethealth simulate --mode
    stream`` writes them (CSV, ``aircraft`` twin-engine aircraft, one flight each, the first
    ``seconds`` of the flight at ``rate_hz``): (path, manifest entry) per flight. The files are
    kept under ``BENCH_DATA`` (or ``folder``) and simulated again only when missing."""
    out = folder or BENCH_DATA / f"streams-{aircraft}x{seconds:g}s-{rate_hz:g}hz-{seed}"
    manifest = out / "streams" / "manifest.json"
    if not manifest.exists():
        t0 = time.perf_counter()
        subprocess.run(
            [sys.executable, "-c", "from app.cli import main; main()", "simulate", "--out",
             str(out), "--mode", "stream", "--aircraft", str(aircraft), "--flights", "1",
             "--seed", str(seed), "--rate-hz", f"{rate_hz:g}", "--stream-seconds",
             f"{seconds:g}", "--format", "csv"],
            cwd=ROOT, check=True, stdout=subprocess.DEVNULL,
            env={**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
                 "MKL_NUM_THREADS": "1"})
        print(f"simulated {2 * aircraft} stream flights into {out} "
              f"({time.perf_counter() - t0:.0f} s)")
    flights = json.loads(manifest.read_text())["flights"]
    return [(out / next(f for f in e["files"] if f.endswith(".csv")), e) for e in flights]


@contextmanager
def schedule_cache(cache: Path) -> Iterator[Path]:
    """This process's data directory (``FLEETHEALTH_DATA_DIR``, a temporary one, removed
    after) with the built-in engine's cached schedule and trim table ``cache`` linked in as its
    ``cache``, so ``estimator.builtin_schedule`` reads them instead of building them."""
    from app.config import get_settings

    BENCH_DATA.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="data-", dir=BENCH_DATA) as tmp:
        (Path(tmp) / "cache").symlink_to(cache.resolve(), target_is_directory=True)
        before = os.environ.get("FLEETHEALTH_DATA_DIR")
        os.environ["FLEETHEALTH_DATA_DIR"] = tmp
        get_settings.cache_clear()
        try:
            yield Path(tmp)
        finally:
            if before is None:
                os.environ.pop("FLEETHEALTH_DATA_DIR", None)
            else:
                os.environ["FLEETHEALTH_DATA_DIR"] = before
            get_settings.cache_clear()


def demo_design(session: Session, operator_id: int) -> tuple[int, EstimatorDesign]:
    """The demo's engine type for the built-in engine, its cruise model and the demo's active
    design (``demo.ACTIVE_DESIGN``, designed and activated by the product's design service, as
    the demo makes it) on the operator; returns (engine type id, design)."""
    from app.services.demo import fleet as demo
    from app.services.designs import engine_models
    from app.services.designs import service as designs
    from app.services.fleet import service as fleet
    from app.services.snapshots import estimator

    kind = fleet.create_engine_type(session, operator_id=operator_id, name=demo.ENGINE_TYPE)
    point = demo.DESIGN_POINT
    model = estimator.builtin_schedule().model_at(point["alt"], point["mach"], point["power"])
    row, _created = engine_models.register_builtin_model(
        session, operator_id=operator_id, engine_type_id=kind.id,
        name="built-in turbofan, cruise", model=model)
    method, tuners = demo.ACTIVE_DESIGN
    spec = demo.design_spec(method, tuners, [n for n in model.sensor_names if n != "Wf"])
    design = designs.create_design(session, operator_id=operator_id, engine_model_id=row.id,
                                   name=f"all health parameters (m = {tuners})", spec=spec)
    designs.run_design(session, design, designs.design_step)
    designs.activate_design(session, operator_id=operator_id, design_id=design.id)
    return kind.id, design
