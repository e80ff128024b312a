"""The fleet simulator: determinism, deterioration signs, faults, swaps, washes, data."""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import pytest

from estimation.engine.fleet import (
    DETERIORATION_RATES,
    FOULING_RATES,
    FleetConfig,
    engine_noise_std,
    fleet_snapshots,
    plan_fleet,
    seed001_actuator_biases,
    seed001_degradations,
    simulate_fleet,
    stream_flights,
    stream_step,
)
from estimation.engine.flight import SNAPSHOT_TIMES_S, condition_at, flight_profile
from estimation.engine.health import HEALTH_NAMES, health_vector
from estimation.engine.steady import steady_state
from estimation.isolation import SEED_002_FAULTS

# A busy fleet: many events in few rounds, so every rule is exercised.
BUSY = FleetConfig(n_aircraft=8, n_flights=120, fault_rate=1 / 150, removal_rate=1 / 200,
                   exchange_rate=1 / 150, wash_interval=40.0, shop_rounds=5)


@pytest.fixture(scope="module")
def busy_plan():
    return plan_fleet(BUSY, np.random.default_rng(20))


def test_plan_is_deterministic_for_a_seed(busy_plan) -> None:
    again = plan_fleet(BUSY, np.random.default_rng(20))
    np.testing.assert_array_equal(again.health, busy_plan.health)
    np.testing.assert_array_equal(again.installed, busy_plan.installed)
    assert again.faults == busy_plan.faults and again.swaps == busy_plan.swaps
    other = plan_fleet(BUSY, np.random.default_rng(21))
    assert not np.array_equal(other.health, busy_plan.health)
    assert len(busy_plan.faults) > 5 and len(busy_plan.swaps) > 5 and len(busy_plan.washes) > 5


def _events_by_engine_round(plan):
    """Rounds where an engine had a fault, a wash after, or a shop visit around it."""
    touched = defaultdict(set)
    flight_round = {r.flight_id: r.round for rnd in plan.flights for r in rnd}
    for f in plan.faults:
        touched[f.esn].add(flight_round[f.flight_id])
    return touched


def test_deterioration_follows_the_sign_convention(busy_plan) -> None:
    plan = busy_plan
    # Signs of the rates: efficiencies and compressor flows fall, turbine flows rise.
    sign = np.array([-1, -1, -1, -1, -1, -1, -1, 1, -1, 1])
    assert np.all(np.sign(DETERIORATION_RATES) == sign)
    assert np.all((np.sign(FOULING_RATES) == sign) | (FOULING_RATES == 0))
    # HPC and HPT dominate.
    mags = np.abs(DETERIORATION_RATES)
    assert min(mags[4:8]) >= max(mags[[0, 1, 2, 3, 8, 9]])
    # Engine by engine: over a round with no fault, wash or shop visit, every
    # turbomachinery parameter moves in its deterioration direction.
    faulted = _events_by_engine_round(plan)
    wash_at = defaultdict(set)
    for w in plan.washes:
        wash_at[w.esn].add(w.at)
    spacing = 86400.0 / BUSY.flights_per_day
    checked = 0
    for j in range(BUSY.n_flights - 1):
        flying = set(plan.installed[j].ravel().tolist())
        both = flying & set(plan.installed[j + 1].ravel().tolist())
        at = BUSY.start_epoch_s + j * spacing + 0.75 * spacing
        for e in both:
            esn = plan.esns[e]
            if j + 1 in faulted[esn] or at in wash_at[esn]:
                continue
            if any(s.at == at and esn in (s.esn_off, s.esn_on) for s in plan.swaps):
                continue
            step = plan.health[j + 1, e, :10] - plan.health[j, e, :10]
            assert np.all(step * sign > 0), (esn, j, step)
            np.testing.assert_array_equal(plan.health[j + 1, e, 10:], plan.health[j, e, 10:])
            checked += 1
    assert checked > 100
    # Spares on the ground do not deteriorate.
    for j in range(BUSY.n_flights - 1):
        idle = set(range(len(plan.esns))) - set(plan.installed[j].ravel().tolist())
        for e in idle:
            if plan.esns[e] in {s.esn_on for s in plan.swaps}:
                continue
            np.testing.assert_array_equal(plan.health[j + 1, e], plan.health[j, e])


