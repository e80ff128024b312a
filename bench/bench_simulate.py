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
- small batches (2 to ``FLOATS_BATCH`` engines), engine by engine on floats (the
  default) against the numpy batch, per engine;
- one engine with the gas path converged at every stage (the other peer);
- the batched steady-state snapshots of a fleet.

By default a 300 s slice of seed 001's flight (ground idle, slam to take-off,
take-off, the first 50 s of climb: the busiest part) is simulated and the
figures are scaled to 2500 s (the printed figures say so); the peers use a 30 s
slice from the start of the flight. ``--full`` runs the whole flight.

    .venv/bin/python bench/bench_simulate.py [--full] [--batch 64] [--seconds 300]

Figures measured 2026-11-22 (2 cores shared with other jobs at load 3-5; CPU
seconds of this process; the old and new code back to back, same conditions,
``run(1, 2500, "one_pass")`` on the whole flight, pairs):

    one engine, numpy path (first version)   214-228 s CPU per flight
    one engine, scalar path, before          10.5-11.4 s CPU (whole flight; 11.5 s scaled from
                                             the 300 s slice; 2.1-3.0 gas-path evaluations
                                             per step, 26 % full solves at ground idle)
    one engine, scalar path, after           7.1-7.3 s CPU (two pairs against 9.9 and 11.2 s
                                             before; 7.3 s scaled from the 300 s slice;
                                             1.08-1.11 evaluations per step, full solves in
                                             0.8 % of stages, at the slam only)
                                             -> 1.4-1.6x less CPU in each pair;
                                             target 5 s: FAIL, 1.4x over
    batch of 64, per engine, 60 s slice      4.9 s before, 1.55 s after (3.1x)
    converged gas path, scalar, 300 s slice  19.7 s before, 18.6 s after

What changed: both stages' gas-path unknowns are predicted through dz/dv in
the states and commands (noise moves the commands, so the old extrapolation
in time missed by the noise and fell back to full solves), and the first
stage of an unrecorded step is the last second stage moved through dk/dv, so
a step costs one gas-path evaluation. Accuracy (tests/estimation/engine/test_transient_one.py):
against the gas path converged at every stage, every sensor stays within 0.07
noise standard deviations over seed 001's busiest 300 s with noise, 0.06 through
a slam; halving the step moves the sensors by up to 0.24 std there (1.25 std
at a slam, mostly the controller's sample rate), and the one-pass run is no
further from the halved step than the converged run.

Then the loop around the gas path (same conditions, three pairs of the whole
flight, old and new back to back, the same trajectory to the last bit):

    one engine, scalar path, before          6.82-6.88 s CPU (41 us per step)
    one engine, scalar path, after           4.91-5.26 s CPU (29-32 us per step)
                                             -> 1.3-1.4x less CPU in each pair;
                                             target 5 s: at the target, not
                                             reliably under (1 pair of 3 under)

What changed: the control law runs as ``controller.scalar_control_law`` (the
formulas of ``control_step`` in the same order, with the design, RU line, gains
and filter coefficient looked up once: 1.8 us a sample against 4.6 us), the
flight condition is recomputed only when altitude, Mach or dTamb move (not on
the ground or in cruise), the noise block is converted to lists once per block,
the controller's four sensors are kept as floats instead of a list of 12 per
step, and the predictions, chord and stage sums are written out row by row.

What is left (the "budget" lines below): one gas-path evaluation on floats is
14-21 us of the 30 us a step may cost (about 1.1 evaluations per step), so the
gas path itself (turbofan.py and its components on floats) is where the next
factor must come from; the loop's own bookkeeping is now a few us per step.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import _common  # noqa: F401  (pins BLAS threads)
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
from estimation.engine.transient import FLOATS_BATCH, simulate  # noqa: E402

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


def budget(n: int = 20000) -> None:
    """CPU per call of what one scalar step is made of (one engine, 50 % power, SLS)."""
    from estimation.engine.atmosphere import LBM, RANKINE, flight_condition
    from estimation.engine.controller import (
        DEFAULT_GAINS,
        ControllerState,
        control_step,
        initial_state,
        scalar_control_law,
    )
    from estimation.engine.design import engine_design
    from estimation.engine.steady import steady_state
    from estimation.engine.turbofan import Operating, gas_path_columns
    from estimation.engine.xp import SCALAR

    d = engine_design()
    ss = steady_state(np.zeros(3), power=50.0)
    x, u, z = (a.reshape(-1).tolist() for a in (ss.x, ss.u, ss.inner))
    y = ss.sensors.reshape(-1).tolist()
    fc: Any = flight_condition(0.0, 0.0, 0.0, SCALAR)  # floats in the fields
    op = Operating(x[0], x[1], x[2] / RANKINE, x[3] / RANKINE, u[0] * LBM, u[1], u[2], fc,
                   None)  # type: ignore[arg-type]
    hs = [0.0] * 13
    nf, nc, t24, ps30 = (np.array([v]) for v in (y[0], y[1], y[2], y[5]))
    c = initial_state(np.array([u[0]]), nf, nc, t24, ps30, design=d)
    c1 = ControllerState(float(c.integrator[0]), c.sensed[0].tolist())  # type: ignore[arg-type]
    law = scalar_control_law(0.015, DEFAULT_GAINS, d)
    generic_law: Any = control_step  # floats where the annotations say arrays
    i1, s1 = float(c.integrator[0]), c.sensed[0].tolist()
    items = {
        "gas path, step stations": lambda: gas_path_columns(op, z, hs, d, True, False, SCALAR,
                                                            False),
        "gas path, all stations": lambda: gas_path_columns(op, z, hs, d, True, False, SCALAR),
        "control law, control_step on floats": lambda: generic_law(
            c1, 50.0, 0.0, fc.theta, fc.delta, y[0], y[1], y[2], y[5], 0.015, DEFAULT_GAINS,
            d, SCALAR),
        "control law, scalar_control_law": lambda: law(
            i1, s1, 50.0, 0.0, fc.theta, fc.delta, y[0], y[1], y[2], y[5]),
        "flight condition": lambda: flight_condition(100.0, 0.1, 0.0, SCALAR),
    }
    print("budget of a scalar step (CPU per call; a 2500 s flight at 15 ms allows 30 us "
          "per step):")
    for name, fun in items.items():
        c0 = time.process_time()
        for _ in range(n):
            fun()
        print(f"  {name:<40s} {(time.process_time() - c0) / n * 1e6:8.1f} us")


def _fmt(label: str, wall: float, cpu: float, extra: str = "") -> str:
    return f"  {label:<40s} {wall:8.1f} s wall {cpu:8.1f} s CPU per flight{extra}"


def main() -> None:
    print(_common.load_line())
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
    print(f"small batches, same slice, per engine (up to {FLOATS_BATCH} engines run engine by "
          f"engine on floats by default; the peer is the numpy batch):")
    for n in sorted({2, FLOATS_BATCH // 2, FLOATS_BATCH}):
        nw, nc = (v * peer_scale / n for v in run(n, args.peer_seconds, "one_pass",
                                                  scalar_path=False))
        fw, fc = (v * peer_scale / n for v in run(n, args.peer_seconds, "one_pass"))
        print(_fmt(f"{n} engines, numpy batch", nw, nc))
        print(_fmt(f"{n} engines, floats", fw, fc, f"  ({nc / fc:.1f}x less CPU)"))

    budget()

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
