"""Honest health uncertainty per design: calibrate on one simulated fleet, score on another.

For each design (method:m, "+bias": the tuners also span the three actuator biases) the
model-error term of ``estimation.uncertainty`` is fitted on a demo-like fleet simulated with
``--calibrate-seed`` (``tests.support.health_uncertainty.calibrate``) and scored on a fleet
simulated with ``--seed``: coverage of the honest 1-sigma and 2-sigma of the level (and of the
filter's own 1-sigma), level RMS, change since the baseline (RMS over all settled records and
at each segment's end) and fleet-average slopes against the simulator's truth, next to the
issue's targets.

    .venv/bin/python bench/bench_uncertainty.py                       # 6 aircraft, a year
    .venv/bin/python bench/bench_uncertainty.py --aircraft 12 --designs svd:8+bias
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import _common  # noqa: F401  (import path)
import numpy as np

from app.engine_cache import engine_schedule
from app.services.demo import fleet as demo_fleet
from estimation.engine.fleet import fleet_snapshots, plan_fleet
from tests.support import health_uncertainty

DESIGNS = ("subset:10", "svd:8+bias", "svd:6")
TARGETS = ("targets: shown parameters 1-sigma coverage 55-85 %, 2-sigma >= 85 %; change RMS "
           "<= 0.5 %; fleet-average slopes within 30 % of the truth")


def fleet(size: demo_fleet.DemoSize, seed: int):  # type: ignore[no-untyped-def]
    plan_rng, snap_rng = np.random.default_rng(seed).spawn(2)
    plan = plan_fleet(demo_fleet.fleet_config(size), plan_rng)
    return plan, fleet_snapshots(plan, snap_rng)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--aircraft", type=int, default=6)
    ap.add_argument("--flights", type=int, default=730)
    ap.add_argument("--calibrate-seed", type=int, default=demo_fleet.SEED + 1)
    ap.add_argument("--seed", type=int, default=demo_fleet.SEED)
    ap.add_argument("--designs", default=",".join(DESIGNS))
    ap.add_argument("--cache", type=Path, default=Path("/tmp/fh/cache"))
    ap.add_argument("--json", type=Path, default=None, help="write the calibrations here")
    args = ap.parse_args()

    sched = engine_schedule(args.cache)
    size = demo_fleet.DemoSize(aircraft=args.aircraft, flights=args.flights)
    t0 = time.perf_counter()
    cal_fleet = fleet(size, args.calibrate_seed)
    test_fleet = fleet(size, args.seed)
    print(f"fleets: {args.aircraft} aircraft, {args.flights} flights; calibration seed "
          f"{args.calibrate_seed}, scoring seed {args.seed}; simulated in "
          f"{time.perf_counter() - t0:.0f} s")
    print(TARGETS)
    stored = {}
    for item in args.designs.split(","):
        method, m = item.split(":")
        biases = m.endswith("+bias")
        est = demo_fleet.design_estimator(sched, method, int(m.removesuffix("+bias")), biases)
        t1 = time.perf_counter()
        calib = health_uncertainty.calibrate(est, *cal_fleet, design=item,
                                             seed=args.calibrate_seed)
        sc = health_uncertainty.score(est, calib, *test_fleet)
        stored[item] = calib.to_dict()
        s = sc.summary()
        print(f"\n== {item} (m = {est.m}; {time.perf_counter() - t1:.0f} s; {sc.records} "
              f"records, {sc.segments} segments)")
        print("model error s [%]: " + " ".join(
            f"{n}={v:.2f}" for n, v in zip(calib.names, calib.level_std, strict=True)))
        print("analytic bias [%]: " + " ".join(
            f"{n}={v:.2f}" for n, v in zip(calib.names, np.sqrt(calib.bias2), strict=True)))
        print("calibration slope error: " + " ".join(
            f"{n}={v:.0%}" for n, v in zip(calib.names, calib.slope_error, strict=True)))
        print(sc.report())
        print(f"shown {s['shown']} of {len(sc.names)}: 1-sigma coverage "
              f"{s['cover1_min']:.2f}-{s['cover1_max']:.2f} (target 0.55-0.85), 2-sigma min "
              f"{s['cover2_min']:.2f} (>= 0.85), level RMS {s['level_rms']:.2f} %, change RMS "
              f"{s['change_rms']:.2f} % (all records; <= 0.5), {s['end_change_rms']:.2f} % "
              f"(segment ends), worst slope error {s['slope_err_max']:.0%} (<= 30 %)")
    if args.json:
        args.json.write_text(json.dumps(stored, indent=1))


if __name__ == "__main__":
    main()
