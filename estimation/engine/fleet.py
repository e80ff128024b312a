"""The fleet simulator: aircraft, engines, deterioration, faults, swaps, washes, data.

Pure: the caller passes a ``np.random.Generator`` and gets arrays and records
back (files are written by ``app.services.simulate_io``). Three layers:

1. ``plan_fleet``: the fleet's history, cheap bookkeeping over flights. N
   aircraft with P engine positions fly F flights each, in rounds (every
   aircraft flies its j-th flight in round j). Every engine (installed or
   spare) has a serial number (ESN) and carries
   - manufacturing scatter: N(0, scatter_std) in the ten turbomachinery health
     parameters, fixed for life;
   - deterioration that grows with cycles (one cycle per flight), at per-engine
     rates (the mean rates times a lognormal multiplier per parameter), with
     the sign convention of ``health.py``: efficiencies and compressor flow
     capacities fall, turbine flow capacities rise; HPC and HPT dominate
     (about 3-4 % in 5,000 cycles, fan, LPC and LPT about 1-1.5 %);
   - compressor fouling on the fan, LPC and HPC that a water wash recovers in
     part (every ``wash_interval`` cycles, with scatter);
   - actuator biases of Wf, VSV and VBV, fixed per engine;
   - occasional abrupt faults from the seed 002 Table 3 library
     (``estimation.isolation.SEED_002_FAULTS``), scaled by U(0.75, 1.5);
     a faulted engine is removed within a few flights and returns from the
     shop with the fault repaired and part of its deterioration restored;
   - removals for other reasons and exchanges between aircraft, so engines
     move between tails and positions (swaps happen between rounds, and no
     position ever holds two engines at once).
2. ``fleet_snapshots``: take-off, climb and cruise snapshots of every flight,
   solved by the steady-state solver for all installed engines and phases of
   a round in one batched call, plus sensor noise (the engine's standard
   deviations, seed 001 Table 2).
3. ``stream_flights``: whole flights (the 2500 s profile of ``flight.py``)
   simulated in closed loop by ``transient.simulate``, engine-flights of all
   rounds batched together (the plan fixes every flight's health in
   advance), yielded flight by flight (a fleet's streams do not fit in
   memory at once).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from estimation.engine.flight import (
    DURATION_S,
    SNAPSHOT_PHASES,
    FlightParameters,
    flight_profile,
    random_parameters,
    snapshot_points,
)
from estimation.engine.health import HEALTH_NAMES, N_HEALTH, health_vector
from estimation.engine.sensors import noise_std
from estimation.engine.steady import steady_state
from estimation.engine.transient import DT_DEFAULT, simulate
from estimation.isolation import SEED_002_FAULTS, Fault

N_TURBO = 10
EPOCH_2026 = 1767225600.0  # 2026-01-01T00:00:00Z in seconds since 1970 (UTC)

# Mean deterioration rates, percent per 1000 cycles, in HEALTH_NAMES[:10] order
# (fan, LPC, HPC, HPT, LPT: efficiency, flow). Negative efficiency and
# compressor flow, positive turbine flow: the sign convention of health.py.
DETERIORATION_RATES = np.array(
    [-0.20, -0.25, -0.25, -0.30, -0.60, -0.75, -0.75, 0.45, -0.25, 0.20]
)
# Recoverable compressor fouling, percent per 1000 cycles (fan, LPC, HPC only).
FOULING_RATES = np.array([-0.30, -0.30, -0.25, -0.25, -0.35, -0.35, 0.0, 0.0, 0.0, 0.0])


# Deterioration direction of each turbomachinery health parameter (health.py).
DETERIORATION_SIGN = np.sign(DETERIORATION_RATES)


def seed001_degradations(n: int, rng: np.random.Generator) -> np.ndarray:
    """Seed 001 Evaluation 2: all ten health parameters shifted by U(1, 5) % [n, 13].

    "The deviation values are uniformly distributed over the range from 1 to
    5 percent"; each in its deterioration direction (efficiencies and
    compressor flows down, turbine flows up). Actuator biases are zero.
    """
    h = np.zeros((n, N_HEALTH))
    h[:, :N_TURBO] = rng.uniform(1.0, 5.0, (n, N_TURBO)) * DETERIORATION_SIGN
    return h


def seed001_actuator_biases(n: int, rng: np.random.Generator) -> np.ndarray:
    """Seed 001 Evaluation 3: healthy engines with Wf, VSV, VBV biases U(-10, 10) % [n, 13].

    The seed's biases are percent of the ground-idle command, held as offsets;
    here a bias is percent of the current command (health.py), which equals
    the seed's at ground idle and scales with the command elsewhere.
    """
    h = np.zeros((n, N_HEALTH))
    h[:, N_TURBO:] = rng.uniform(-10.0, 10.0, (n, 3))
    return h


@dataclass(frozen=True)
class FleetConfig:
    """What the fleet looks like; rates are per engine cycle (one flight).

    n_aircraft, n_flights (per aircraft), positions (engines per aircraft,
    1..4); spares: spare engines at the start; flights_per_day: the round
    spacing (24 h / flights_per_day); start_epoch_s: first round, seconds
    since 1970 UTC; initial_cycles_max: engines start with U(0, max) cycles;
    rate_spread: sigma of the lognormal per-engine rate multiplier;
    scatter_std [%]: manufacturing scatter; bias_std [%] (Wf, VSV, VBV);
    wash_interval [cycles] and wash_recovery (fraction of fouling removed);
    fault_rate, removal_rate, exchange_rate: per engine and flight;
    faulted_removal: probability per flight that a faulted engine is pulled;
    shop_rounds: rounds an engine spends in the shop; shop_restore: fraction
    of permanent deterioration a shop visit restores; noise: add sensor noise.
    """

    n_aircraft: int = 4
    n_flights: int = 10
    positions: int = 2
    spares: int | None = None
    flights_per_day: float = 4.0
    start_epoch_s: float = EPOCH_2026
    initial_cycles_max: float = 12000.0
    rate_spread: float = 0.3
    scatter_std: float = 0.4
    bias_std: tuple[float, float, float] = (0.5, 1.0, 2.0)
    wash_interval: float = 500.0
    wash_recovery: float = 0.8
    fault_rate: float = 1.0 / 1500.0
    removal_rate: float = 1.0 / 1200.0
    exchange_rate: float = 1.0 / 2000.0
    faulted_removal: float = 0.3
    shop_rounds: int = 12
    shop_restore: float = 0.6
    noise: bool = True
    faults: tuple[Fault, ...] = field(default=SEED_002_FAULTS)

    def __post_init__(self) -> None:
        if self.n_aircraft < 1 or self.n_flights < 1:
            raise ValueError("a fleet needs at least one aircraft and one flight")
        if not 1 <= self.positions <= 4:
            raise ValueError(f"positions must be 1..4, got {self.positions}")
        if self.flights_per_day <= 0 or self.flights_per_day > 12:
            raise ValueError("flights_per_day must lie in (0, 12] (flights may not overlap)")

    @property
    def n_spares(self) -> int:
        if self.spares is not None:
            return self.spares
        return max(2, int(np.ceil(0.15 * self.n_aircraft * self.positions)))


class Installation(NamedTuple):
    """An engine on a tail and position from installed_at until removed_at (s UTC; None: still)."""

    esn: str
    tail: str
    position: int
    installed_at: float
    removed_at: float | None


class FaultEvent(NamedTuple):
    """An abrupt fault: from the flight ``flight_id`` on, health shifted by ``shifts`` [%]."""

    esn: str
    flight_id: str
    tail: str
    position: int
    occurred_at: float
    fault: str
    scale: float
    shifts: dict[str, float]


class SwapEvent(NamedTuple):
    """At ``at``: ``esn_off`` leaves tail/position, ``esn_on`` takes it; reason in words."""

    at: float
    tail: str
    position: int
    esn_off: str
    esn_on: str
    reason: str


class WashEvent(NamedTuple):
    """A water wash of ``esn`` at ``at``; recovered: health recovered [%] (10 turbomachinery)."""

    esn: str
    at: float
    recovered: dict[str, float]


class FlightRecord(NamedTuple):
    """One aircraft flight: id, tail, start time [s UTC], round index, its parameters."""

    flight_id: str
    tail: str
    round: int
    started_at: float
    params: FlightParameters


class FleetPlan(NamedTuple):
    """The simulated fleet's history (the ground truth) and what the data is made of.

    esns [E]; tails [N]; flights: per round, one FlightRecord per aircraft
    (flights[j][a]); installed [F, N, P]: index into esns of the engine on each
    tail and position during round j; health [F, E, 13]: true health of every
    engine during round j (percent, HEALTH_NAMES order); installations, faults,
    swaps, washes: event records.
    """

    config: FleetConfig
    esns: tuple[str, ...]
    tails: tuple[str, ...]
    flights: tuple[tuple[FlightRecord, ...], ...]
    installed: np.ndarray
    health: np.ndarray
    installations: tuple[Installation, ...]
    faults: tuple[FaultEvent, ...]
    swaps: tuple[SwapEvent, ...]
    washes: tuple[WashEvent, ...]

    @property
    def health_names(self) -> tuple[str, ...]:
        return HEALTH_NAMES


def _tail_name(a: int) -> str:
    return f"N{101 + a}FH"


def _esn_name(e: int) -> str:
    return f"ESN{880001 + e}"


class _Engines:
    """Mutable per-engine state of the planner (arrays over all E engines)."""

    def __init__(self, n: int, cfg: FleetConfig, rng: np.random.Generator) -> None:
        mult = np.exp(rng.normal(0.0, cfg.rate_spread, (n, N_TURBO)))
        self.rate = DETERIORATION_RATES * mult / 1000.0  # % per cycle
        self.foul_rate = FOULING_RATES * mult / 1000.0
        self.scatter = rng.normal(0.0, cfg.scatter_std, (n, N_TURBO))
        self.bias = rng.normal(0.0, 1.0, (n, 3)) * np.array(cfg.bias_std)
        age = rng.uniform(0.0, cfg.initial_cycles_max, n)
        # An engine has fouled at most since it first flew: with washes rarer than the fleet's
        # age (a wash_interval of 1e5 cycles for "no washes"), an uncapped draw gave engines up
        # to 1e5 cycles of fouling, efficiencies 20-60 % down.
        since_wash = np.minimum(rng.uniform(0.0, cfg.wash_interval, n), age)
        self.perm = self.rate * age[:, None]
        self.foul = self.foul_rate * since_wash[:, None]
        self.fault = np.zeros((n, N_HEALTH))
        self.faulted = np.zeros(n, dtype=bool)
        self.next_wash = cfg.wash_interval * rng.uniform(0.8, 1.2, n) - since_wash
        self.shop_until = np.full(n, -1)

    def health(self) -> np.ndarray:
        h = np.zeros((self.rate.shape[0], N_HEALTH))
        h[:, :N_TURBO] = self.scatter + self.perm + self.foul
        h[:, N_TURBO:] = self.bias
        return h + self.fault


def plan_fleet(config: FleetConfig, rng: np.random.Generator) -> FleetPlan:
    """The fleet's history over ``config.n_flights`` rounds (deterministic for the rng state)."""
    cfg = config
    n_air, n_pos, n_rounds = cfg.n_aircraft, cfg.positions, cfg.n_flights
    n_eng = n_air * n_pos + cfg.n_spares
    esns = tuple(_esn_name(e) for e in range(n_eng))
    tails = tuple(_tail_name(a) for a in range(n_air))
    eng = _Engines(n_eng, cfg, rng)
    spacing = 86400.0 / cfg.flights_per_day
    on_wing = np.arange(n_air * n_pos).reshape(n_air, n_pos)
    pool = list(range(n_air * n_pos, n_eng))  # spares available
    installed_at = np.full((n_air, n_pos), cfg.start_epoch_s - 86400.0)
    installations: list[Installation] = []
    faults: list[FaultEvent] = []
    swaps: list[SwapEvent] = []
    washes: list[WashEvent] = []
    flights: list[tuple[FlightRecord, ...]] = []
    installed = np.zeros((n_rounds, n_air, n_pos), dtype=np.int64)
    health = np.zeros((n_rounds, n_eng, N_HEALTH))
    fault_h = [health_vector(f.shifts) for f in cfg.faults]

    def swap(a: int, p: int, new: int, at: float, reason: str) -> None:
        old = int(on_wing[a, p])
        installations.append(Installation(esns[old], tails[a], p + 1,
                                          float(installed_at[a, p]), at))
        swaps.append(SwapEvent(at, tails[a], p + 1, esns[old], esns[new], reason))
        on_wing[a, p] = new
        installed_at[a, p] = at

    for j in range(n_rounds):
        round_start = cfg.start_epoch_s + j * spacing
        # Engines back from the shop join the spare pool.
        pool.extend(int(back) for back in np.flatnonzero(eng.shop_until == j))
        params = random_parameters(n_air, rng)
        starts = round_start + rng.uniform(0.0, 0.25 * spacing, n_air)
        records = []
        for a in range(n_air):
            fp = FlightParameters(*(np.asarray(v)[a:a + 1] for v in params))
            records.append(FlightRecord(f"{tails[a]}-{j + 1:05d}", tails[a], j,
                                        float(np.round(starts[a])), fp))
        flights.append(tuple(records))
        flying = on_wing.ravel()
        # Abrupt faults strike at the start of a flight.
        hit = rng.random(flying.size) < cfg.fault_rate
        for k in np.flatnonzero(hit):
            e = int(flying[k])
            a, p = divmod(int(k), n_pos)
            i = int(rng.integers(len(cfg.faults)))
            scale = float(rng.uniform(0.75, 1.5))
            eng.fault[e] += scale * fault_h[i]
            eng.faulted[e] = True
            shifts = {n: float(scale * v) for n, v in cfg.faults[i].shifts.items()}
            faults.append(FaultEvent(esns[e], records[a].flight_id, tails[a], p + 1,
                                     records[a].started_at, cfg.faults[i].name, scale, shifts))
        installed[j] = on_wing
        health[j] = eng.health()
        # One cycle of deterioration and fouling for every engine that flew.
        eng.perm[flying] += eng.rate[flying]
        eng.foul[flying] += eng.foul_rate[flying]
        eng.next_wash[flying] -= 1.0
        # Between rounds: washes, removals, exchanges (all at one instant).
        at = round_start + 0.75 * spacing
        for washed in flying[eng.next_wash[flying] <= 0.0]:
            rec = eng.foul[washed] * cfg.wash_recovery
            eng.foul[washed] -= rec
            eng.next_wash[washed] = cfg.wash_interval * rng.uniform(0.8, 1.2)
            washes.append(WashEvent(esns[washed], at, {
                HEALTH_NAMES[i]: float(-rec[i]) for i in range(N_TURBO) if rec[i] != 0.0
            }))
        if j == n_rounds - 1:
            break
        for a in range(n_air):
            for p in range(n_pos):
                e = int(on_wing[a, p])
                pulled = eng.faulted[e] and rng.random() < cfg.faulted_removal
                if not pulled and rng.random() >= cfg.removal_rate:
                    continue
                if not pool:
                    continue
                new = pool.pop(int(rng.integers(len(pool))))
                swap(a, p, new, at, "fault removal" if pulled else "scheduled removal")
                eng.shop_until[e] = j + 1 + cfg.shop_rounds
                if pulled:
                    eng.fault[e] = 0.0
                    eng.faulted[e] = False
                eng.perm[e] *= 1.0 - cfg.shop_restore
        if n_air > 1:
            n_exchanges = rng.binomial(n_air * n_pos, cfg.exchange_rate)
            for _ in range(n_exchanges):
                a1, a2 = rng.choice(n_air, 2, replace=False)
                p1, p2 = rng.integers(n_pos), rng.integers(n_pos)
                e1, e2 = int(on_wing[a1, p1]), int(on_wing[a2, p2])
                if installed_at[a1, p1] == at or installed_at[a2, p2] == at:
                    continue  # an engine moves at most once per instant
                swap(int(a1), int(p1), e2, at, f"exchange with {tails[a2]}")
                # The second leg: e2's old position; its installation record
                # ends now and e1 takes it.
                installations.append(Installation(esns[e2], tails[a2], int(p2) + 1,
                                                  float(installed_at[a2, p2]), at))
                swaps.append(SwapEvent(at, tails[a2], int(p2) + 1, esns[e2], esns[e1],
                                       f"exchange with {tails[a1]}"))
                on_wing[a2, p2] = e1
                installed_at[a2, p2] = at
    for a in range(n_air):
        for p in range(n_pos):
            installations.append(Installation(esns[int(on_wing[a, p])], tails[a], p + 1,
                                              float(installed_at[a, p]), None))
    return FleetPlan(cfg, esns, tails, tuple(flights), installed, health,
                     tuple(installations), tuple(faults), tuple(swaps), tuple(washes))


