"""Scale-out of one operator's estimation backlog over engine groups, on the product's path:
the finish time of a stored backlog with 1 and 2 workers, in the embedded default's process
pool and in Celery worker processes, on PostgreSQL.

The data are ``fleethealth simulate --mode snapshot``'s fleet (``bench_ingest_fleet.simulate``:
the demo's fleet, take-off and cruise records) on the demo's engine type and designs. Per run,
on a throw-away database: ``fleethealth serve`` (and for Celery, ``fleethealth worker`` with
``--concurrency`` 1 or 2 on Redis database ``--redis-db``, flushed: one of this run's own)
estimates two first uploads of ``--warm`` records in all (its job and worker processes make
what they keep between jobs), then the bench holds the job claims' advisory lock
(``app.jobs.claim.SERIAL_CLAIM_LOCK``) while the records go up as CSV over HTTP, so that they
are all stored and marked before any estimation starts. The clock runs from the lock's release
to the end of the last estimation job: the job spreads the backlog over engine groups
(``app.services.snapshots.groups``), estimates its own share and waits for the rest.

Workers: the pool runs with ``FLEETHEALTH_ESTIMATION_WORKERS`` 1 (the job alone) and 2 (the job
and one pool process); Celery with ``FLEETHEALTH_ESTIMATION_WORKERS=2`` and 1 or 2 worker
processes (with one, the job finds the groups it sent still queued and estimates them itself).

Target (issue 17): with 2 workers the backlog finishes >= 1.7x faster than with 1. A shared
machine caps what any second process can buy (Linux shares CPU time between sessions, not
processes, when the cores are busy): ``headroom`` measures that cap with a pure-Python control
before and after each mode's runs, to read the speed-up against.

Each run also prints the CPU seconds of the timed window by role (``CpuWatch``): the server's
process tree (the job, the pool), the Celery worker's tree, the database's PostgreSQL backends,
this bench's own process, the other processes by name (PostgreSQL's background writers among
them) and the whole machine: what two cores have to give for the backlog.

BLAS and OpenMP run one thread (bench/_common.py) in every process.

    .venv/bin/python bench/bench_scale_out.py --redis-db N [--rows 100000] [--modes pool,celery]
        [--port N]
    ... bench/bench_scale_out.py --redis-db N --large      # 2,000,000 records
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from _common import (
    ROOT,
    cpu_by_process,
    load_line,
    postgres_backends,
    process_cpu,
    throwaway_database,
)

sys.path.insert(0, str(ROOT / "bench"))

import httpx  # noqa: E402
import pyarrow as pa  # noqa: E402
from bench_ingest_fleet import (  # noqa: E402
    build_operator,
    csv_bodies,
    post_all,
    raw_binary_copy,
    simulate,
    threads_line,
    wait_for_jobs,
)
from sqlalchemy import create_engine, text  # noqa: E402

from app.jobs.claim import SERIAL_CLAIM_LOCK  # noqa: E402
from app.migrate import upgrade  # noqa: E402
from tests.support import server  # noqa: E402

TARGET_SPEEDUP = 1.7


@contextmanager
def celery_worker(env: dict[str, str], concurrency: int) -> Iterator[int]:
    """``fleethealth worker --concurrency N`` until the block ends (a warm shutdown); yields
    its process id."""
    command = [sys.executable, "-c", "from app.cli import main; main()", "worker",
               f"--concurrency={concurrency}"]
    worker = subprocess.Popen(command, env=env, cwd=ROOT, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)
    try:
        yield worker.pid
    finally:
        worker.terminate()
        try:
            worker.wait(timeout=60)
        except subprocess.TimeoutExpired:
            worker.kill()
            worker.wait()


def flush_redis(url: str) -> None:
    import redis

    redis.Redis.from_url(url).flushdb()


def one_run(args: argparse.Namespace, plan: object, warm: pa.Table, bodies: list[bytes],
            n: int, mode: str, workers: int) -> float:
    """Seconds from the claims' release to the end of the backlog's estimation."""
    redis_url = f"redis://127.0.0.1:6379/{args.redis_db}"
    env = {"FLEETHEALTH_ESTIMATION_WORKERS": str(workers if mode == "pool" else 2),
           "FLEETHEALTH_REDIS_URL": redis_url, "OPENBLAS_NUM_THREADS": "1",
           "MKL_NUM_THREADS": "1"}
    if mode == "celery":
        env["FLEETHEALTH_JOB_RUNNER"] = "celery"
        flush_redis(redis_url)
    with throwaway_database("postgresql") as (url, _label):
        upgrade(url)
        key, operator_id, _design_s = build_operator(url, plan)
        worker_env = {**os.environ, **env, "FLEETHEALTH_DATABASE_URL": url,
                      "FLEETHEALTH_DATA_DIR": args.data_dir, "FLEETHEALTH_LOG_LEVEL": "WARNING",
                      "FLEETHEALTH_LOG_JSON": "false", "OMP_NUM_THREADS": "1"}
        with server.serving(url, Path(args.data_dir), port=args.port, env=env) as (served, base), \
                (celery_worker(worker_env, workers) if mode == "celery" else _nothing()) as worker:
            engine = create_engine(url)
            with httpx.Client(base_url=base, timeout=3600, headers={"X-API-Key": key}) as client:
                # Two warm-up uploads: the first may find the pool's or worker's process still
                # starting (then the job does it all), the second has every process take part.
                for half in (warm.slice(0, args.warm // 2), warm.slice(args.warm // 2)):
                    t0 = time.perf_counter()
                    post_all(client, csv_bodies(half, args.chunk))
                    wait_for_jobs(engine, operator_id, t0)
                with engine.connect() as hold:
                    hold.execute(text("SELECT pg_advisory_lock(:k)"), {"k": SERIAL_CLAIM_LOCK})
                    hold.commit()
                    t_up = time.perf_counter()
                    post_all(client, bodies)
                    upload = time.perf_counter() - t_up
                    load0 = os.getloadavg()[0]
                    watch = CpuWatch(engine, served.pid, worker)
                    t0 = time.perf_counter()
                    hold.execute(text("SELECT pg_advisory_unlock(:k)"), {"k": SERIAL_CLAIM_LOCK})
                    hold.commit()
                wait_for_jobs(engine, operator_id, t0)
                took = time.perf_counter() - t0
                cpu = watch.line()
            with engine.connect() as connection:
                estimated = connection.execute(text(
                    "SELECT count(*) FROM estimates e JOIN engines g ON g.id = e.engine_id "
                    "WHERE g.operator_id = :o"),
                    {"o": operator_id}).scalar_one()
                waiting = connection.execute(text(
                    "SELECT count(*) FROM estimation_backlog WHERE operator_id = :o"),
                    {"o": operator_id}).scalar_one()
                failed = connection.execute(text(
                    "SELECT count(*) FROM jobs WHERE operator_id = :o AND status <> 'succeeded'"),
                    {"o": operator_id}).scalar_one()
                ran = connection.execute(text(
                    "SELECT count(*), sum(extract(epoch FROM finished_at - started_at)) "
                    "FROM jobs WHERE operator_id = :o"), {"o": operator_id}).one()
                groups, own = connection.execute(text(
                    "SELECT max((result->>'groups')::int), sum((result->>'records')::int) "
                    "FROM jobs WHERE operator_id = :o"), {"o": operator_id}).one()
            engine.dispose()
        copy = raw_binary_copy(url, operator_id)[0] if (mode, workers) == ("pool", 2) else None
    if mode == "celery":
        flush_redis(redis_url)
    print(f"  {mode:6s} {workers} worker(s): backlog of {n:,} records in {took:6.2f} s "
          f"({n / took:,.0f} records/s; {groups or 1} engine groups, "
          f"{own - args.warm:,} records by the job's own process; {ran[0]} jobs ran "
          f"{float(ran[1]):.2f} s, the warm-ups' included); load at start {load0:.2f},"
          f" at end {os.getloadavg()[0]:.2f}; {estimated - args.warm:,} estimates stored, "
          f"{waiting} marks left, {failed} job(s) not succeeded", flush=True)
    print(f"    {cpu}", flush=True)
    total = upload + took
    print(f"    uploads stored before (claims held) in {upload:.2f} s; upload then backlog, "
          f"one after the other: {total:.2f} s, {n / total:,.0f} records/s end to end "
          "(target >= 50,000)", flush=True)
    if copy is not None:
        peer = (n + args.warm) / copy  # it copies the warm-up's rows too
        print(f"    raw binary COPY of the same rows: {copy:.2f} s, {peer:,.0f} records/s; "
              f"end to end {100 * n / total / peer:.1f} % of it (target >= 30 %)", flush=True)
    if failed or waiting or estimated - args.warm != n:
        raise SystemExit("the backlog was not estimated exactly once")
    return took


@contextmanager
def _nothing() -> Iterator[None]:
    yield None


def machine_busy() -> float:
    """CPU seconds the machine's cores spent busy since boot (``/proc/stat``: all but idle
    and iowait)."""
    fields = [int(f) for f in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:8]]
    return (sum(fields) - fields[3] - fields[4]) / os.sysconf("SC_CLK_TCK")


def every_process() -> dict[int, tuple[str, float]]:
    """Name and CPU seconds (``process_cpu``) of every process on the machine."""
    out = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            comm = stat.read_text().split("(", 1)[1].rsplit(")", 1)[0]
        except OSError:
            continue
        out[int(stat.parent.name)] = (comm, process_cpu(int(stat.parent.name)))
    return out


class CpuWatch:
    """CPU seconds over the timed window: the server's process tree (the job and the pool),
    the Celery worker's tree, the database's PostgreSQL backends, this bench's own process
    (its polling for the jobs' end), the other processes by name, and the whole machine."""

    def __init__(self, engine: object, server_pid: int, worker_pid: int | None) -> None:
        self.engine, self.pids = engine, {"server": server_pid, "celery": worker_pid}
        self.start = self._read()

    def _read(self) -> dict[str, dict[int, float]]:
        trees = {role: cpu_by_process(pid) for role, pid in self.pids.items() if pid}
        return {**trees, "postgres": {b: process_cpu(b) for b in postgres_backends(self.engine)},
                "bench": {os.getpid(): process_cpu(os.getpid())},
                "all": {p: c for p, (_n, c) in every_process().items()},
                "machine": {0: machine_busy()}}

    def line(self) -> str:
        names = {p: n for p, (n, _c) in every_process().items()}
        end = self._read()
        spent = {role: sum(c - self.start.get(role, {}).get(p, 0.0) for p, c in procs.items())
                 for role, procs in end.items() if role not in ("all", "machine")}
        known = {p for role, procs in end.items() if role not in ("all", "machine")
                 for p in procs}
        others: dict[str, float] = {}
        for p, c in end["all"].items():
            if p not in known:
                name = names.get(p, "?")
                others[name] = others.get(name, 0.0) + c - self.start["all"].get(p, 0.0)
        machine = end["machine"][0] - self.start["machine"][0]
        gone = machine - sum(spent.values()) - sum(others.values())
        top = sorted(others.items(), key=lambda kv: -kv[1])[:4]
        return ("CPU s in the window: " + ", ".join(f"{k} {v:.1f}" for k, v in spent.items())
                + "; other processes " + ", ".join(f"{n} {c:.1f}" for n, c in top)
                + f"; processes that ended, and the kernel's own {gone:.1f}; machine {machine:.1f}")


def _busy(n: int = 3_000_000) -> int:
    total = 0
    for i in range(n):
        total += i
    return total


def headroom() -> float:
    """What a second process buys on this machine now: the time of two units of pure-Python
    work in one process over one unit in each of two processes (2.0 on two idle cores; on a
    shared machine the scheduler's share for these processes caps it, whatever the code)."""
    import multiprocessing

    started = time.perf_counter()
    _busy()
    _busy()
    one = time.perf_counter() - started
    started = time.perf_counter()
    processes = [multiprocessing.get_context("fork").Process(target=_busy) for _ in range(2)]
    for process in processes:
        process.start()
    for process in processes:
        process.join()
    return one / (time.perf_counter() - started)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=100_000)
    ap.add_argument("--large", action="store_true", help="2,000,000 records")
    ap.add_argument("--aircraft", type=int, default=25)
    ap.add_argument("--chunk", type=int, default=250_000, help="records per request")
    ap.add_argument("--warm", type=int, default=2000, help="records estimated before timing")
    ap.add_argument("--seed", type=int, default=20260101)
    ap.add_argument("--modes", default="pool,celery")
    ap.add_argument("--workers", default="1,2")
    ap.add_argument("--port", type=int, default=None, help="the server's (default: a free one)")
    ap.add_argument("--redis-db", type=int, default=None,
                    help="a Redis database of this run's own (flushed before and after); "
                         "needed for the celery mode")
    ap.add_argument("--data-dir", default="/tmp/fh-bench-fleet",
                    help="the server's data directory (its engine caches are kept)")
    args = ap.parse_args()
    if "celery" in args.modes.split(",") and args.redis_db is None:
        ap.error("--redis-db: the celery mode flushes it, give a database of this run's own")
    n = 2_000_000 if args.large else args.rows
    os.environ["FLEETHEALTH_DATA_DIR"] = args.data_dir
    print(f"{load_line()}; {threads_line()} (servers and workers: 1 thread)")

    from app.services.snapshots import estimator

    estimator.builtin_schedule()
    estimator.builtin_trim_table()
    started = time.perf_counter()
    plan, table = simulate(args.aircraft, n + args.warm, args.seed)
    warm, table = table.slice(0, args.warm), table.slice(args.warm)
    n = table.num_rows
    print(f"simulated {n:,} + {args.warm} records of {2 * args.aircraft} engines in "
          f"{time.perf_counter() - started:.1f} s", flush=True)
    bodies = csv_bodies(table, args.chunk)
    times = {}
    for mode in args.modes.split(","):
        print(f"{mode}: the machine's headroom for a second process now {headroom():.2f}x "
              "(a pure-Python control; 2.00x on idle cores)", flush=True)
        for workers in (int(w) for w in args.workers.split(",")):
            times[mode, workers] = one_run(args, plan, warm, bodies, n, mode, workers)
        print(f"{mode}: headroom after {headroom():.2f}x", flush=True)
    ok = True
    for mode in args.modes.split(","):
        if (mode, 1) in times and (mode, 2) in times:
            speedup = times[mode, 1] / times[mode, 2]
            ok &= speedup >= TARGET_SPEEDUP
            print(f"{mode}: 2 workers / 1 worker speed-up {speedup:.2f}x "
                  f"(target >= {TARGET_SPEEDUP}x) -> "
                  f"{'PASS' if speedup >= TARGET_SPEEDUP else 'FAIL'}")
    print(f"load average at the end {os.getloadavg()[0]:.2f}")
    print("PASS" if ok else "FAIL")


if __name__ == "__main__":
    main()
