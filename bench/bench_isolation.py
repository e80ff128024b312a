"""Isolation of the seed 002 fault library on the nonlinear engine, per candidate design.

A simulated fleet (scatter, deterioration, actuator biases; take-off and cruise snapshots over
the envelope) gets each library fault after ``--before`` records; every design isolates it the
product's way (sensor-space WSSR over ``--after`` records against the baseline tuners,
``estimation.evaluate_engine``). Printed per design: percent correct (mean of the confusion
diagonal), the same with the ambiguity groups of the best design counted as right, the health
RMS at the baseline, and the confusion of the best design; targets beside.

    PYTHONPATH=. python bench/bench_isolation.py            # 25 engines per fault (~1 min)
    PYTHONPATH=. python bench/bench_isolation.py --engines 100
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from estimation import evaluate_engine as ee
from estimation.engine.health import HEALTH_NAMES
from estimation.engine.schedule import build_schedule
from estimation.engine.sensors import SENSOR_NAMES
from estimation.posterior import ambiguity_groups

TARGET, AIM = 90.0, 95.0
TURBO = HEALTH_NAMES[:10]
NO_WF = tuple(s for s in SENSOR_NAMES if s != "Wf")


def designs() -> list[ee.EngineDesign]:
    sub10, sub11 = ee.subset_vstar(TURBO), ee.subset_vstar((*TURBO, "wf_bias"))
    return [
        ee.EngineDesign("demo: subset m=10, 11 sensors, Wf input, linear", NO_WF, sub10),
        ee.EngineDesign("subset m=10, 12 sensors, Wf sensor, linear", SENSOR_NAMES, sub10,
                        wf="sensor"),
        ee.EngineDesign("subset m=10, 11 sensors, Wf input, secant", NO_WF, sub10,
                        signatures="secant"),
        ee.EngineDesign("subset m=10, 12 sensors, Wf sensor, secant", SENSOR_NAMES, sub10,
                        wf="sensor", signatures="secant"),
        ee.EngineDesign("subset m=11 (+wf_bias), 12 sensors, Wf sensor, secant", SENSOR_NAMES,
                        sub11, wf="sensor", signatures="secant"),
    ]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--engines", type=int, default=25, help="engines per library fault")
    ap.add_argument("--before", type=int, default=30)
    ap.add_argument("--after", type=int, default=20)
    ap.add_argument("--seed", type=int, default=2)
    args = ap.parse_args()
    t0 = time.perf_counter()
    sched = build_schedule()
    rec = ee.simulate_records(args.engines, rng=np.random.default_rng(args.seed),
                              n_before=args.before, n_after=args.after)
    print(f"fleet: {len(rec.fault)} engines, {args.before}+{args.after} records each "
          f"({time.perf_counter() - t0:.1f} s with the schedule)")
    results = []
    for d in designs():
        t = time.perf_counter()
        try:
            results.append((d, ee.evaluate_design(d, rec, sched), time.perf_counter() - t))
        except np.linalg.LinAlgError as exc:
            print(f"{d.name}: not observable ({exc})")
    best = max(results, key=lambda r: r[1].percent_correct)[1]
    groups = ambiguity_groups(best.confusion, best.faults, threshold=10.0)
    print(f"\nambiguity groups of the best design (C_ij + C_ji > 10 %): "
          f"{[' or '.join(g) for g in groups.groups]}")
    visible = [i for i, f in enumerate(best.faults) if groups.group_of(f) == (f,)]
    print(f"\n{'design':58s} {'% correct':>9s} {'groups':>7s} {'visible':>8s} "
          f"{'h RMS':>6s} {'s':>5s}   target >= {TARGET:.0f} % (aim {AIM:.0f})")
    for d, r, dt in results:
        diag = np.diag(np.nan_to_num(r.confusion))
        print(f"{d.name:58s} {r.percent_correct:9.1f} "
              f"{groups.group_correct(r.confusion, r.faults):7.1f} "
              f"{np.mean(diag[visible]):8.1f} {np.sqrt(np.mean(r.health_rms**2)):6.2f} "
              f"{dt:5.1f}   {'met' if r.percent_correct >= TARGET else 'miss'}")
    print(f"\nconfusion of the best design, {best.design} (percent, rows true):")
    print("".ljust(6) + "".join(f.rjust(6) for f in best.faults))
    for f, row in zip(best.faults, best.confusion, strict=True):
        print(f.ljust(6) + "".join(f"{v:6.0f}" for v in row))
    print("\nhealth at the baseline (best design): RMS % and 95 % coverage")
    for n, rms, cov in zip(HEALTH_NAMES, best.health_rms, best.coverage, strict=True):
        print(f"  {n:9s} {rms:5.2f} {cov:5.2f}")


if __name__ == "__main__":
    main()