class Snapshots(NamedTuple):
    """Snapshot records, columnar, one row per engine, flight and phase ([n] arrays).

    recorded_at [s UTC]; tail, phase, flight_id (str arrays); position (1..P);
    esn (ground truth: never part of an upload); alt_ft, mach, dtamb_k,
    power_pct: operating condition; actuators [n, 3] (Wf pps as measured, VSV
    and VBV % commanded); sensors [n, 12] as measured (SENSOR_NAMES order);
    sensors_true [n, 12] without noise.
    """

    recorded_at: np.ndarray
    tail: np.ndarray
    position: np.ndarray
    phase: np.ndarray
    flight_id: np.ndarray
    esn: np.ndarray
    alt_ft: np.ndarray
    mach: np.ndarray
    dtamb_k: np.ndarray
    power_pct: np.ndarray
    actuators: np.ndarray
    sensors: np.ndarray
    sensors_true: np.ndarray


def engine_noise_std() -> np.ndarray:
    """The engine's sensor noise standard deviations [12] in sensor units.

    Percent of the sea-level static take-off trim (seed 001 Table 2).
    """
    return _engine_noise_std().copy()


@functools.lru_cache(maxsize=1)
def _engine_noise_std() -> np.ndarray:
    return noise_std(steady_state(np.zeros(3), power=100.0).sensors)  # a solve: kept


