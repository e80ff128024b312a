"""Live streams through ``fleethealth serve``: from a chunk's POST until its estimates can be read.

The server runs in its own process as deployed (uvicorn, its job process) on a free port (or
``--port``) and a throw-away database (SQLite file, PostgreSQL database, dropped after). The
operator's engine type is the demo's built-in engine with the demo's active design (made by the
product's design service, as the demo makes it: ``bench_stream_service.setup``); the built-in
engine's schedule is read from the cache (``--cache``).

The flight: the first of ``fleethealth simulate --mode stream``'s whole-flight CSV files of the
built-in engine (20 Hz; bench_stream_filter's pool), its ground idle cut as in
``bench_stream_service``; the first ``--seconds`` after it (take-off and climb, the engine's
own conditions changing every sample) are sent as live chunks of ``--chunk-s`` seconds at the
pace they are recorded, over real sockets (httpx); after each POST the client reads
``GET /streams/{id}/estimates`` every 10 ms until the filter has run over every sample sent
(``n_samples_estimated``). The latency of a chunk is the time from its POST to that read.

The bound, in this process on the same chunks: the work a chunk needs at the least, parsed as
an upload parses it (``parse_body``), its trims and deviations (``filter_inputs``) and the
filter over it from the carry of the chunk before (``filter_piece``, the gains cached).

BLAS and OpenMP run one thread in both processes; the load average is printed first and last.

Target (issue 13): p95 latency <= 1 s at 20 Hz.

    .venv/bin/python bench/bench_live.py [--backends sqlite,postgresql] [--seconds 120]
        [--chunk-s 1] [--port N]
"""

from __future__ import annotations

import argparse
import time
from datetime import datetime
from pathlib import Path

import _common
import httpx
import numpy as np
from bench_stream_service import TAILS, after_idle, csv_of, setup, wait_estimated

from app.migrate import upgrade
from app.services.streams.run import Carry, filter_inputs, filter_piece
from app.services.uploads.parse import parse_body

TARGET_P95_S = 1.0


def run(url: str, label: str, args: argparse.Namespace) -> bool:
    upgrade(url)
    path, entry = _common.simulated_streams(args.aircraft, args.flight_seconds, args.seed)[0]
    raw = path.read_bytes()
    parsed = parse_body(raw, "csv", kind="stream")
    operator_id, key, est = setup(url, sorted(parsed.signals))
    sent, dt, cut = after_idle(est, raw, parsed)
    per = int(round(args.chunk_s / dt))
    n = min(sent.num_rows, int(round(args.seconds / dt)))
    chunks = [csv_of(sent.slice(lo, per)) for lo in range(0, n, per)]
    n = min(n, len(chunks) * per)
    started = datetime.fromisoformat(str(entry["started_at"]).replace("Z", "+00:00"))
    print(f"\n== {label}: flight {entry['flight_id']}, {cut:,} samples of ground idle cut, "
          f"{len(chunks)} chunks of {args.chunk_s:g} s ({per} samples at {1 / dt:g} Hz) sent "
          "in real time")
    latencies = []
    with _common.serving(url, port=args.port, schedule_cache=args.cache) as base, \
            httpx.Client(base_url=base, timeout=60, headers={"X-API-Key": key}) as client:
        opened = client.post("/api/v1/streams/live", json={
            "tail": TAILS[3], "position": 1, "started_at": started.isoformat(), "dt_s": dt})
        opened.raise_for_status()
        rid = opened.json()["id"]
        ok = True
        t_start = time.perf_counter()
        for index, part in enumerate(chunks):
            # Recorded in real time: chunk k is complete (k + 1) chunk lengths after the start.
            time.sleep(max(0.0, t_start + index * args.chunk_s - time.perf_counter()))
            t0 = time.perf_counter()
            r = client.post(f"/api/v1/streams/{rid}/chunks", params={"index": index},
                            content=part, headers={"Content-Type": "text/csv"})
            assert r.status_code == 201, r.text[:300]
            ok &= wait_estimated(client, rid, min(n, (index + 1) * per), url, operator_id,
                                 timeout=60.0)
            latencies.append(time.perf_counter() - t0)

    # The bound: each chunk parsed, its inputs and the filter over it, in this process.
    carry = Carry(np.zeros(est.n), np.zeros(est.model.n_inputs), None, 0)
    whole = parse_body(b"".join([chunks[0], *(c.split(b"\n", 1)[1] for c in chunks[1:])]),
                       "csv", kind="stream").table
    filter_piece(est, dt, *filter_inputs(est, whole), carry)  # every segment's gain, once
    floor = []
    for part in chunks:
        t0 = time.perf_counter()
        table = parse_body(part, "csv", kind="stream").table
        _rows, carry, _ = filter_piece(est, dt, *filter_inputs(est, table), carry)
        floor.append(time.perf_counter() - t0)
    lat, low = np.array(latencies), np.array(floor)
    p50, p95 = np.percentile(lat, [50, 95])
    ok &= bool(p95 <= TARGET_P95_S)
    print(f"POST to estimates readable: p50 {1e3 * p50:.0f} ms, p95 {1e3 * p95:.0f} ms, max "
          f"{1e3 * lat.max():.0f} ms; target p95 <= {1e3 * TARGET_P95_S:.0f} ms: "
          f"{'PASS' if p95 <= TARGET_P95_S else 'FAIL'}")
    print(f"bound (parse, inputs, filter of the chunk in-process): p50 "
          f"{1e3 * np.median(low):.1f} ms, p95 {1e3 * np.percentile(low, 95):.1f} ms; the "
          f"server's p50 is {p50 / np.median(low):.0f}x it")
    return ok


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--backends", default="sqlite,postgresql")
    ap.add_argument("--seconds", type=float, default=120.0, help="seconds sent after ground idle")
    ap.add_argument("--chunk-s", type=float, default=1.0)
    ap.add_argument("--port", type=int, default=None, help="the server's (default: a free one)")
    ap.add_argument("--flight-seconds", type=float, default=600.0,
                    help="simulated seconds of flight (bench_stream_filter's pool)")
    ap.add_argument("--aircraft", type=int, default=8,
                    help="aircraft of the simulated pool (bench_stream_filter's; the first flight)")
    ap.add_argument("--seed", type=int, default=20260101)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/fh/cache"),
                    help="the built-in engine's schedule cache")
    args = ap.parse_args()
    with _common.schedule_cache(args.cache):
        _common.run_on_backends(args.backends, lambda url, label: run(url, label, args))


if __name__ == "__main__":
    main()
