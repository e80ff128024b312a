"""Shift detection and fault isolation on a simulated fleet, scored against the simulator's truth.

Simulates the demo fleet (``app.services.demo.fleet``: seed, size, design) or a larger one
with more faults, runs the pipeline's estimation functions over every engine's take-off and
cruise snapshots (``tests.support.detection_replay``), and prints the confusion table of
isolated vs injected fault, detection delays in flights and false alarms per 1000
engine-flights. The truth is the fleet plan's fault list, never typed-in numbers.

    .venv/bin/python bench/bench_detection.py                      # the demo fleet
    .venv/bin/python bench/bench_detection.py --aircraft 20 --flights 1000 \\
        --fault-rate 0.002 --seed 7                                     # many faults
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import _common  # noqa: F401  (import path)
import numpy as np

from app.engine_cache import engine_schedule
from app.services.demo import fleet
from estimation import shift_detector as detector
from estimation.engine.fleet import fleet_snapshots, plan_fleet
from tests.support import detection_replay


def main() -> None:
    print(_common.load_line())
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = fleet.DemoSize()
    ap.add_argument("--aircraft", type=int, default=default.aircraft)
    ap.add_argument("--flights", type=int, default=default.flights)
    ap.add_argument("--fault-rate", type=float, default=default.fault_rate)
    ap.add_argument("--seed", type=int, default=fleet.SEED)
    ap.add_argument("--tuners", type=int, default=10)
    ap.add_argument("--method", default="subset")
    ap.add_argument("--biases", action="store_true",
                    help="the design's health vector includes the three actuator biases")
    ap.add_argument("--cache", type=Path, default=Path("/tmp/fh/cache"))
    args = ap.parse_args()

    t0 = time.perf_counter()
    est = fleet.design_estimator(engine_schedule(args.cache), args.method, args.tuners,
                                      args.biases)
    t1 = time.perf_counter()
    size = fleet.DemoSize(aircraft=args.aircraft, flights=args.flights,
                               fault_rate=args.fault_rate)
    plan_rng, snap_rng = np.random.default_rng(args.seed).spawn(2)
    plan = plan_fleet(fleet.fleet_config(size), plan_rng)
    snaps = fleet_snapshots(plan, snap_rng)
    t2 = time.perf_counter()
    engines = detection_replay.engine_runs(plan, snaps, est)
    events = detection_replay.replay(est, engines)
    t3 = time.perf_counter()
    result = detection_replay.score(plan, engines, events, est.layout.faults, est)
    print(f"fleet: {args.aircraft} aircraft, {len(plan.esns)} engines, {args.flights} flights, "
          f"seed {args.seed}, {len(plan.faults)} faults injected; design {args.method} "
          f"m = {est.m}")
    print(f"time: design {t1 - t0:.1f} s, simulation {t2 - t1:.1f} s, "
          f"estimation {t3 - t2:.1f} s")
    print(result.report())
    wanted = result.detectable(3, detector.N_BASE + detector.GAP, 60.0)
    correct = [f for f in wanted if f.isolated == f.fault]
    delays = [f.delay_flights for f in correct if f.delay_flights is not None]
    print(f"detectable faults (alone on their engine, >= 3 flights with it, baseline in place, "
          f"signature noncentrality >= 60 over 20 records): {len(wanted)}; detected "
          f"{sum(f.detected for f in wanted)}, correctly isolated {len(correct)}"
          + (f" ({100.0 * len(correct) / len(wanted):.0f} %)" if wanted else "")
          + (f", median delay {np.median(delays):.0f} flights" if delays else ""))
    for f in result.scored:
        print(f"  {f.esn} {f.fault:4s} x{f.scale:.2f} -> {f.isolated:4s} ({f.kind}), "
              f"delay {f.delay_flights} of {f.flights_observed} flights, noncentrality "
              f"{f.noncentrality:.0f}, {f.records_before} records after the last reset"
              + (", concurrent" if f.concurrent else ""))
    for esn, epoch, kind, fault in result.false_alarms[:30]:
        print(f"  false alarm {esn} {time.strftime('%Y-%m-%d', time.gmtime(epoch))} "
              f"{kind} {fault}")


if __name__ == "__main__":
    main()
