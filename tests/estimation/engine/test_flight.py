"""Flight profiles: breakpoints, interpolation, phases, snapshot points, envelope."""

from __future__ import annotations

import numpy as np
import pytest

from estimation.engine.flight import (
    BREAKPOINTS_S,
    DURATION_S,
    PHASE_WINDOWS,
    PHASES,
    SNAPSHOT_PHASES,
    condition_at,
    flight_profile,
    phase_at,
    random_parameters,
    seed001_parameters,
    snapshot_points,
)
from estimation.engine.steady import steady_state


def test_seed001_profile_spans_the_papers_flight() -> None:
    prof = flight_profile()
    t = np.arange(0.0, DURATION_S + 1e-9, 0.5)
    c = condition_at(prof, t)
    # seed 001: 2500 s, 0-35,000 ft, Mach 0-0.84, ground idle to take-off power.
    assert prof.duration_s == DURATION_S == 2500.0
    assert c.alt_ft.min() == 0.0 and c.alt_ft.max() == 35000.0
    assert c.mach.min() == 0.0 and c.mach.max() == pytest.approx(0.84)
    assert c.power_pct.min() == 0.0 and c.power_pct.max() == 100.0
    # Ground idle at rest, cruise level at the end.
    idle = phase_at(t) == "ground_idle"
    assert np.all(c.power_pct[0, idle] == 0.0) and np.all(c.mach[0, idle] == 0.0)
    assert c.alt_ft[0, -1] == 35000.0 and c.mach[0, -1] == pytest.approx(0.84)
    # Altitude never falls during the flight.
    assert np.all(np.diff(c.alt_ft[0]) >= 0.0)


def test_interpolation_matches_numpy_per_flight() -> None:
    rng = np.random.default_rng(3)
    prof = flight_profile(random_parameters(5, rng))
    t = rng.uniform(-10.0, DURATION_S + 10.0, 200)
    c = condition_at(prof, t)
    for j in range(prof.n_flights):
        for got, table in ((c.alt_ft, prof.alt_ft), (c.mach, prof.mach),
                           (c.power_pct, prof.power_pct)):
            np.testing.assert_allclose(got[j], np.interp(t, BREAKPOINTS_S, table[j]), rtol=1e-13)
        assert np.all(c.dtamb_k[j] == prof.dtamb_k[j])
    # Scalar time gives the column of the array result.
    c1 = condition_at(prof, t[7])
    np.testing.assert_allclose(c1.alt_ft, c.alt_ft[:, 7], rtol=1e-14)


def test_phases_and_snapshot_points() -> None:
    starts = [PHASE_WINDOWS[p][0] for p in PHASES]
    assert list(phase_at(np.array(starts))) == list(PHASES)
    assert phase_at(DURATION_S) == "cruise"
    rng = np.random.default_rng(4)
    params = random_parameters(6, rng)
    prof = flight_profile(params)
    snaps = snapshot_points(prof)
    assert tuple(s.phase for s in snaps) == SNAPSHOT_PHASES
    for s in snaps:
        lo, hi = PHASE_WINDOWS[s.phase]
        assert lo <= s.time_s < hi and phase_at(s.time_s) == s.phase
        expect = condition_at(prof, s.time_s)
        for a, b in zip(s.condition, expect, strict=True):
            np.testing.assert_array_equal(a, b)
    cruise = snaps[2].condition
    np.testing.assert_allclose(cruise.alt_ft, params.cruise_alt_ft)
    np.testing.assert_allclose(cruise.power_pct, params.cruise_power_pct)
    take_off = snaps[0].condition
    np.testing.assert_allclose(take_off.power_pct, params.takeoff_power_pct)


def test_random_flights_are_deterministic_and_solvable() -> None:
    a = random_parameters(40, np.random.default_rng(11))
    b = random_parameters(40, np.random.default_rng(11))
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    prof = flight_profile(a)
    # Every snapshot point of every flight lies where the steady-state solver converges.
    for s in snapshot_points(prof):
        c = s.condition
        env = np.stack([c.alt_ft, c.mach, c.dtamb_k], axis=1)
        ss = steady_state(env, power=c.power_pct)
        assert np.all(np.isfinite(ss.sensors))


def test_seed001_parameters_broadcast() -> None:
    prof = flight_profile(seed001_parameters(3))
    assert prof.alt_ft.shape == (3, BREAKPOINTS_S.size)
    np.testing.assert_array_equal(prof.alt_ft[0], prof.alt_ft[2])
