"""Closed-loop transient simulation: rest point, step size, batch, noise, determinism."""

from __future__ import annotations

import numpy as np
import pytest

from estimation.engine.flight import OperatingPoint, condition_at, flight_profile
from estimation.engine.sensors import SENSOR_NAMES, noise_std
from estimation.engine.steady import steady_state
from estimation.engine.transient import simulate

ALT = np.array([0.0, 20000.0, 35000.0])
MACH = np.array([0.0, 0.6, 0.84])
DT = np.array([10.0, -5.0, 0.0])
HEALTH = np.zeros((3, 13))
HEALTH[0, [4, 5]] = -2.0  # HPC fault (seed 002 Table 3)
HEALTH[1, [6, 7]] = [-2.0, 2.0]  # HPT fault
HEALTH[2, :10] = [-1, -1.2, -0.8, -1, -2, -2.2, -1.9, 1.4, -0.6, 0.5]  # aged engine
HEALTH[2, 10:] = [1.0, -2.0, -5.0]  # actuator biases


def _hold(power: np.ndarray, t_step: float = np.inf, power2: np.ndarray | None = None):
    return lambda t: OperatingPoint(ALT, MACH, DT, power if t < t_step else power2)


def test_disturbed_start_runs_to_the_steady_state_point() -> None:
    power = np.array([60.0, 80.0, 70.0])
    env = np.stack([ALT, MACH, DT], axis=1)
    ss = steady_state(env, power=power, health=HEALTH)
    x0 = ss.x * np.array([1.02, 0.98, 1.0, 1.0])  # spools off their balance
    res = simulate(_hold(power), 25.0, health=HEALTH, x0=x0, record_every=100)
    assert np.max(np.abs(res.x[0, :, 0] / ss.x[:, 0] - 1.0)) > 0.01
    # Spools and controller at rest; the metal temperatures, disturbed by the
    # transient's heat flows, still soak back (time constants of minutes, see
    # the slow test for the full rest).
    np.testing.assert_allclose(res.x[-1, :, :2], ss.x[:, :2], rtol=3e-6)
    np.testing.assert_allclose(res.x[-1, :, 2:], ss.x[:, 2:], rtol=2e-4)
    np.testing.assert_allclose(res.u[-1], ss.u, rtol=1e-4)
    np.testing.assert_allclose(res.sensors[-1], ss.sensors, rtol=2e-4)


@pytest.mark.slow
def test_power_step_runs_to_rest_with_heat_soak() -> None:
    p0, p1 = np.array([40.0, 60.0, 50.0]), np.array([70.0, 85.0, 80.0])
    # The slowest metal mode (about 140 s at cruise) needs a half hour to settle
    # below 1e-6; a 50 ms step keeps that affordable.
    res = simulate(_hold(p0, 1.0, p1), 2000.0, health=HEALTH, dt=0.05, record_every=1000)
    ss = steady_state(np.stack([ALT, MACH, DT], axis=1), power=p1, health=HEALTH)
    np.testing.assert_allclose(res.x[-1], ss.x, rtol=1e-6)
    np.testing.assert_allclose(res.sensors[-1], ss.sensors, rtol=1e-6)


def test_power_step_rests_on_spools_and_soaks_metal_slowly() -> None:
    # Reduced form of the slow test: after 60 s the spools sit on the new point
    # within the heat-soak error, and the metal temperatures move towards it.
    p0, p1 = np.array([40.0, 60.0, 50.0]), np.array([70.0, 85.0, 80.0])
    res = simulate(_hold(p0, 1.0, p1), 30.0, health=HEALTH, dt=0.03, record_every=100)
    ss = steady_state(np.stack([ALT, MACH, DT], axis=1), power=p1, health=HEALTH)
    np.testing.assert_allclose(res.x[-1, :, 0], ss.x[:, 0], rtol=1e-4)
    np.testing.assert_allclose(res.x[-1, :, 1], ss.x[:, 1], rtol=5e-3)
    gap0 = np.abs(res.x[0, :, 2:] - ss.x[:, 2:])
    gap1 = np.abs(res.x[-1, :, 2:] - ss.x[:, 2:])
    assert np.all(gap1 < 0.9 * gap0)


