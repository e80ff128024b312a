"""Speed of closed-loop transient flights and of the fleet simulator.

Targets (issue 3): a 2500 s closed-loop flight at 15 ms <= 5 s for one engine;
a batch of engines simulated together much faster per engine. Measured in the
same run, each as wall time and as CPU time of this process (the CPU figure is
the one to compare on a shared, loaded machine):

- one engine on the scalar path (the default for B = 1: the same cycle and
  control law on Python floats, ``transient_one.py``);
- one engine on the numpy path (``scalar_path=False``: the batch code with
  B = 1, which is how one engine ran before the scalar path existed), the peer;
- a batch of engines on the numpy path, per engine;
- one engine with the gas path converged at every stage (the other peer);
- the batched steady-state snapshots of a fleet.

By default a 300 s slice of seed 001's flight (ground idle, slam to take-off,
take-off, the first 50 s of climb: the busiest part) is simulated and the
figures are scaled to 2500 s (the printed figures say so); the peers use a 30 s
slice from the start of the flight. ``--full`` runs the whole flight.

    /work/venv/bin/python bench/bench_simulate.py [--full] [--batch 64] [--seconds 300]

Figures measured 2026-11-22 (2 cores shared with other jobs at load 5-10, so
wall times are 2-3x the CPU times; CPU seconds per 2500 s flight, scaled from
the 300 s and 30 s slices; two runs each):

    one engine, numpy path (before)   214-228 s CPU (800-850 s wall; 1.3 ms CPU per step)
    one engine, scalar path (after)   12.7-18.4 s CPU (40 s wall; 76-110 us CPU per step)
                                      -> 15x less CPU than before; target 5 s: FAIL, 2.5-3.7x over
    batch of 64, per engine           4.4-4.6 s CPU (19-20 s wall), 3-4x less than one alone
    batch of 64, per engine, before   5.5 s CPU vs 4.9 s after on the same 60 s slice (the
                                      batch path skips unused stations now; trajectories
                                      bit-identical to before)
    converged gas path, scalar        1.25x the one-pass cost

Why one engine is still over 5 s: the target is 30 us per 15 ms step; one
gas-path evaluation on floats costs about 30 us (CPython arithmetic on about
400 floats and 40 calls), and a step needs two plus, with sensor noise, about
one full solve in four (2.5-3 evaluations per step).
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


def run(n: int, seconds: float, mode: str, seed: int = 0,
        scalar_path: bool = True) -> tuple[float, float]:
    """Wall and CPU time [s] of a closed-loop flight of n engines (random flights, health,
    noise)."""
    rng = np.random.default_rng(seed)
    params = seed001_parameters(1) if n == 1 else random_parameters(n, rng)
    health = np.zeros((n, 13))
    health[:, :10] = rng.uniform(-3.0, 0.0, (n, 10)) * np.sign(
        [1, 1, 1, 1, 1, 1, 1, -1, 1, -1])
    health[:, 10:] = rng.uniform(-2.0, 2.0, (n, 3))
    t0, c0 = time.perf_counter(), time.process_time()
    simulate(flight_profile(params), seconds, health=health, noise_std=engine_noise_std(),
             rng=rng, record_every=67, gas_path_solution=mode, scalar_path=scalar_path)
    return time.perf_counter() - t0, time.process_time() - c0


def _fmt(label: str, wall: float, cpu: float, extra: str = "") -> str:
    return f"  {label:<40s} {wall:8.1f} s wall {cpu:8.1f} s CPU per flight{extra}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="simulate the whole 2500 s flight")
    ap.add_argument("--seconds", type=float, default=300.0, help="slice length [s]")
    ap.add_argument("--batch", type=int, default=64, help="engines in the batch")
    ap.add_argument("--peer-seconds", type=float, default=30.0,
                    help="slice for the numpy-path and converged peers [s]")
    args = ap.parse_args()
    seconds = DURATION_S if args.full else args.seconds
    scale = DURATION_S / seconds
    engine_noise_std()  # warm the caches (sea-level line, ratio-unit schedule)
    simulate(flight_profile(), 0.1)
    simulate(flight_profile(), 0.1, scalar_path=False)

    print(f"closed-loop flight, dt = 15 ms, {seconds:g} s simulated"
          + ("" if args.full else f", scaled x{scale:g} to {DURATION_S:g} s"))
    wall, cpu = (v * scale for v in run(1, seconds, "one_pass"))
    verdict = "PASS" if min(wall, cpu) <= TARGET_ONE_ENGINE_S else "FAIL"
    steps = DURATION_S / 0.015
    print(_fmt("one engine, scalar path", wall, cpu,
               f"  ({cpu / steps * 1e6:.0f} us CPU per step)  "
               f"target <= {TARGET_ONE_ENGINE_S:g} s: {verdict}"))
    bwall, bcpu = (v * scale for v in run(args.batch, seconds, "one_pass"))
    print(_fmt(f"batch of {args.batch} engines, per engine", bwall / args.batch,
               bcpu / args.batch,
               f"  ({bcpu:.0f} s CPU for the batch; {cpu / (bcpu / args.batch):.1f}x "
               f"less CPU per engine than one engine alone)"))

    peer_scale = DURATION_S / args.peer_seconds
    pw, pc = (v * peer_scale for v in run(1, args.peer_seconds, "one_pass", scalar_path=False))
    sw, sc = (v * peer_scale for v in run(1, args.peer_seconds, "one_pass"))
    print(f"peers, same {args.peer_seconds:g} s slice (flight start), one engine, scaled "
          f"x{peer_scale:g}:")
    print(_fmt("numpy path (one engine before)", pw, pc))
    print(_fmt("scalar path", sw, sc, f"  ({pc / sc:.1f}x faster in CPU)"))
    cw, cc = (v * peer_scale for v in run(1, args.peer_seconds, "converged"))
    print(_fmt("scalar path, converged gas path", cw, cc, f"  ({cc / sc:.2f}x one-pass)"))

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
