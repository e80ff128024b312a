"""Speed of closed-loop transient flights and of the fleet simulator.

Targets (issue 3): a 2500 s closed-loop flight at 15 ms <= 5 s for one engine;
a batch of engines simulated together much faster per engine. Measured in the
same run: one engine against a batch (per-engine time and ratio), the
default one-pass gas path against the gas path converged at every stage (the
peer), and the batched steady-state snapshots of a fleet.

By default a 300 s slice of seed 001's flight (ground idle, slam to take-off,
take-off, the first 50 s of climb: the busiest part) is simulated and the
figures are scaled to 2500 s; ``--full`` runs the whole flight (minutes).

    /work/venv/bin/python bench/bench_simulate.py [--full] [--batch 64] [--seconds 300]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from estimation.engine.fleet import (  # noqa: E402
    FleetConfig,
    engine_noise_std,
    fleet_snapshots,
    plan_fleet,
)
from estimation.engine.flight import (  # noqa: E402
    DURATION_S,
    flight_profile,
    random_parameters,
    seed001_parameters,
)
from estimation.engine.transient import simulate  # noqa: E402

TARGET_ONE_ENGINE_S = 5.0


def run(n: int, seconds: float, mode: str, seed: int = 0) -> float:
    """Wall time [s] of a closed-loop flight of n engines (random flights, health, noise)."""
    rng = np.random.default_rng(seed)
    params = seed001_parameters(1) if n == 1 else random_parameters(n, rng)
    health = np.zeros((n, 13))
    health[:, :10] = rng.uniform(-3.0, 0.0, (n, 10)) * np.sign(
        [1, 1, 1, 1, 1, 1, 1, -1, 1, -1])
    health[:, 10:] = rng.uniform(-2.0, 2.0, (n, 3))
    t0 = time.perf_counter()
    simulate(flight_profile(params), seconds, health=health, noise_std=engine_noise_std(),
             rng=rng, record_every=67, gas_path_solution=mode)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="simulate the whole 2500 s flight")
    ap.add_argument("--seconds", type=float, default=300.0, help="slice length [s]")
    ap.add_argument("--batch", type=int, default=64, help="engines in the batch")
    ap.add_argument("--peer-seconds", type=float, default=30.0,
                    help="slice for the converged-gas-path peer [s]")
    args = ap.parse_args()
    seconds = DURATION_S if args.full else args.seconds
    scale = DURATION_S / seconds
    engine_noise_std()  # warm the caches (sea-level line, ratio-unit schedule)
    simulate(flight_profile(), 0.1)

    print(f"closed-loop flight, dt = 15 ms, {seconds:g} s simulated"
          + ("" if args.full else f", scaled x{scale:g} to {DURATION_S:g} s"))
    one = run(1, seconds, "one_pass") * scale
    verdict = "PASS" if one <= TARGET_ONE_ENGINE_S else "FAIL"
    print(f"  one engine                     {one:9.1f} s per flight   "
          f"target <= {TARGET_ONE_ENGINE_S:g} s: {verdict}")
    batch = run(args.batch, seconds, "one_pass") * scale
    per = batch / args.batch
    print(f"  batch of {args.batch:<4d} engines          {batch:9.1f} s per flight, "
          f"{per:.2f} s per engine ({one / per:.1f}x faster per engine than one alone)")

    peer_scale = DURATION_S / args.peer_seconds
    conv = run(1, args.peer_seconds, "converged") * peer_scale
    fast = run(1, args.peer_seconds, "one_pass") * peer_scale
    print(f"  peer, same {args.peer_seconds:g} s slice, one engine: converged gas path "
          f"{conv:.1f} s vs one-pass {fast:.1f} s per flight ({conv / fast:.2f}x)")

    cfg = FleetConfig(n_aircraft=50, n_flights=20)
    plan = plan_fleet(cfg, np.random.default_rng(1))
    t0 = time.perf_counter()
    snaps = fleet_snapshots(plan, np.random.default_rng(2))
    el = time.perf_counter() - t0
    print(f"fleet snapshots: {snaps.recorded_at.size} snapshots ({cfg.n_aircraft} aircraft x "
          f"{cfg.positions} engines x {cfg.n_flights} flights x 3 phases) in {el:.2f} s, "
          f"{snaps.recorded_at.size / el:.0f} snapshots/s")


if __name__ == "__main__":
    main()
