"""Estimated health trends of a simulated fleet against the simulator's truth, per design.

Simulates the demo fleet (``app.services.demo_fleet``: seed, size, configuration) or a
smaller one, runs the pipeline's snapshot filter over every engine's take-off and cruise
snapshots exactly as after an upload (``pipeline.run_filters`` through
``app.services.health_accuracy``) and prints, per health parameter and design: bias and RMS
of h_hat - h against the plan's true health, the filter's own mean 1-sigma, the error at each
engine's last record and the fleet-average deterioration slope estimated vs true. Also prints
the rank of G_y at cruise alone, take-off alone, and both stacked (what a snapshot filter over
both phases can observe).

    /work/venv/bin/python bench/bench_health_accuracy.py                 # the demo fleet
    /work/venv/bin/python bench/bench_health_accuracy.py --aircraft 4 --flights 200
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import _common  # noqa: F401  (import path)
import numpy as np

from app.engine_cache import engine_schedule
from app.services import demo_fleet, health_accuracy, pipeline
from app.services.models_designs import design_step
from estimation.engine.fleet import fleet_snapshots, plan_fleet
from estimation.model import LinearModel

DESIGNS = (("subset", 10), ("subset", 9), ("subset", 8), ("svd", 9), ("svd", 8), ("svd", 6),
           ("optimal", 8))


# A direction of health counts as observable in one record when a 1 % shift along it moves the
# sensors by at least 0.1 noise sigma (G_y is scaled by each sensor's noise).
OBSERVABLE = 0.1


def estimator(sched, method: str, m: int) -> pipeline.SnapshotEstimator:
    p = demo_fleet.DESIGN_POINT
    model = sched.model_at(p["alt"], p["mach"], p["power"])
    sensors = [n for n in model.sensor_names if n != "Wf"]
    result = design_step(model, demo_fleet.design_spec(method, m, sensors))
    embedded = LinearModel.from_dict(result["model"])
    return pipeline.build_estimator(
        0, embedded, result, pipeline.engine_schedule_for(embedded, sched)
    )


def ranks(est: pipeline.SnapshotEstimator) -> str:
    """Singular values / rank of G_y (noise-scaled) at cruise, take-off, and both stacked."""
    cruise = np.array([[35000.0, 0.8, 0.0, 80.0]])
    takeoff = np.array([[0.0, 0.2, 15.0, 100.0]])
    out = []
    stacked = []
    for name, c in (("cruise", cruise), ("takeoff", takeoff)):
        g = est.schedule(c)
        noise = est.noise_std if g.noise_std is None else np.sqrt(
            g.noise_std[0] ** 2 + pipeline.MODEL_ERROR**2)
        A = g.G_y[0] / noise[:, None]
        stacked.append(A)
        sv = np.linalg.svd(A, compute_uv=False)
        out.append(f"{name}: rank {int(np.sum(sv > OBSERVABLE))}, smallest sv {sv[-1]:.3g}")
    A = np.vstack(stacked)
    sv = np.linalg.svd(A, compute_uv=False)
    out.append(f"stacked: rank {int(np.sum(sv > OBSERVABLE))}, "
               f"singular values {np.array2string(sv, precision=3)}")
    return "; ".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = demo_fleet.DemoSize()
    ap.add_argument("--aircraft", type=int, default=default.aircraft)
    ap.add_argument("--flights", type=int, default=default.flights)
    ap.add_argument("--seed", type=int, default=demo_fleet.SEED)
    ap.add_argument("--designs", default=",".join(f"{a}:{m}" for a, m in DESIGNS))
    ap.add_argument("--cache", type=Path, default=Path("/tmp/fh/cache"))
    args = ap.parse_args()

    sched = engine_schedule(args.cache)
    size = demo_fleet.DemoSize(aircraft=args.aircraft, flights=args.flights)
    plan_rng, snap_rng = np.random.default_rng(args.seed).spawn(2)
    t0 = time.perf_counter()
    plan = plan_fleet(demo_fleet.fleet_config(size), plan_rng)
    snaps = fleet_snapshots(plan, snap_rng)
    print(f"fleet: {args.aircraft} aircraft, {len(plan.esns)} engines, {args.flights} flights, "
          f"seed {args.seed}, {len(plan.faults)} faults; simulated in "
          f"{time.perf_counter() - t0:.1f} s")
    for item in args.designs.split(","):
        method, m = item.split(":")
        try:
            est = estimator(sched, method, int(m))
        except Exception as exc:  # an unobservable choice
            print(f"\n== {method} m = {m}: design failed ({exc})")
            continue
        t1 = time.perf_counter()
        acc = health_accuracy.accuracy(est, health_accuracy.tracks(est, plan, snaps))
        print(f"\n== {method} m = {est.m} ({time.perf_counter() - t1:.1f} s); G_y {ranks(est)}")
        print(acc.report())


if __name__ == "__main__":
    main()