def test_faults_come_from_the_seed_002_library(busy_plan) -> None:
    plan = busy_plan
    library = {f.name: health_vector(f.shifts) for f in SEED_002_FAULTS}
    flight_round = {r.flight_id: r.round for rnd in plan.flights for r in rnd}
    for f in plan.faults:
        assert 0.75 <= f.scale <= 1.5
        shifts = health_vector(f.shifts)
        np.testing.assert_allclose(shifts, f.scale * library[f.fault], rtol=1e-14)
        j = flight_round[f.flight_id]
        e = plan.esns.index(f.esn)
        a = plan.tails.index(f.tail)
        assert plan.installed[j, a, f.position - 1] == e
        if j == 0:
            continue
        # The jump into the fault round is the shift plus one cycle of wear
        # (and any wash recovery or second fault in the same round).
        if any(g.esn == f.esn and g is not f and flight_round[g.flight_id] == j
               for g in plan.faults):
            continue
        jump = plan.health[j, e] - plan.health[j - 1, e]
        washed = any(w.esn == f.esn and w.at < f.occurred_at and
                     w.at > f.occurred_at - 86400.0 / BUSY.flights_per_day for w in plan.washes)
        if washed:
            continue
        wear = jump - shifts
        assert np.max(np.abs(wear)) < 0.01  # one cycle of deterioration is tiny


def test_swaps_never_share_a_position_or_an_engine(busy_plan) -> None:
    plan = busy_plan
    by_position = defaultdict(list)
    by_engine = defaultdict(list)
    for inst in plan.installations:
        end = np.inf if inst.removed_at is None else inst.removed_at
        assert end > inst.installed_at
        by_position[(inst.tail, inst.position)].append((inst.installed_at, end, inst.esn))
        by_engine[inst.esn].append((inst.installed_at, end))
    for spans in list(by_position.values()) + list(by_engine.values()):
        spans.sort()
        for (_s0, e0, *_), (s1, _e1, *_) in zip(spans, spans[1:], strict=False):
            assert s1 >= e0  # half-open [installed_at, removed_at) never overlap
    # Each position is covered without gaps from the start to the end.
    for spans in by_position.values():
        for (_s0, e0, _), (s1, _e1, _) in zip(spans, spans[1:], strict=False):
            assert s1 == e0
        assert spans[-1][1] == np.inf
    # The installed table agrees with the installation records at each flight.
    for j, rnd in enumerate(plan.flights):
        for a, rec in enumerate(rnd):
            for p in range(BUSY.positions):
                esn = plan.esns[plan.installed[j, a, p]]
                spans = by_position[(rec.tail, p + 1)]
                owner = [x for s, e, x in spans if s <= rec.started_at < e]
                assert owner == [esn]
    # Engines really move between aircraft.
    tails_of = defaultdict(set)
    for inst in plan.installations:
        tails_of[inst.esn].add(inst.tail)
    assert any(len(t) > 1 for t in tails_of.values())


def test_washes_recover_compressor_fouling(busy_plan) -> None:
    for w in busy_plan.washes:
        assert set(w.recovered) <= set(HEALTH_NAMES[:6])
        for name, value in w.recovered.items():
            # Recovery moves against the deterioration direction.
            assert value > 0.0, (name, value)


