"""A simulated engine with snapshots and two whole-flight recordings, for the steady-window
tests: one engine of a seeded fleet (deterioration, actuator biases, no faults, no removals)
flies ``FLIGHTS`` flights as snapshots (``fleet_snapshots``), then two more flights recorded at
20 Hz by the closed-loop transient simulator (``transient.simulate``), the second with a
seed 002 library fault injected. The recorded flights follow ``flight.py``'s profile shape
(ground idle, take-off, initial climb, climb in two legs, level-off, cruise) on a compressed
time axis (980 s instead of 2500 s), so both fit in one batched simulation of about a minute.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pyarrow as pa

from app.services.demo.simulation_files import snapshot_table, stream_table
from estimation import isolation
from estimation.engine.fleet import (
    FleetConfig,
    FleetPlan,
    StreamFlight,
    engine_noise_std,
    fleet_snapshots,
    plan_fleet,
    stream_step,
)
from estimation.engine.flight import FlightProfile
from estimation.engine.health import HEALTH_NAMES
from estimation.engine.transient import simulate

FLIGHTS = 150
RATE_HZ = 20.0
FAULT = "HPC"
SEED = 5
# Breakpoints [s]: idle, throttle up, take-off roll, initial climb to +2000 ft, climb power,
# climb to 15,000 ft, climb to cruise level, level-off, cruise.
TIMES_S = np.array([0.0, 30.0, 36.0, 70.0, 150.0, 160.0, 460.0, 760.0, 790.0, 980.0])


class Simulated(NamedTuple):
    plan: FleetPlan
    snapshots: pa.Table
    flights: tuple[StreamFlight, StreamFlight]  # healthy, faulted
    fault_shift: np.ndarray  # [13] percent, added in the second flight


def _profile(plan: FleetPlan) -> FlightProfile:
    p = plan.flights[-1][0].params
    f = float(np.asarray(p.field_alt_ft).ravel()[0])
    cruise_alt = max(float(np.asarray(p.cruise_alt_ft).ravel()[0]), f + 20000.0)
    cruise_mach = float(np.asarray(p.cruise_mach).ravel()[0])
    to, cl, cr = (float(np.asarray(v).ravel()[0]) for v in
                  (p.takeoff_power_pct, p.climb_power_pct, p.cruise_power_pct))
    alt = [f, f, f, f, f + 2000, f + 2000, max(15000.0, f + 5000), cruise_alt, cruise_alt,
           cruise_alt]
    mach = [0, 0, 0, 0.25, 0.30, 0.30, 0.50, min(cruise_mach, 0.80), cruise_mach, cruise_mach]
    power = [0, 0, to, to, to, cl, cl, cl, cr, cr]
    two = np.ones((2, 1))
    return FlightProfile(TIMES_S.copy(), two * np.array(alt), two * np.array(mach),
                         two * np.array(power),
                         np.full(2, float(np.asarray(p.dtamb_k).ravel()[0])))


def simulate_engine() -> Simulated:
    config = FleetConfig(
        n_aircraft=1, n_flights=FLIGHTS + 2, positions=1, spares=0, flights_per_day=2.0,
        fault_rate=0.0, removal_rate=0.0, exchange_rate=0.0, wash_interval=1e5,
        initial_cycles_max=2000.0,
    )
    plan = plan_fleet(config, np.random.default_rng(SEED))
    snaps = snapshot_table(fleet_snapshots(plan, np.random.default_rng(SEED + 1)))
    cut = plan.flights[FLIGHTS][0].started_at
    snaps = snaps.filter(pa.compute.less(
        snaps["recorded_at"], pa.scalar(int(cut), pa.timestamp("s", tz="UTC"))))
    library = {f.name: f for f in isolation.default_faults()}
    shift = isolation.signature_matrix([library[FAULT]], HEALTH_NAMES)[:, 0]
    engine = int(plan.installed[FLIGHTS, 0, 0])
    h = np.stack([plan.health[FLIGHTS, engine], plan.health[FLIGHTS + 1, engine] + shift])
    dt, every = stream_step(RATE_HZ)
    res = simulate(_profile(plan), float(TIMES_S[-1]), health=h, dt=dt, record_every=every,
                   noise_std=engine_noise_std(), rng=np.random.default_rng(SEED + 2))
    flights = []
    for k, j in enumerate((FLIGHTS, FLIGHTS + 1)):
        rec = plan.flights[j][0]
        act = res.u[:, k].copy()
        act[:, 0] = res.measured[:, k, -1]
        flights.append(StreamFlight(
            rec.tail, 1, rec.flight_id, plan.esns[engine], rec.started_at, res.time_s,
            res.condition.alt_ft[:, k], res.condition.mach[:, k], res.condition.dtamb_k[:, k],
            res.condition.power_pct[:, k], act, res.measured[:, k], h[k]))
    return Simulated(plan, snaps, (flights[0], flights[1]), shift)


def stream_csv(flight: StreamFlight) -> bytes:
    import pyarrow.csv as pacsv

    sink = pa.BufferOutputStream()
    pacsv.write_csv(stream_table(flight), sink)
    return sink.getvalue().to_pybytes()
