"""The nominal trim table against the exact steady-state solve, over the engine's envelope.

The pipeline's residuals are taken against the nominal engine's trims at each record's
condition; ``estimation.engine.trim_table`` interpolates them from a dense table solved once
instead of solving each record. This bench solves the table (timed), draws random conditions
uniformly over the envelope (altitude, Mach, dTamb, power) and over the simulated fleet's
take-off and cruise records, and prints per sensor the interpolation error's maximum and RMS
in percent of trim and in sensor-noise sigmas (``engine_noise_std``), the actuators' in points
of stroke, and the cost per record of the table against the exact solve.

Target (issue 17): max below 0.05 % of trim or below 0.1 sigma for every sensor.

    OMP_NUM_THREADS=1 .venv/bin/python bench/bench_trim_table.py [--points 20000]
"""

from __future__ import annotations

import argparse
import time

import _common  # noqa: F401  (pins BLAS threads)
import numpy as np
from _common import load_line

from estimation.engine.fleet import engine_noise_std
from estimation.engine.sensors import SENSOR_NAMES
from estimation.engine.steady import ENVELOPE, steady_state
from estimation.engine.trim_table import TRIM_AXIS_NAMES, TRIM_NAMES, build_trim_table


def exact(conditions: np.ndarray) -> np.ndarray:
    out = []
    for s in range(0, len(conditions), 4096):
        c = conditions[s: s + 4096]
        ss = steady_state(c[:, :3], power=c[:, 3])
        out.append(np.concatenate([ss.sensors, ss.u[:, 1:]], axis=1))
    return np.concatenate(out)


def fleet_conditions(n: int, rng: np.random.Generator) -> np.ndarray:
    """Take-off and cruise conditions as the fleet simulator draws them
    (``estimation.engine.flight``): field elevation, dTamb, power, cruise level and Mach."""
    half = n // 2
    takeoff = np.column_stack([np.minimum(rng.exponential(800.0, half), 5000.0),
                               rng.uniform(0.0, 0.25, half),
                               np.clip(rng.normal(0.0, 8.0, half), -25.0, 25.0),
                               rng.uniform(90.0, 100.0, half)])
    cruise = np.column_stack([rng.choice(np.arange(31000.0, 39001.0, 2000.0), n - half),
                              rng.uniform(0.74, 0.82, n - half),
                              np.clip(rng.normal(0.0, 8.0, n - half), -25.0, 25.0),
                              rng.uniform(75.0, 85.0, n - half)])
    return np.concatenate([takeoff, cruise])


def report(label: str, approx: np.ndarray, truth: np.ndarray) -> bool:
    sigma = engine_noise_std()
    print(f"{label}: {len(truth)} conditions")
    print(f"  {'signal':<6} {'max %':>8} {'RMS %':>8} {'max sigma':>10} {'RMS sigma':>10}")
    ok = True
    for j, name in enumerate(TRIM_NAMES):
        err = approx[:, j] - truth[:, j]
        if name not in SENSOR_NAMES:
            print(f"  {name:<6} max {np.abs(err).max():.4f}, RMS {np.sqrt(np.mean(err**2)):.4f} "
                  "points of stroke")
            continue
        pct = 100 * err / np.abs(truth[:, j])
        sig = err / sigma[SENSOR_NAMES.index(name)]
        mp, ms = np.abs(pct).max(), np.abs(sig).max()
        ok &= bool(mp < 0.05 or ms < 0.1)
        print(f"  {name:<6} {mp:8.4f} {np.sqrt(np.mean(pct**2)):8.4f} {ms:10.3f} "
              f"{np.sqrt(np.mean(sig**2)):10.3f}")
    return ok


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=20_000)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    print(load_line())
    t0 = time.perf_counter()
    table = build_trim_table()
    shape = " x ".join(f"{len(a)} {n}" for a, n in zip(table.axes, TRIM_AXIS_NAMES, strict=True))
    print(f"table {shape} = {table.corrected[..., 0].size} points solved in "
          f"{time.perf_counter() - t0:.1f} s")
    rng = np.random.default_rng(args.seed)
    envelope = np.column_stack([rng.uniform(*ENVELOPE[n], args.points) for n in TRIM_AXIS_NAMES])
    ok = True
    for label, c in (("envelope (uniform)", envelope),
                     ("fleet take-off and cruise", fleet_conditions(args.points, rng))):
        t0 = time.process_time()
        truth = exact(c)
        t_exact = time.process_time() - t0
        t0 = time.process_time()
        approx = table.trims_at(c)
        t_table = time.process_time() - t0
        ok &= report(label, approx, truth)
        print(f"  CPU per record: exact solve {1e6 * t_exact / len(c):.1f} us, table "
              f"{1e6 * t_table / len(c):.2f} us ({t_exact / t_table:.0f} x)")
    print(f"target: every sensor within 0.05 % or 0.1 sigma -> {'PASS' if ok else 'FAIL'}")


if __name__ == "__main__":
    main()