def test_snapshots_are_steady_states_of_the_true_health_plus_noise() -> None:
    cfg = FleetConfig(n_aircraft=3, n_flights=4)
    res = simulate_fleet(cfg, np.random.default_rng(5))
    again = simulate_fleet(cfg, np.random.default_rng(5))
    s, plan = res.snapshots, res.plan
    assert s is not None and again.snapshots is not None
    np.testing.assert_array_equal(s.sensors, again.snapshots.sensors)
    n = cfg.n_aircraft * cfg.positions * cfg.n_flights * 3
    assert s.sensors.shape == (n, 12) and set(s.phase) == {"takeoff", "climb", "cruise"}
    # Row by row, an independent one-engine solve reproduces the true sensors.
    flight_round = {r.flight_id: r for rnd in plan.flights for r in rnd}
    for i in range(0, n, 7):
        rec = flight_round[s.flight_id[i]]
        e = plan.esns.index(s.esn[i])
        assert plan.installed[rec.round, plan.tails.index(s.tail[i]), s.position[i] - 1] == e
        assert s.recorded_at[i] == rec.started_at + SNAPSHOT_TIMES_S[s.phase[i]]
        env = np.array([s.alt_ft[i], s.mach[i], s.dtamb_k[i]])
        one = steady_state(env, power=float(s.power_pct[i]), health=plan.health[rec.round, e])
        np.testing.assert_allclose(s.sensors_true[i], one.sensors, rtol=1e-7)
        np.testing.assert_allclose(s.actuators[i, 1:], one.u[1:], rtol=1e-7)
        cond = condition_at(flight_profile(rec.params), SNAPSHOT_TIMES_S[s.phase[i]])
        np.testing.assert_allclose(s.alt_ft[i], cond.alt_ft[0], rtol=1e-12)
    # Noise: standardised residuals are N(0, 1) within sampling error.
    z = (s.sensors - s.sensors_true) / engine_noise_std()
    assert abs(z.mean()) < 4 / np.sqrt(z.size)
    assert abs(z.std() - 1.0) < 0.1
    np.testing.assert_array_equal(s.actuators[:, 0], s.sensors[:, -1])
    quiet = fleet_snapshots(plan._replace(config=FleetConfig(n_aircraft=3, n_flights=4,
                                                             noise=False)),
                            np.random.default_rng(0))
    np.testing.assert_allclose(quiet.sensors, s.sensors_true, rtol=1e-12)


def test_stream_step_divides_the_output_interval() -> None:
    for rate in (1.0, 2.0, 10.0, 20.0, 30.0):
        dt, every = stream_step(rate)
        assert dt <= 0.015 + 1e-15
        assert dt * every == pytest.approx(1.0 / rate, rel=1e-12)
    assert stream_step(None) == (0.015, 1)
    assert stream_step(100.0) == (0.01, 1)


def test_stream_flights_follow_the_profile_from_rest() -> None:
    cfg = FleetConfig(n_aircraft=2, n_flights=2, positions=1, noise=False)
    plan = plan_fleet(cfg, np.random.default_rng(8))
    flights = list(stream_flights(plan, np.random.default_rng(9), rate_hz=5.0, duration_s=4.0,
                                  rounds=[1]))
    assert len(flights) == 2
    for fl in flights:
        rec = next(r for r in plan.flights[1] if r.flight_id == fl.flight_id)
        assert fl.tail == rec.tail and fl.started_at == rec.started_at
        np.testing.assert_allclose(fl.time_s, np.arange(21) * 0.2, atol=1e-12)
        cond = condition_at(flight_profile(rec.params), fl.time_s)
        np.testing.assert_allclose(fl.alt_ft, cond.alt_ft[0], rtol=1e-12)
        np.testing.assert_allclose(fl.power_pct, cond.power_pct[0], rtol=1e-12)
        e = plan.esns.index(fl.esn)
        np.testing.assert_array_equal(fl.health, plan.health[1, e])
        # Ground idle at rest: the recording is the steady state throughout.
        ss = steady_state(np.array([fl.alt_ft[0], 0.0, fl.dtamb_k[0]]), power=0.0,
                          health=fl.health)
        np.testing.assert_allclose(fl.sensors, np.broadcast_to(ss.sensors, fl.sensors.shape),
                                   rtol=1e-6)