def test_halving_the_step_changes_the_trajectory_little() -> None:
    p0, p1 = np.array([40.0, 60.0, 50.0]), np.array([50.0, 75.0, 62.0])
    a = simulate(_hold(p0, 0.3, p1), 4.0, health=HEALTH, dt=0.015)
    b = simulate(_hold(p0, 0.3, p1), 4.0, health=HEALTH, dt=0.0075, record_every=2)
    assert a.time_s.shape == b.time_s.shape
    np.testing.assert_allclose(a.time_s, b.time_s, atol=1e-12)
    swing = np.ptp(a.x, axis=0)  # [B, 4] excursion of each state
    diff = np.max(np.abs(a.x - b.x), axis=0)
    # Spool speeds: within 1 % of their excursion (the controller's sample
    # rate halves too, so part of the difference is the shorter delay).
    assert np.all(diff[:, :2] <= 0.01 * swing[:, :2])
    assert np.all(diff[:, 2:] <= 0.01 * swing[:, 2:] + 1e-6)
    # Sensors that follow fuel flow without lag (T30, Ps30, T48, T50, Wf) see
    # the controller's zero-order hold directly in the first samples after
    # the step: within 4 % of their excursion there, 1 % after 0.2 s.
    swing_y = np.ptp(a.sensors, axis=0)
    diff_y = np.abs(a.sensors - b.sensors)
    assert np.all(diff_y.max(axis=0) <= 0.04 * swing_y + 1e-9)
    late = a.time_s >= 0.5
    assert np.all(diff_y[late].max(axis=0) <= 0.01 * swing_y + 1e-9)


def test_batch_equals_engine_by_engine() -> None:
    p0, p1 = np.array([40.0, 60.0, 50.0]), np.array([50.0, 75.0, 62.0])
    batch = simulate(_hold(p0, 0.2, p1), 2.0, health=HEALTH, record_every=10)
    for i in range(3):
        sl = slice(i, i + 1)

        def one(t: float, i: int = i, sl: slice = sl) -> OperatingPoint:
            return OperatingPoint(ALT[sl], MACH[sl], DT[sl], (p0 if t < 0.2 else p1)[sl])

        single = simulate(one, 2.0, health=HEALTH[i], record_every=10)
        np.testing.assert_allclose(single.x[:, 0], batch.x[:, i], rtol=1e-8)
        np.testing.assert_allclose(single.sensors[:, 0], batch.sensors[:, i], rtol=1e-8)


def test_noise_is_the_engines_and_deterministic_for_a_seed() -> None:
    power = np.array([60.0, 80.0, 70.0])
    trim = steady_state(np.zeros(3), power=100.0).sensors
    std = noise_std(trim)
    runs = [
        simulate(_hold(power), 3.0, health=HEALTH, noise_std=std, rng=np.random.default_rng(5))
        for _ in range(2)
    ]
    np.testing.assert_array_equal(runs[0].measured, runs[1].measured)
    err = (runs[0].measured - runs[0].sensors).reshape(-1, len(SENSOR_NAMES))
    # Sample standard deviation within its sampling error (about 2.3 % here).
    np.testing.assert_allclose(err.std(axis=0), std, rtol=0.08)
    other = simulate(_hold(power), 3.0, health=HEALTH, noise_std=std, rng=np.random.default_rng(6))
    assert not np.array_equal(other.measured, runs[0].measured)


def test_flight_profile_is_followed() -> None:
    prof = flight_profile()
    start = 115.0  # the last seconds of ground idle, then the throttle moves

    def late(t: float) -> OperatingPoint:
        return condition_at(prof, t + start)

    res = simulate(late, 35.0, record_every=50)
    c = condition_at(prof, res.time_s + start)
    np.testing.assert_allclose(res.condition.alt_ft, c.alt_ft.T, rtol=1e-12)
    np.testing.assert_allclose(res.condition.power_pct, c.power_pct.T, rtol=1e-12)
    # After the throttle moves to take-off power, the fan reaches the take-off point.
    ss = steady_state(np.array([0.0, 0.25, 0.0]), power=100.0)
    np.testing.assert_allclose(res.x[-1, 0, 0], ss.x[0], rtol=5e-3)


def test_one_pass_gas_path_matches_the_converged_solution() -> None:
    p0, p1 = np.array([40.0, 60.0, 50.0]), np.array([55.0, 80.0, 65.0])
    one = simulate(_hold(p0, 0.3, p1), 3.0, health=HEALTH, record_every=4)
    full = simulate(_hold(p0, 0.3, p1), 3.0, health=HEALTH, record_every=4,
                    gas_path_solution="converged")
    swing = np.ptp(full.x, axis=0)
    assert np.all(np.abs(one.x - full.x).max(axis=0) <= 1e-3 * swing + 1e-9)
    # Sensors within a fifth of the smallest noise (0.25 % of trim), the
    # largest differences at the sample where the step kicks the commands.
    np.testing.assert_allclose(one.sensors, full.sensors, rtol=5e-4)
    with pytest.raises(ValueError, match="gas_path_solution"):
        simulate(_hold(p0), 0.1, gas_path_solution="exact")
