"""Estimated health trends of a simulated fleet against the simulator's truth, per design.

Simulates the demo fleet (``app.services.demo.fleet``: seed, size, configuration) or a
smaller one, runs the pipeline's snapshot filter over every engine's take-off and cruise
snapshots exactly as after an upload (``pipeline.run_filters`` through
``tests.support.health_accuracy``) and prints, per health parameter and design: bias and RMS
of h_hat - h against the plan's true health, the filter's own mean 1-sigma, the error at each
engine's last record and the fleet-average deterioration slope estimated vs true. Also prints
the rank of G_y at cruise alone, take-off alone, and both stacked (what a snapshot filter over
both phases can observe).

    .venv/bin/python bench/bench_health_accuracy.py                 # the demo fleet
    .venv/bin/python bench/bench_health_accuracy.py --aircraft 4 --flights 200
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import _common  # noqa: F401  (import path)
import numpy as np

from app.engine_cache import engine_schedule
from app.services.demo import fleet
from app.services.snapshots.estimator import (
    MODEL_ERROR,
    SnapshotEstimator,
)
from estimation.engine.fleet import fleet_snapshots, plan_fleet
from tests.support import health_accuracy

# method:m, "+bias": the tuners also span the three actuator biases (13 health parameters).
DESIGNS = ("subset:10", "subset:8", "svd:9", "svd:8", "svd:6", "optimal:8", "svd:8+bias",
           "svd:9+bias")


# A direction of health counts as observable in one record when a 1 % shift along it moves the
# sensors by at least 0.1 noise sigma (G_y is scaled by each sensor's noise).
OBSERVABLE = 0.1


def ranks(est: SnapshotEstimator) -> str:
    """Singular values / rank of G_y (noise-scaled) at cruise, take-off, and both stacked."""
    cruise = np.array([[35000.0, 0.8, 0.0, 80.0]])
    takeoff = np.array([[0.0, 0.2, 15.0, 100.0]])
    out = []
    stacked = []
    for name, c in (("cruise", cruise), ("takeoff", takeoff)):
        g = est.schedule(c)
        noise = est.noise_std if g.noise_std is None else np.sqrt(
            g.noise_std[0] ** 2 + MODEL_ERROR**2)
        A = g.G_y[0] / noise[:, None]
        stacked.append(A)
        sv = np.linalg.svd(A, compute_uv=False)
        out.append(f"{name}: rank {int(np.sum(sv > OBSERVABLE))}, smallest sv {sv[-1]:.3g}")
    A = np.vstack(stacked)
    sv = np.linalg.svd(A, compute_uv=False)
    out.append(f"stacked: rank {int(np.sum(sv > OBSERVABLE))}, "
               f"singular values {np.array2string(sv, precision=3)}")
    return "; ".join(out)


def fleet_average(est: SnapshotEstimator, tracks, flights: int) -> str:
    """Fleet-average h_hat vs true h over the first and last 60 rounds (about a month), and
    the most deteriorated value of any engine (settled records), estimated vs true."""
    rounds = np.concatenate([t.round for t in tracks])
    hat = np.concatenate([t.h_hat for t in tracks])
    true = np.concatenate([t.h_true for t in tracks])
    lines = [" " * 22 + "".join(f"{n[:9]:>10s}" for n in est.layout.health)]
    for label, lo, hi in (("first month", 0, 60), ("last month", flights - 60, flights)):
        sel = (rounds >= lo) & (rounds < hi)
        for kind, v in (("est", hat), ("true", true)):
            lines.append(f"{label + ' ' + kind:22s}" + "".join(
                f"{x:10.2f}" for x in v[sel].mean(axis=0)))
    worst_hat = np.min([t.h_hat[t.settled].min(axis=0) for t in tracks if t.settled.any()], 0)
    worst_true = np.min([t.h_true.min(axis=0) for t in tracks], axis=0)
    lines.append(f"{'lowest of any engine est':22s}" + "".join(f"{x:10.2f}" for x in worst_hat))
    lines.append(f"{'lowest of any engine true':22s}" + "".join(f"{x:10.2f}" for x in worst_true))
    return "\n".join(lines)


def main() -> None:
    print(_common.load_line())
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = fleet.DemoSize()
    ap.add_argument("--aircraft", type=int, default=default.aircraft)
    ap.add_argument("--flights", type=int, default=default.flights)
    ap.add_argument("--seed", type=int, default=fleet.SEED)
    ap.add_argument("--designs", default=",".join(DESIGNS))
    ap.add_argument("--cache", type=Path, default=Path("/tmp/fh/cache"))
    args = ap.parse_args()

    sched = engine_schedule(args.cache)
    size = fleet.DemoSize(aircraft=args.aircraft, flights=args.flights)
    plan_rng, snap_rng = np.random.default_rng(args.seed).spawn(2)
    t0 = time.perf_counter()
    plan = plan_fleet(fleet.fleet_config(size), plan_rng)
    snaps = fleet_snapshots(plan, snap_rng)
    print(f"fleet: {args.aircraft} aircraft, {len(plan.esns)} engines, {args.flights} flights, "
          f"seed {args.seed}, {len(plan.faults)} faults; simulated in "
          f"{time.perf_counter() - t0:.1f} s")
    for item in args.designs.split(","):
        method, m = item.split(":")
        biases = m.endswith("+bias")
        try:
            est = fleet.design_estimator(sched, method, int(m.removesuffix("+bias")),
                                              biases)
        except Exception as exc:  # an unobservable choice
            print(f"\n== {method} m = {m}: design failed ({exc})")
            continue
        t1 = time.perf_counter()
        tracks = health_accuracy.tracks(est, plan, snaps)
        acc = health_accuracy.accuracy(est, tracks)
        print(f"\n== {item} m = {est.m} ({time.perf_counter() - t1:.1f} s); G_y {ranks(est)}")
        print(acc.report())
        print(fleet_average(est, tracks, args.flights))


if __name__ == "__main__":
    main()
