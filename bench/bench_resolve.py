"""Engine resolution of upload records: (tail, position, time) -> engine id.

The fleet and the records are ``fleethealth simulate --mode snapshot``'s
(``bench_ingest_fleet.simulate``: the demo's fleet settings for ``--aircraft`` aircraft, with
its engine swaps, shop visits and spares; ``--records`` take-off and cruise records), the
installations stored by the demo's own ``_fleet`` on a throw-away database (SQLite file,
PostgreSQL database; ``--backends``). fleethealth's ``fleet.resolve_engines`` (one query, then
numpy keys and ``searchsorted``) against two peers on the same fleet and records, in the same
run:
- per-record ``bisect`` over each tail position's sorted installations in plain Python
  (what a straightforward loop does once the installations are loaded);
- per-record SQL (``fleet.resolve_engine``), on a sample, scaled to the whole batch.
All three must give the same engines. BLAS threads pinned (one), the load printed first and
last. Target: 100,000 records well inside the ingest budget of issue 5 (50,000 snapshots/s end
to end, i.e. 2 s per 100,000): <= 0.2 s.

    .venv/bin/python bench/bench_resolve.py [--records N] [--aircraft N] [--backends sqlite]
"""

from __future__ import annotations

import argparse
import bisect
import sys
import time
from datetime import datetime
from typing import Any

import _common  # noqa: F401  (pins BLAS threads)
import numpy as np
from _common import ROOT, best_time, run_on_backends

sys.path.insert(0, str(ROOT / "bench"))

from bench_ingest_fleet import simulate
from sqlalchemy.orm import Session

from app.db import make_engine
from app.migrate import upgrade
from app.services.demo import fleet as demo
from app.services.fleet import service as fleet
from app.services.tenancy import service as tenancy


def bisect_peer(session: Session, operator_id: int, tails, positions, times) -> np.ndarray:
    """Load the installations, then bisect per record in plain Python."""
    rows, _ = fleet.list_installations(session, operator_id=operator_id, limit=10**9, offset=0)
    slots: dict[tuple[str, int], list[tuple[datetime, datetime | None, int]]] = {}
    for r in rows:
        slots.setdefault((r.aircraft.tail, r.position), []).append(
            (r.installed_at, r.removed_at, r.engine_id)
        )
    starts = {k: sorted(v) for k, v in slots.items()}
    keys = {k: [s for s, _, _ in v] for k, v in starts.items()}
    out = np.full(len(tails), fleet.NO_ENGINE, dtype=np.int64)
    for i, (tail, position, t) in enumerate(zip(tails, positions, times, strict=True)):
        where = keys.get((tail, position))
        if not where:
            continue
        j = bisect.bisect_right(where, t) - 1
        if j >= 0:
            start, end, engine_id = starts[(tail, position)][j]
            if end is None or t < end:
                out[i] = engine_id
    return out


def run(url: str, label: str, plan: Any, records: Any, sql_sample: int) -> bool:
    upgrade(url)
    engine = make_engine(url)
    with Session(engine) as session:
        operator = tenancy.create_operator(session, name="Bench Resolve Air")
        kind = fleet.create_engine_type(session, operator_id=operator.id, name=demo.ENGINE_TYPE)
        demo._fleet(session, operator.id, kind.id, plan)
        session.commit()
        operator_id = operator.id
        n = records.num_rows
        tails = records["tail"].to_pylist()
        positions = records["position"].to_numpy()
        times64 = records["recorded_at"].to_numpy().astype("datetime64[us]")
        times = records["recorded_at"].to_pylist()

        ours = fleet.resolve_engines(session, operator_id, tails, positions, times64)
        t_ours = best_time(
            lambda: fleet.resolve_engines(session, operator_id, tails, positions, times64)
        )
        peer = bisect_peer(session, operator_id, tails, positions.tolist(), times)
        t_bisect = best_time(
            lambda: bisect_peer(session, operator_id, tails, positions.tolist(), times), repeat=1
        )
        assert np.array_equal(ours, peer), "vectorised and bisect resolutions differ"
        assert (ours != fleet.NO_ENGINE).all(), "a simulated record without its engine"

        rng = np.random.default_rng(0)
        sample = rng.choice(n, size=min(sql_sample, n), replace=False)
        t0 = time.perf_counter()
        for i in sample:
            found = fleet.resolve_engine(
                session, operator_id, tails[i], int(positions[i]), times[i]
            )
            assert (found.id if found else fleet.NO_ENGINE) == ours[i], "SQL peer differs"
        t_sql = (time.perf_counter() - t0) * n / len(sample)

    engine.dispose()
    print(
        f"{label}: {n:,} records, {len(plan.tails)} tails x 2 positions, {len(plan.esns)} "
        f"engines, {len(plan.installations)} installations"
    )
    print(
        f"  resolve_engines (fleethealth)   {t_ours * 1e3:9.1f} ms  {n / t_ours:12,.0f} records/s"
    )
    print(
        f"  per-record bisect (Python)      {t_bisect * 1e3:9.1f} ms  "
        f"ratio {t_bisect / t_ours:6.1f}x"
    )
    print(f"  per-record SQL (scaled)         {t_sql * 1e3:9.1f} ms  ratio {t_sql / t_ours:6.1f}x")
    ok = t_ours <= 0.2 * n / 100_000
    print(f"  target <= 0.2 s per 100,000 records: {'PASS' if ok else 'FAIL'}")
    return ok


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--records", type=int, default=100_000)
    parser.add_argument("--aircraft", type=int, default=25)
    parser.add_argument("--sql-sample", type=int, default=300)
    parser.add_argument("--seed", type=int, default=20260101)
    parser.add_argument("--backends", default="sqlite")
    args = parser.parse_args()
    t0 = time.perf_counter()
    plan, records = simulate(args.aircraft, args.records, args.seed)
    print(f"simulated {records.num_rows:,} records of {args.aircraft} aircraft in "
          f"{time.perf_counter() - t0:.1f} s")
    run_on_backends(args.backends,
                    lambda url, label: run(url, label, plan, records, args.sql_sample))


if __name__ == "__main__":
    main()
