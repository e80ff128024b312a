"""Snapshot filter throughput on the product's path: the demo's active design, per-engine
operating conditions, against the minimal numpy loop that computes the same estimates.

Data: ``fleethealth simulate --mode snapshot``'s records of the demo fleet
(``estimation.engine.fleet``; take-off and cruise, every engine at its own altitude, Mach,
ambient temperature and power). Each bench engine flies its own sequence of records drawn from
that pool, so no two engines share an operating condition at a snapshot.

The product's path, timed in two parts:

- ``schedule``: the estimator's gains and trims at every record's condition
  (``SnapshotEstimator.schedule``: the dense trim table and the interpolated gains) and the
  sensor deviations (``estimation.snapshot.snapshot_deviation``);
- ``filter``: ``estimation.snapshot.snapshot_filter`` over all engines at once, with the
  per-record gains G_y [E, S, ny, p], one worker thread (and, beside it, the product's
  default of one thread per core).

The bound, in the same run on the same arrays: the minimal numpy loop of the same algorithm
(predict, then one scalar Kalman update per sensor, each vectorised over the engines, the
tuner-space sensor matrix H = G_y V*^+ formed per snapshot), and the matrix-form update with
``numpy.linalg.solve``. All three give the same estimates (the largest difference is printed).

BLAS and OpenMP run one thread (``bench/_common.py``, before numpy loads); the load is printed
first and last. Engines 10 / 1,000 / 10,000 / 100,000, with fewer snapshots each as the fleet
grows (about 0.4M records at 100,000 engines).

    .venv/bin/python bench/bench_snapshot_filter.py [--sizes 10x2000,1000x200,10000x40,100000x4]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import _common
import numpy as np

from app.engine_cache import engine_schedule, engine_trim_table
from app.services.demo import fleet as demo
from app.services.snapshots import estimator
from estimation.engine.fleet import fleet_snapshots, plan_fleet
from estimation.engine.sensors import SENSOR_NAMES
from estimation.engine.turbofan import INPUT_NAMES
from estimation.snapshot import SnapshotState, snapshot_deviation, snapshot_filter

SIZES = "10x2000,1000x200,10000x40,100000x4"
TARGET = 1e6  # engine-snapshots per second through the filter


def record_pool(est, aircraft: int, flights: int, seed: int) -> dict[str, np.ndarray]:
    """The simulated demo fleet's take-off and cruise records: conditions [N, 4], sensors
    [N, ny] and inputs [N, nu] in the design's order."""
    size = demo.DemoSize(aircraft=aircraft, flights=flights, calibrate=False)
    plan_rng, snap_rng = np.random.default_rng(seed).spawn(2)
    snaps = fleet_snapshots(plan_fleet(demo.fleet_config(size), plan_rng), snap_rng)
    keep = np.isin(snaps.phase.astype(str), ["takeoff", "cruise"])
    cond = np.stack([snaps.alt_ft, snaps.mach, snaps.dtamb_k, snaps.power_pct], axis=1)[keep]
    sensors = [n.lower() for n in SENSOR_NAMES]
    inputs = [n.lower() for n in INPUT_NAMES]
    return {"cond": cond,
            "sensors": snaps.sensors[keep][:, [sensors.index(c) for c in est.sensor_columns]],
            "inputs": snaps.actuators[keep][:, [inputs.index(c) for c in est.input_columns]]}


def minimal_loop(q0, P0, dy, H_of, Qq, var, scale, Vp):
    """The same filter in the plainest numpy: per snapshot predict, then one scalar update per
    sensor over all engines; the same outputs as the product's (estimate, innovation, health
    1-sigma). q [E, m], P [E, m, m]; H_of(j) -> [E, ny, m]."""
    q, P = q0.copy(), P0.copy()
    E, S, ny = dy.shape
    out = np.empty((E, S, q.shape[1]))
    innov = np.empty((E, S, ny))
    h_std = np.empty((E, S, Vp.shape[0]))
    for j in range(S):
        P += scale[:, j, None, None] * Qq
        H = H_of(j)
        innov[:, j] = dy[:, j] - np.einsum("enm,em->en", H, q)
        for i in range(ny):
            h = H[:, i]
            Ph = np.einsum("emn,en->em", P, h)
            s = np.einsum("em,em->e", h, Ph) + var[:, j, i]
            k = Ph / s[:, None]
            r = dy[:, j, i] - np.einsum("em,em->e", h, q)
            q += k * r[:, None]
            P -= k[:, :, None] * Ph[:, None, :]
        out[:, j] = q
        h_std[:, j] = np.sqrt(np.einsum("pa,eab,pb->ep", Vp, P, Vp))
    return out, innov, h_std


def matrix_form(q0, P0, dy, H_of, Qq, var, scale):
    """The matrix-form update per snapshot: K = P H^T (H P H^T + R)^-1 by solve."""
    q, P = q0.copy(), P0.copy()
    E, S, ny = dy.shape
    out = np.empty((E, S, q.shape[1]))
    for j in range(S):
        P = P + scale[:, j, None, None] * Qq
        H = H_of(j)
        PHt = P @ np.swapaxes(H, 1, 2)
        Sm = H @ PHt + var[:, j, :, None] * np.eye(ny)
        K = np.swapaxes(np.linalg.solve(Sm, np.swapaxes(PHt, 1, 2)), 1, 2)
        q = q + np.einsum("emn,en->em", K, dy[:, j] - np.einsum("enm,em->en", H, q))
        P = P - K @ np.swapaxes(PHt, 1, 2)
        out[:, j] = q
    return out


