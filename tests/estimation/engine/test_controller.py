"""The controller: fixed point at the steady state, limits, batch, closed-loop steps."""

from __future__ import annotations

from typing import Any

import numpy as np

from estimation.engine.actuators import demanded_corrected_fan_speed, vbv_schedule, vsv_schedule
from estimation.engine.atmosphere import flight_condition
from estimation.engine.controller import (
    ControllerGains,
    ControllerState,
    control_step,
    corrected_core_speed,
    initial_state,
    power_from_pla,
    ratio_unit_limits,
    scalar_control_law,
)
from estimation.engine.design import engine_design
from estimation.engine.flight import OperatingPoint
from estimation.engine.steady import steady_state
from estimation.engine.transient import simulate
from estimation.engine.xp import SCALAR

NF, NC, T24, PS30 = 0, 1, 2, 5
ENV = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 15.0], [20000.0, 0.6, -5.0], [35000.0, 0.84, 0.0]])
POWER = np.array([5.0, 60.0, 85.0, 70.0])


def _steady():
    health = np.zeros((4, 13))
    health[1, 4:6] = -2.0  # an HPC fault, seed 002 Table 3
    health[3, 10] = 3.0  # a fuel-flow bias
    return steady_state(ENV, power=POWER, health=health)


def test_controller_holds_the_steady_state_solvers_point() -> None:
    ss = _steady()
    y = ss.sensors
    state = initial_state(ss.u[:, 0], y[:, NF], y[:, NC], y[:, T24], y[:, PS30])
    fc = flight_condition(ENV[:, 0], ENV[:, 1], ENV[:, 2])
    new, out = control_step(state, POWER, ENV[:, 1], fc.theta, fc.delta, y[:, NF], y[:, NC],
                            y[:, T24], y[:, PS30], 0.015)
    # Zero speed error, commands equal the solver's Wf and scheduled VSV/VBV.
    np.testing.assert_allclose(out.error, 0.0, atol=1e-12)
    np.testing.assert_allclose(out.u, ss.u, rtol=1e-11)
    np.testing.assert_allclose(new.integrator, state.integrator, rtol=1e-13)
    np.testing.assert_allclose(out.nrc_rel, ss.stations["n_hpc"], rtol=1e-12)
    assert np.all(out.limited == 0)


def test_batch_equals_engine_by_engine() -> None:
    rng = np.random.default_rng(0)
    b = 6
    d = engine_design()
    raw = np.empty((b, 4))  # filter states: set below to the measurements
    state = ControllerState(rng.uniform(0.6, 1.1, b), raw)
    power, mach, theta = rng.uniform(0, 100, b), rng.uniform(0, 0.8, b), rng.uniform(0.8, 1.1, b)
    delta = rng.uniform(0.3, 1.0, b)
    nf, nc = rng.uniform(1000, 2400, b), rng.uniform(6000, 9100, b)
    t24, ps30 = rng.uniform(520, 650, b), rng.uniform(100, 550, b)
    raw[:] = np.stack([nf, nc, t24, ps30], axis=1)
    new, out = control_step(state, power, mach, theta, delta, nf, nc, t24, ps30, 0.015)
    for i in range(b):
        one = slice(i, i + 1)
        n1, o1 = control_step(ControllerState(state.integrator[one], raw[one]), power[one],
                              mach[one], theta[one], delta[one], nf[one], nc[one], t24[one],
                              ps30[one], 0.015)
        np.testing.assert_allclose(o1.u[0], out.u[i], rtol=1e-14)
        np.testing.assert_allclose(n1.integrator[0], new.integrator[i], rtol=1e-14)
        np.testing.assert_allclose(n1.sensed[0], new.sensed[i], rtol=1e-14)
    # Schedules on corrected core speed, written out independently.
    nrc = nc / np.sqrt(t24 / 1.8 / d.t24) / d.nc
    np.testing.assert_allclose(corrected_core_speed(nc, t24), nrc, rtol=1e-14)
    np.testing.assert_allclose(out.u[:, 1], vsv_schedule(nrc), rtol=1e-14)
    np.testing.assert_allclose(out.u[:, 2], vbv_schedule(nrc), rtol=1e-14)
    # Fuel flow is the (limited) ratio units times Ps30.
    np.testing.assert_allclose(out.u[:, 0], out.ru * ps30, rtol=1e-14)
    assert np.all((out.ru >= out.ru_min - 1e-15) & (out.ru <= out.ru_max + 1e-15))


def _step(p0: np.ndarray, p1: np.ndarray, alt: np.ndarray, mach: np.ndarray, t_step: float):
    z = np.zeros_like(alt)
    return lambda t: OperatingPoint(alt, mach, z, p0 if t < t_step else p1)


def test_closed_loop_step_settles_on_the_commanded_fan_speed() -> None:
    alt = np.array([0.0, 0.0, 35000.0])
    mach = np.array([0.0, 0.0, 0.84])
    p0, p1 = np.array([40.0, 90.0, 50.0]), np.array([50.0, 80.0, 60.0])
    res = simulate(_step(p0, p1, alt, mach, 0.3), 15.0, record_every=10)
    d = engine_design()
    fc = flight_condition(alt, mach)
    target = demanded_corrected_fan_speed(p1, d.nf, mach) * np.sqrt(fc.theta)
    start = res.x[0, :, 0]
    # Within 1 % of the step after 7 s, 0.01 % of the speed at the end.
    t7 = np.searchsorted(res.time_s, 7.0)
    assert np.all(np.abs(res.x[t7:, :, 0] - target) <= 1e-2 * np.abs(target - start))
    np.testing.assert_allclose(res.x[-1, :, 0], target, rtol=1e-4)
    # The spool speeds and fuel flow approach the new steady state (metal still soaking).
    ss = steady_state(np.stack([alt, mach, 0 * alt], 1), power=p1)
    np.testing.assert_allclose(res.x[-1, :, 1], ss.x[:, 1], rtol=2e-3)
    np.testing.assert_allclose(res.u[-1, :, 0], ss.u[:, 0], rtol=2e-2)


