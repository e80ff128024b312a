"""Honest health uncertainty per design: calibrate on several simulated fleets, score on others.

For each design (method:m, "+bias": the tuners also span the three actuator biases) the
model-error term of ``estimation.uncertainty`` is fitted as the product fits it
(``app.services.designs.calibration``: demo-like fleets simulated with each of
``--calibrate-seeds``, pooled) and scored on a fleet simulated with each of ``--seeds``:
coverage of the honest 1-sigma and 2-sigma of the level (and of the
filter's own 1-sigma), level RMS, change since the baseline (RMS over all settled records and
at each segment's end) and the product's fleet-average slopes (``app.services.fleet.slopes``:
weekly means split at baseline resets, inverse-variance mean, calibrated gain; percent per
year) against the simulator's truth, next to the issue's targets. A slope the calibration
finds unobservable is printed as such and left out of the worst slope error.

    .venv/bin/python bench/bench_uncertainty.py                       # 8 aircraft, a year
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
from app.services.designs import calibration
from tests.support import health_uncertainty

DESIGNS = ("subset:10", "svd:8+bias", "svd:6")
TARGETS = ("targets: shown parameters 1-sigma coverage 55-85 %, 2-sigma >= 85 %; change RMS "
           "<= 0.5 %; fleet-average slopes within 30 % of the truth (observable ones)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--aircraft", type=int, default=calibration.CALIBRATION_AIRCRAFT)
    ap.add_argument("--flights", type=int, default=730)
    ap.add_argument("--calibrate-seeds", default=",".join(map(str, calibration.CALIBRATION_SEEDS)))
    ap.add_argument("--seeds", default=f"{demo_fleet.SEED},{demo_fleet.SEED + 7}")
    ap.add_argument("--designs", default=",".join(DESIGNS))
    ap.add_argument("--cache", type=Path, default=Path("/tmp/fh/cache"))
    ap.add_argument("--json", type=Path, default=None, help="write the calibrations here")
    args = ap.parse_args()

    sched = engine_schedule(args.cache)
    t0 = time.perf_counter()
    cal_seeds = [int(s) for s in args.calibrate_seeds.split(",")]
    test_seeds = [int(s) for s in args.seeds.split(",")]
    cal_fleets = [calibration.simulate_fleet(s, args.aircraft, args.flights) for s in cal_seeds]
    test_fleets = [calibration.simulate_fleet(s, args.aircraft, args.flights)
                   for s in test_seeds]
    print(f"fleets: {args.aircraft} aircraft, {args.flights} flights; calibration seeds "
          f"{cal_seeds}, scoring seeds {test_seeds}; simulated in "
          f"{time.perf_counter() - t0:.0f} s")
    print(TARGETS)
    stored = {}
    for item in args.designs.split(","):
        method, m = item.split(":")
        biases = m.endswith("+bias")
        est = demo_fleet.design_estimator(sched, method, int(m.removesuffix("+bias")), biases)
        t1 = time.perf_counter()
        calib = calibration.calibrate(est, cal_fleets, design=item, seeds=cal_seeds)
        stored[item] = calib.to_dict()
        print(f"\n== {item} (m = {est.m}; calibrated in {time.perf_counter() - t1:.0f} s on "
              f"{calib.source['records']} records, {calib.source['segments']} segments)")
        print("model error s [%]: " + " ".join(
            f"{n}={v:.2f}" for n, v in zip(calib.names, calib.level_std, strict=True)))
        print("analytic bias [%]: " + " ".join(
            f"{n}={v:.2f}" for n, v in zip(calib.names, np.sqrt(calib.bias2), strict=True)))
        print("calibration slope error (pooled, before the gain): " + " ".join(
            f"{n}={v:.0%}" for n, v in zip(calib.names, calib.slope_error, strict=True)))
        print("slope error of a calibration fleet, cross-validated (RMS): " + " ".join(
            f"{n}={v:.0%}" for n, v in zip(calib.names, calib.source["slope_cross_error"],
                                           strict=True) if v is not None))
        print("slope gain (nan: slope unobservable): " + " ".join(
            f"{n}={v:.2f}" for n, v in zip(calib.names, np.asarray(calib.slope_gain),
                                           strict=True)))
        for seed, test_fleet in zip(test_seeds, test_fleets, strict=True):
            sc = health_uncertainty.score(est, calib, *test_fleet)
            s = sc.summary()
            print(f"-- scored on seed {seed}: {sc.records} records, {sc.segments} segments, "
                  f"{sc.pieces} trend pieces")
            print(sc.report())
            print(f"shown {s['shown']} of {len(sc.names)}: 1-sigma coverage "
                  f"{s['cover1_min']:.2f}-{s['cover1_max']:.2f} (target 0.55-0.85), 2-sigma "
                  f"min {s['cover2_min']:.2f} (>= 0.85), level RMS {s['level_rms']:.2f} %, "
                  f"change RMS {s['change_rms']:.2f} % (all records; <= 0.5), "
                  f"{s['end_change_rms']:.2f} % (segment ends), worst slope error "
                  f"{s['slope_err_max']:.0%} over {s['slopes_shown']} observable slopes "
                  f"(<= 30 %)")
            print(_common.load_line())
    if args.json:
        args.json.write_text(json.dumps(stored, indent=1))


if __name__ == "__main__":
    main()