def run_size(est, pool, E: int, S: int, rng: np.random.Generator) -> float:
    """Time the product's path and the bounds on E engines x S snapshots; the filter's rate."""
    pick = rng.integers(0, pool["cond"].shape[0], size=E * S)
    cond = pool["cond"][pick]
    t0 = time.perf_counter()
    g = est.schedule(cond)
    u_dev = 100.0 * (pool["inputs"][pick] - g.u_trim) / g.u_trim
    dy = snapshot_deviation(pool["sensors"][pick], g.y_trim, g.G_u, u_dev)
    t_schedule = time.perf_counter() - t0
    ny, p = g.G_y.shape[-2:]
    dy = dy.reshape(E, S, ny)
    G = np.asarray(g.G_y).reshape(E, S, ny, p)
    noise = np.sqrt(np.asarray(g.noise_std) ** 2 + estimator.MODEL_ERROR**2).reshape(E, S, ny)
    scale = np.ones((E, S))
    m = est.m

    def ours(workers: int):
        state = SnapshotState.initial(E, est.P0)
        return snapshot_filter(state, dy, G, est.vstar, est.Qq, noise, scale, workers=workers)

    Vp = est.Vp
    q0 = np.zeros((E, m))
    P0 = np.broadcast_to(est.P0, (E, m, m)).copy()
    var = noise**2

    def H_of(j: int) -> np.ndarray:
        return G[:, j] @ Vp

    t_ours = _common.best_time(lambda: ours(1), repeat=2)
    t_ours_cores = _common.best_time(lambda: ours(os.cpu_count() or 1), repeat=2)
    t_min = _common.best_time(
        lambda: minimal_loop(q0, P0, dy, H_of, est.Qq, var, scale, Vp), repeat=2)
    t_mat = _common.best_time(lambda: matrix_form(q0, P0, dy, H_of, est.Qq, var, scale),
                              repeat=1)
    res = ours(1)
    q = res.q_hat
    q_min, innov_min, h_std_min = minimal_loop(q0, P0, dy, H_of, est.Qq, var, scale, Vp)
    diff_min = max(float(np.max(np.abs(a - b))) for a, b in (
        (q, q_min), (res.innovation, innov_min), (res.h_std, h_std_min)))
    diff_mat = float(np.max(np.abs(q - matrix_form(q0, P0, dy, H_of, est.Qq, var, scale))))
    n = E * S
    print(f"\n{E:,} engines x {S} snapshots ({n:,} records, {len(np.unique(pick)):,} distinct "
          f"conditions), m = {m}, {ny} sensors")
    print(f"  {'schedule':<22} {t_schedule:8.3f} s  {n / t_schedule:12,.0f} records/s  "
          "(trims, gains, deviations)")
    for name, t, note in (
        ("filter, 1 thread", t_ours, "the product"),
        (f"filter, {os.cpu_count()} threads", t_ours_cores, "the product's default"),
        ("minimal numpy loop", t_min, f"bound; max |diff| {diff_min:.1e}"),
        ("matrix-form numpy", t_mat, f"max |diff| {diff_mat:.1e}"),
    ):
        print(f"  {name:<22} {t:8.3f} s  {n / t:12,.0f} records/s  "
              f"{t / t_min:5.2f}x the bound  {note}")
    return n / t_ours


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default=SIZES, help="engines x snapshots, comma-separated")
    ap.add_argument("--aircraft", type=int, default=8)
    ap.add_argument("--flights", type=int, default=300)
    ap.add_argument("--seed", type=int, default=20260101)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/fh/cache"))
    args = ap.parse_args()
    print(_common.load_line())
    sched = engine_schedule(args.cache)
    est = demo.design_estimator(sched, *demo.ACTIVE_DESIGN,
                                trims=engine_trim_table(args.cache))
    t0 = time.perf_counter()
    pool = record_pool(est, args.aircraft, args.flights, args.seed)
    print(f"record pool: {pool['cond'].shape[0]:,} simulated take-off and cruise records of "
          f"{2 * args.aircraft} engines ({time.perf_counter() - t0:.0f} s); the demo's active "
          f"design {demo.ACTIVE_DESIGN}")
    rng = np.random.default_rng(args.seed)
    rates = {}
    for item in args.sizes.split(","):
        E, S = (int(v) for v in item.split("x"))
        rates[E] = run_size(est, pool, E, S, rng)
    print(f"\nload average at the end {os.getloadavg()[0]:.2f}")
    worst = min(rates.values())
    print(f"target >= {TARGET:,.0f} records/s through the filter (one thread): slowest size "
          f"{worst:,.0f} -> {'PASS' if worst >= TARGET else 'FAIL'}")


if __name__ == "__main__":
    main()