def test_stream_batches_do_not_change_the_flights() -> None:
    cfg = FleetConfig(n_aircraft=2, n_flights=2, positions=2, noise=False)
    plan = plan_fleet(cfg, np.random.default_rng(12))
    together = list(stream_flights(plan, np.random.default_rng(1), rate_hz=2.0, duration_s=2.0))
    apart = list(stream_flights(plan, np.random.default_rng(1), rate_hz=2.0, duration_s=2.0,
                                max_batch=3))
    assert [f.flight_id for f in together] == [r.flight_id for rnd in plan.flights
                                               for r in rnd for _ in range(2)]
    for a, b in zip(together, apart, strict=True):
        assert (a.flight_id, a.position, a.esn) == (b.flight_id, b.position, b.esn)
        np.testing.assert_allclose(a.sensors, b.sensors, rtol=1e-9)


def test_snapshot_solve_batches_do_not_change_the_snapshots() -> None:
    cfg = FleetConfig(n_aircraft=2, n_flights=5)
    plan = plan_fleet(cfg, np.random.default_rng(13))
    big = fleet_snapshots(plan, np.random.default_rng(1))
    rounds = []
    small = fleet_snapshots(plan, np.random.default_rng(1), on_round=rounds.append, max_rows=12)
    assert rounds == list(range(5))
    np.testing.assert_allclose(small.sensors, big.sensors, rtol=1e-9)
    np.testing.assert_array_equal(small.flight_id, big.flight_id)


def test_seed001_evaluation_cases() -> None:
    rng = np.random.default_rng(0)
    deg = seed001_degradations(100, rng)
    mag = np.abs(deg[:, :10])
    assert mag.min() >= 1.0 and mag.max() <= 5.0 and np.all(deg[:, 10:] == 0.0)
    # Efficiencies and compressor flows fall, turbine flows rise (seed 002 Table 3 signs).
    hpt = health_vector(next(f for f in SEED_002_FAULTS if f.name == "HPT").shifts)
    assert np.all(np.sign(deg[:, 6:8]) == np.sign(hpt[6:8]))
    assert np.all(deg[:, [0, 1, 2, 3, 4, 5, 6, 8]] < 0) and np.all(deg[:, [7, 9]] > 0)
    bias = seed001_actuator_biases(200, rng)
    assert np.all(bias[:, :10] == 0.0) and np.abs(bias[:, 10:]).max() <= 10.0
    assert bias[:, 10:].min() < -8.0 and bias[:, 10:].max() > 8.0
    # The engine runs at both kinds of case (steady state at ground idle and cruise).
    env = np.array([[0.0, 0.0, 0.0], [35000.0, 0.84, 0.0]])
    for cases in (deg[:5], bias[:5]):
        ss = steady_state(np.tile(env, (5, 1)), power=np.tile([0.0, 80.0], 5),
                          health=np.repeat(cases, 2, axis=0))
        assert np.all(np.isfinite(ss.sensors))


def test_stream_progress_reaches_the_end() -> None:
    cfg = FleetConfig(n_aircraft=1, n_flights=2, positions=1, noise=False)
    plan = plan_fleet(cfg, np.random.default_rng(2))
    seen: list[float] = []
    flights = list(stream_flights(plan, np.random.default_rng(3), rate_hz=1.0, duration_s=1.0,
                                  max_batch=1, on_progress=seen.append))
    assert len(flights) == 2
    assert seen == sorted(seen) and seen[0] == 0.0 and seen[-1] == 1.0


def test_an_engine_has_fouled_no_longer_than_it_has_flown() -> None:
    # Washes rarer than the engines' age ("no washes" as 1e5 cycles): the fouling at the start
    # is that of the engine's own cycles, so health stays within what its age allows.
    config = FleetConfig(n_aircraft=6, n_flights=2, initial_cycles_max=1000.0,
                         wash_interval=1e5, fault_rate=0.0, scatter_std=0.0)
    plan = plan_fleet(config, np.random.default_rng(3))
    # Percent per cycle at a 4-sigma rate multiplier, times the oldest engine.
    worst = np.abs(DETERIORATION_RATES + FOULING_RATES) / 1000.0 * np.exp(4 * config.rate_spread)
    assert np.all(np.abs(plan.health[0, :, :10]) <= worst * config.initial_cycles_max + 1e-9)