def _round_conditions(plan: FleetPlan, j: int) -> FlightParameters:
    recs = plan.flights[j]
    return FlightParameters(*(np.concatenate([np.asarray(r.params[i]) for r in recs])
                              for i in range(len(FlightParameters._fields))))


def fleet_snapshots(
    plan: FleetPlan,
    rng: np.random.Generator,
    on_round: Callable[[int], None] | None = None,
    max_rows: int = 2048,
) -> Snapshots:
    """Take-off, climb and cruise snapshots of every flight of the plan.

    Rows are laid out round by round (phase, then aircraft and position);
    batched steady-state solves of whole rounds, at most about ``max_rows``
    engine-points per solve; then noise N(0, engine_noise_std()) on the
    sensors of all rows in one draw when the plan's config says so (the
    result does not depend on max_rows). ``on_round(j)`` reports progress.
    """
    cfg = plan.config
    n_air, n_pos = cfg.n_aircraft, cfg.positions
    n = n_air * n_pos
    air = np.repeat(np.arange(n_air), n_pos)
    esns = np.asarray(plan.esns, dtype=object)
    tails = np.asarray(plan.tails, dtype=object)
    cols: dict[str, list[np.ndarray]] = {k: [] for k in Snapshots._fields}
    health = []
    for j in range(cfg.n_flights):
        points = snapshot_points(flight_profile(_round_conditions(plan, j)))
        eng = plan.installed[j].ravel()  # [N P]
        starts = np.array([r.started_at for r in plan.flights[j]])
        fids = np.asarray([r.flight_id for r in plan.flights[j]], dtype=object)
        for pt in points:
            c = pt.condition
            cols["recorded_at"].append(starts[air] + pt.time_s)
            cols["tail"].append(tails[air])
            cols["position"].append(np.tile(np.arange(1, n_pos + 1), n_air))
            cols["phase"].append(np.full(n, pt.phase, dtype=object))
            cols["flight_id"].append(fids[air])
            cols["esn"].append(esns[eng])
            cols["alt_ft"].append(c.alt_ft[air])
            cols["mach"].append(c.mach[air])
            cols["dtamb_k"].append(c.dtamb_k[air])
            cols["power_pct"].append(c.power_pct[air])
            health.append(plan.health[j, eng])
    meta = {k: np.concatenate(v) for k, v in cols.items() if v}
    h = np.concatenate(health)
    env = np.stack([meta["alt_ft"], meta["mach"], meta["dtamb_k"]], axis=1)
    per_round = 3 * n
    rounds_per_solve = max(1, max_rows // per_round)
    y = np.empty((env.shape[0], 12))
    u = np.empty((env.shape[0], 3))
    for j0 in range(0, cfg.n_flights, rounds_per_solve):
        j1 = min(cfg.n_flights, j0 + rounds_per_solve)
        sl = slice(j0 * per_round, j1 * per_round)
        ss = steady_state(env[sl], power=meta["power_pct"][sl], health=h[sl])
        y[sl], u[sl] = ss.sensors, ss.u
        if on_round is not None:
            for j in range(j0, j1):
                on_round(j)
    ym = y + rng.standard_normal(y.shape) * engine_noise_std() if cfg.noise else y.copy()
    u[:, 0] = ym[:, -1]  # the Wf sensor (fuel flow command, measured)
    meta.update(actuators=u, sensors=ym, sensors_true=y)
    return Snapshots(*(meta[k] for k in Snapshots._fields))


class StreamFlight(NamedTuple):
    """One engine's whole-flight recording at a fixed rate.

    tail, position, flight_id, esn (ground truth), started_at [s UTC]; time_s
    [T] from the start; alt_ft, mach, dtamb_k, power_pct [T]; actuators [T, 3]
    (Wf as measured, VSV, VBV commanded); sensors [T, 12] measured; health [13]
    true during the flight.
    """

    tail: str
    position: int
    flight_id: str
    esn: str
    started_at: float
    time_s: np.ndarray
    alt_ft: np.ndarray
    mach: np.ndarray
    dtamb_k: np.ndarray
    power_pct: np.ndarray
    actuators: np.ndarray
    sensors: np.ndarray
    health: np.ndarray


def stream_step(rate_hz: float | None) -> tuple[float, int]:
    """Integration step [s] and record interval [steps] for an output rate.

    The step is the largest that is at most 15 ms and divides the output
    interval 1/rate exactly; None or rates above 66.7 Hz record every step
    (of 15 ms, or 1/rate when faster).
    """
    if rate_hz is None:
        return DT_DEFAULT, 1
    if rate_hz <= 0:
        raise ValueError(f"rate_hz must be positive, got {rate_hz}")
    interval = 1.0 / rate_hz
    if interval <= DT_DEFAULT:
        return interval, 1
    every = int(np.ceil(interval / DT_DEFAULT - 1e-9))
    return interval / every, every


def stream_flights(
    plan: FleetPlan,
    rng: np.random.Generator,
    rate_hz: float | None = None,
    duration_s: float | None = None,
    rounds: Sequence[int] | None = None,
    max_batch: int = 256,
    memory_bytes: float = 1.0e9,
    on_progress: Callable[[float], None] | None = None,
) -> Iterator[StreamFlight]:
    """Whole flights of every installed engine, in round, aircraft, position order (a generator).

    The plan fixes every engine's health for every flight in advance, so
    flights of different rounds are independent: all of them are simulated
    together in batches (``transient.simulate``, from rest at ground idle) of
    at most ``max_batch`` engine-flights and about ``memory_bytes`` of
    recorded samples. duration_s shortens the 2500 s flight (tests, demos).
    on_progress(fraction) reports the fraction of all engine-flights simulated.
    """
    cfg = plan.config
    n_pos = cfg.positions
    std = engine_noise_std() if cfg.noise else None
    dt, every = stream_step(rate_hz)
    t_end = DURATION_S if duration_s is None else min(duration_s, DURATION_S)
    samples = int(np.floor(t_end / dt + 1e-9)) // every + 1
    per_row = samples * 8.0 * 48  # float64 recorded values per engine and sample
    chunk = int(max(1, min(max_batch, memory_bytes // per_row)))
    rows = [(j, a, p) for j in (range(cfg.n_flights) if rounds is None else rounds)
            for a in range(cfg.n_aircraft) for p in range(n_pos)]
    n_rows = max(len(rows), 1)
    for start in range(0, len(rows), chunk):
        part = rows[start:start + chunk]

        def progress(frac: float, start: int = start, size: int = len(part)) -> None:
            if on_progress is not None:
                on_progress((start + frac * size) / n_rows)

        recs = [plan.flights[j][a] for j, a, _ in part]
        eng = np.array([plan.installed[j, a, p] for j, a, p in part])
        h = np.stack([plan.health[j, e] for (j, _a, _p), e in zip(part, eng, strict=True)])
        params = FlightParameters(*(np.concatenate([np.asarray(r.params[i]) for r in recs])
                                    for i in range(len(FlightParameters._fields))))
        res = simulate(flight_profile(params), t_end, health=h, dt=dt, record_every=every,
                       noise_std=std, rng=rng if std is not None else None,
                       on_progress=progress)
        for k, ((_j, _a, p), rec) in enumerate(zip(part, recs, strict=True)):
            act = res.u[:, k].copy()
            act[:, 0] = res.measured[:, k, -1]
            yield StreamFlight(
                rec.tail, p + 1, rec.flight_id, plan.esns[eng[k]], rec.started_at,
                res.time_s, res.condition.alt_ft[:, k], res.condition.mach[:, k],
                res.condition.dtamb_k[:, k], res.condition.power_pct[:, k], act,
                res.measured[:, k], h[k],
            )


class FleetResult(NamedTuple):
    """plan (ground truth) and the data: snapshots (snapshot mode) or streams (stream mode)."""

    plan: FleetPlan
    snapshots: Snapshots | None
    streams: Iterator[StreamFlight] | None


def simulate_fleet(
    config: FleetConfig,
    rng: np.random.Generator,
    mode: str = "snapshot",
    rate_hz: float | None = None,
    duration_s: float | None = None,
) -> FleetResult:
    """Plan the fleet, then its snapshots or (lazily) its stream flights.

    The plan, the snapshot noise and the stream noise draw from three
    generators spawned from ``rng``, so the fleet's history is the same in
    both modes for one seed.
    """
    if mode not in ("snapshot", "stream"):
        raise ValueError(f"mode must be 'snapshot' or 'stream', got {mode!r}")
    plan_rng, snap_rng, stream_rng = rng.spawn(3)
    plan = plan_fleet(config, plan_rng)
    if mode == "snapshot":
        return FleetResult(plan, fleet_snapshots(plan, snap_rng), None)
    return FleetResult(plan, None, stream_flights(plan, stream_rng, rate_hz, duration_s))


__all__ = [
    "DETERIORATION_RATES", "DETERIORATION_SIGN", "FOULING_RATES", "FaultEvent", "FleetConfig",
    "FleetPlan",
    "FleetResult", "FlightRecord", "Installation", "SNAPSHOT_PHASES", "Snapshots",
    "StreamFlight", "SwapEvent", "WashEvent", "engine_noise_std", "fleet_snapshots",
    "plan_fleet", "seed001_actuator_biases", "seed001_degradations", "simulate_fleet",
    "stream_flights", "stream_step",
]
