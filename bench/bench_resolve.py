"""Engine resolution of upload records: (tail, position, time) -> engine id.

fleethealth's ``fleet.resolve_engines`` (one query, then numpy keys and ``searchsorted``)
against two peers on the same fleet and records, in the same run:
- per-record ``bisect`` over each tail position's sorted installations in plain Python
  (what a straightforward loop does once the installations are loaded);
- per-record SQL (``fleet.resolve_engine``), on a sample, scaled to the whole batch.
All three must give the same engines. Target: 100,000 records well inside the ingest
budget of issue 5 (50,000 snapshots/s end to end, i.e. 2 s per 100,000): <= 0.2 s.

    .venv/bin/python bench/bench_resolve.py [--records N] [--tails N] [--url URL]
"""

from __future__ import annotations

import argparse
import bisect
import tempfile
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
from _common import best_time
from sqlalchemy.orm import Session

from app.db import make_engine
from app.migrate import upgrade
from app.services.fleet import service as fleet
from app.services.tenancy import service as tenancy

T0 = datetime(2025, 1, 1, tzinfo=UTC)


def build_fleet(session: Session, tails: int, swaps: int) -> int:
    """An operator with ``tails`` two-engine aircraft, each position swapped ``swaps`` times
    over a year (fresh engines each time)."""
    operator = tenancy.create_operator(session, name=f"bench {time.time()}")
    et = fleet.create_engine_type(session, operator_id=operator.id, name="TF")
    period = timedelta(days=365 / (swaps + 1))
    for i in range(tails):
        ac = fleet.create_aircraft(session, operator_id=operator.id, tail=f"B{i:04d}")
        for position in (1, 2):
            for k in range(swaps + 1):
                engine = fleet.create_engine(
                    session,
                    operator_id=operator.id,
                    esn=f"E{i}-{position}-{k}",
                    engine_type_id=et.id,
                )
                fleet.install(
                    session,
                    operator_id=operator.id,
                    engine_id=engine.id,
                    aircraft_id=ac.id,
                    position=position,
                    installed_at=T0 + k * period,
                    removed_at=None if k == swaps else T0 + (k + 1) * period,
                )
    session.commit()
    return operator.id


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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--records", type=int, default=100_000)
    parser.add_argument("--tails", type=int, default=50)
    parser.add_argument("--swaps", type=int, default=3)
    parser.add_argument("--sql-sample", type=int, default=300)
    parser.add_argument("--url", default=None, help="database URL (default: a temporary SQLite)")
    args = parser.parse_args()

    url = args.url or f"sqlite:///{Path(tempfile.mkdtemp()) / 'bench.sqlite3'}"
    upgrade(url)
    engine = make_engine(url)
    with Session(engine) as session:
        operator_id = build_fleet(session, args.tails, args.swaps)
        rng = np.random.default_rng(0)
        n = args.records
        tails = [f"B{i:04d}" for i in rng.integers(0, args.tails, n)]
        positions = rng.integers(1, 3, n)
        micros = rng.integers(-30 * 86400 * 10**6, 400 * 86400 * 10**6, n)
        times64 = np.datetime64(T0.replace(tzinfo=None), "us") + micros.astype("timedelta64[us]")
        times = [T0 + timedelta(microseconds=int(m)) for m in micros]

        ours = fleet.resolve_engines(session, operator_id, tails, positions, times64)
        t_ours = best_time(
            lambda: fleet.resolve_engines(session, operator_id, tails, positions, times64)
        )
        peer = bisect_peer(session, operator_id, tails, positions.tolist(), times)
        t_bisect = best_time(
            lambda: bisect_peer(session, operator_id, tails, positions.tolist(), times), repeat=1
        )
        assert np.array_equal(ours, peer), "vectorised and bisect resolutions differ"

        sample = rng.choice(n, size=min(args.sql_sample, n), replace=False)
        t0 = time.perf_counter()
        for i in sample:
            found = fleet.resolve_engine(
                session, operator_id, tails[i], int(positions[i]), times[i]
            )
            assert (found.id if found else fleet.NO_ENGINE) == ours[i], "SQL peer differs"
        t_sql = (time.perf_counter() - t0) * n / len(sample)

    engine.dispose()
    print(
        f"{n} records, {args.tails} tails x 2 positions, {args.swaps} swaps each, "
        f"{url.split(':')[0]}"
    )
    print(
        f"  resolve_engines (fleethealth)   {t_ours * 1e3:9.1f} ms  {n / t_ours:12,.0f} records/s"
    )
    print(
        f"  per-record bisect (Python)      {t_bisect * 1e3:9.1f} ms  "
        f"ratio {t_bisect / t_ours:6.1f}x"
    )
    print(f"  per-record SQL (scaled)         {t_sql * 1e3:9.1f} ms  ratio {t_sql / t_ours:6.1f}x")
    verdict = "PASS" if t_ours <= 0.2 * n / 100_000 else "FAIL"
    print(f"  target <= 0.2 s per 100,000 records: {verdict}")


if __name__ == "__main__":
    main()