def test_limits_clip_and_the_integrator_does_not_wind_up() -> None:
    d = engine_design()
    gains = ControllerGains(sensor_tau=0.0)  # the PI logic alone, no sensor filter
    one = np.ones(2)
    nf = np.array([1100.0, 2300.0])
    nc, t24, ps30 = np.array([6500.0, 8900.0]), np.array([560.0, 640.0]), np.array([130.0, 500.0])
    state = ControllerState(np.array([0.65, 0.95]), np.stack([nf, nc, t24, ps30], axis=1))
    # Slam to take-off on the first engine, chop to idle on the second.
    power = np.array([100.0, 0.0])
    new, out = control_step(state, power, 0 * one, one, one, nf, nc, t24, ps30, 0.015, gains)
    lo, hi = ratio_unit_limits(corrected_core_speed(nc, t24), gains)
    assert list(out.limited) == [1, -1]
    np.testing.assert_allclose(out.ru, [hi[0], lo[1]], rtol=1e-14)
    np.testing.assert_allclose(out.u[:, 0], out.ru * ps30, rtol=1e-14)
    # Back-calculation: the integrator is where the limited output leaves it
    # (I + kp e = RU_limit), and it stays there while the limit holds.
    ratio = (new.integrator + gains.kp * out.error) / out.ru
    np.testing.assert_allclose(ratio, ratio[0], rtol=1e-13)
    again, out2 = control_step(new, power, 0 * one, one, one, nf, nc, t24, ps30, 0.015, gains)
    np.testing.assert_allclose(again.integrator, new.integrator, rtol=1e-13)
    np.testing.assert_allclose(out2.ru, out.ru, rtol=1e-13)
    # The first sample with a smaller error leaves the limit at once.
    demand = demanded_corrected_fan_speed(power, d.nf, 0.0)
    closer = demand - 0.95 * (demand - nf)
    _, out3 = control_step(new, power, 0 * one, one, one, closer, nc, t24, ps30, 0.015, gains)
    assert np.all(out3.limited == 0)


def test_slam_and_chop_ride_the_limits_without_overshoot() -> None:
    alt = np.zeros(2)
    mach = np.zeros(2)
    p0, p1 = np.array([0.0, 100.0]), np.array([100.0, 0.0])  # slam and chop
    res = simulate(_step(p0, p1, alt, mach, 0.1), 15.0, record_every=2)
    lim = res.limited
    assert np.any(lim[:, 0] == 1) and np.any(lim[:, 1] == -1)
    d = engine_design()
    assert res.x[:, 0, 0].max() <= 1.02 * d.nf
    ss = steady_state(np.zeros((2, 3)), power=p1)
    np.testing.assert_allclose(res.x[-1, :, 0], ss.x[:, 0], rtol=2e-3)


def test_power_lever_angle_maps_onto_the_power_setting() -> None:
    pla = np.array([0.0, 20.0, 35.0, 50.0, 80.0, 90.0])
    expect = np.interp(pla, [20.0, 80.0], [0.0, 100.0])
    np.testing.assert_allclose(power_from_pla(pla), expect, rtol=1e-14)


def test_scalar_law_equals_control_step_on_floats_and_arrays() -> None:
    # Free, on the acceleration limit and on the deceleration limit (integrators
    # far above and below the steady RU), over the envelope and both filter settings.
    rng = np.random.default_rng(3)
    b = 40
    integ = rng.choice([0.05, 0.8, 1.0, 5.0], b) * rng.uniform(0.9, 1.1, b)
    power, mach, theta = rng.uniform(0, 100, b), rng.uniform(0, 0.9, b), rng.uniform(0.7, 1.2, b)
    delta = rng.uniform(0.2, 1.2, b)
    meas = np.stack([rng.uniform(800, 2500, b), rng.uniform(5000, 9300, b),
                     rng.uniform(500, 660, b), rng.uniform(60, 560, b)], axis=1)
    raw = meas * rng.uniform(0.97, 1.03, (b, 4))
    for gains in (ControllerGains(), ControllerGains(sensor_tau=0.0, kp=2.0)):
        generic: Any = control_step  # floats where the annotations say arrays
        new, out = generic(ControllerState(integ, raw), power, mach, theta, delta,
                           *meas.T, 0.015, gains)
        law = scalar_control_law(0.015, gains)
        for i in range(b):
            args = [float(v[i]) for v in (power, mach, theta, delta)] + meas[i].tolist()
            integ1, sensed1, u1, lim1 = law(float(integ[i]), raw[i].tolist(), *args)
            n0, o0 = generic(ControllerState(float(integ[i]), raw[i].tolist()),  # type: ignore[arg-type]
                             *args, 0.015, gains, None, SCALAR)
            # The same floats as the generic law on floats ...
            assert (integ1, sensed1, u1, lim1) == (n0.integrator, n0.sensed, o0.u, o0.limited)
            # ... and as the batch (numpy) law to rounding.
            np.testing.assert_allclose(u1, out.u[i], rtol=1e-13)
            np.testing.assert_allclose(integ1, new.integrator[i], rtol=1e-13)
            np.testing.assert_allclose(sensed1, new.sensed[i], rtol=1e-15)
            assert lim1 == out.limited[i]
        assert {-1, 0, 1} <= set(out.limited.tolist())
