"""One engine on Python floats (transient_one.py) against the numpy batch path."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimation.engine.atmosphere import flight_condition
from estimation.engine.design import engine_design
from estimation.engine.flight import OperatingPoint, flight_profile
from estimation.engine.health import health_vector
from estimation.engine.sensors import noise_std
from estimation.engine.steady import steady_state
from estimation.engine.transient import simulate
from estimation.engine.transient_one import ScalarGasPath
from estimation.engine.turbofan import gas_path, gas_path_columns, operating
from estimation.engine.xp import SCALAR, SCALAR_ERRORS
from estimation.isolation import SEED_002_FAULTS

HPC = next(f for f in SEED_002_FAULTS if f.name == "HPC")
HEALTH = health_vector(dict(HPC.shifts) | {"wf_bias": 1.0, "vsv_bias": -2.0, "vbv_bias": -5.0})
STD = noise_std(steady_state(np.zeros(3), power=100.0).sensors)
FIELDS = ("x", "u", "sensors", "measured", "aux")


def _assert_same(fast, batch, row: int = 0, rtol: float = 1e-8, fast_row: int = 0) -> None:
    for name in FIELDS:
        a, b = getattr(fast, name)[:, fast_row], getattr(batch, name)[:, row]
        np.testing.assert_allclose(a, b, rtol=rtol, atol=1e-12, err_msg=name)
    np.testing.assert_array_equal(fast.limited[:, fast_row], batch.limited[:, row])
    for a, b in zip(fast.condition, batch.condition, strict=True):
        np.testing.assert_allclose(a[:, fast_row], b[:, row], rtol=1e-14)


def test_scalar_path_follows_the_batch_through_a_throttle_slam_with_noise() -> None:
    # A slam from 10 % to take-off power: the one-pass gas path's full solves,
    # the acceleration limit and the noisy controller.
    def slam(t: float) -> OperatingPoint:
        return OperatingPoint(np.array([1000.0]), np.array([0.1]), np.array([3.0]),
                              np.array([10.0 if t < 0.3 else 100.0]))

    rngs = [np.random.default_rng(7), np.random.default_rng(7)]
    runs = [
        simulate(slam, 6.0, health=HEALTH, noise_std=STD, rng=rng, record_every=3,
                 scalar_path=scalar)
        for scalar, rng in zip((True, False), rngs, strict=True)
    ]
    assert np.ptp(runs[1].x[:, 0, 0]) > 100.0  # the fan really accelerates
    assert (runs[1].limited != 0).any()
    _assert_same(*runs)
    # Both drew the same noise, and as much of it: the generators go on alike.
    assert rngs[0].standard_normal() == rngs[1].standard_normal()


def test_scalar_path_equals_a_row_of_a_batch_on_a_flight_profile() -> None:
    # A two-engine batch (the vectorised fleet path) against one engine alone,
    # over the profile's start and the converged gas-path mode; 250 steps reach
    # the Jacobian refresh.
    prof2 = flight_profile()._replace(dtamb_k=np.array([5.0]))
    batch_prof = prof2._replace(
        alt_ft=np.repeat(prof2.alt_ft, 2, axis=0), mach=np.repeat(prof2.mach, 2, axis=0),
        power_pct=np.repeat(prof2.power_pct, 2, axis=0), dtamb_k=np.array([5.0, -10.0]),
    )
    h2 = np.stack([HEALTH, np.zeros(13)])
    for mode in ("one_pass", "converged"):
        fast = simulate(prof2, 3.75, health=HEALTH, record_every=5, gas_path_solution=mode)
        batch = simulate(batch_prof, 3.75, health=h2, record_every=5, gas_path_solution=mode,
                         scalar_path=False)
        _assert_same(fast, batch)


def test_a_small_batch_on_floats_equals_the_numpy_batch_row_by_row_with_noise() -> None:
    # Three engines of different health and ambient on the profile's start, past a
    # block of steps (the engines advance on floats block by block, each block's
    # noise drawn for all of them at once): each row equals the numpy batch's, and
    # both drew the same noise.
    prof = flight_profile()
    prof3 = prof._replace(
        alt_ft=np.repeat(prof.alt_ft[:1], 3, axis=0), mach=np.repeat(prof.mach[:1], 3, axis=0),
        power_pct=np.repeat(prof.power_pct[:1], 3, axis=0), dtamb_k=np.array([5.0, -10.0, 0.0]))
    h3 = np.stack([HEALTH, np.zeros(13), -0.5 * HEALTH])
    rngs = [np.random.default_rng(11), np.random.default_rng(11)]
    fast, batch = (simulate(prof3, 16.0, health=h3, noise_std=STD, rng=rng, record_every=7,
                            scalar_path=floats)
                   for floats, rng in zip((True, False), rngs, strict=True))
    assert fast.time_s.size == batch.time_s.size > 1000 // 7
    for row in range(3):
        _assert_same(fast, batch, row, fast_row=row)
    assert rngs[0].standard_normal() == rngs[1].standard_normal()


def test_scalar_cycle_equals_the_numpy_cycle_and_falls_back_where_math_fails() -> None:
    d = engine_design()
    env = np.array([[20000.0, 0.6, -5.0]])
    ss = steady_state(env, power=np.array([70.0]), health=HEALTH[None])
    x, u, z = ss.x.reshape(1, 4) * [1.01, 0.99, 1.0, 1.0], ss.u.reshape(1, 3), ss.inner
    op = operating(x, u, env, HEALTH[None])
    fc = flight_condition(*env[0], xp=SCALAR)
    op1 = op._replace(nf=float(x[0, 0]), nc=float(x[0, 1]), tm_hpc=float(op.tm_hpc[0]),
                      tm_hpt=float(op.tm_hpt[0]), wf=float(op.wf[0]), vsv=float(u[0, 1]),
                      vbv=float(u[0, 2]), fc=fc, h=None)
    solver = ScalarGasPath(d, (HEALTH / 100.0).tolist(), 2e-6, 1e-12, 6,
                           3e-4, 200, 1e-7)
    z_in = np.reshape(z, (1, 5))
    res, st = gas_path(op, z_in, d)
    res1, st1 = solver.evaluate(op1, z_in[0].tolist())
    np.testing.assert_allclose(res1, res[0], rtol=0, atol=1e-13)
    for key, val in st.items():
        np.testing.assert_allclose(st1[key], val[0], rtol=1e-12, atol=1e-12, err_msg=key)
    # An HPC beta deep beyond choke drives the HPC pressure ratio
    # negative: math raises, numpy gives nan, and the scalar path returns numpy's.
    bad = z_in.copy()
    bad[0, 2] = -40.0
    with np.errstate(all="ignore"):
        res_np = gas_path(op, bad, d)[0][0]
    with pytest.raises(SCALAR_ERRORS):  # what the scalar cycle alone does
        gas_path_columns(op1, bad[0].tolist(), solver.hs, d, True, False, SCALAR)
    res_bad = solver.evaluate(op1, bad[0].tolist())[0]
    assert any(math.isnan(r) for r in res_bad)
    np.testing.assert_array_equal(np.isnan(res_bad), np.isnan(res_np))


def _slam_to_take_off(t: float) -> OperatingPoint:
    return OperatingPoint(np.array([1000.0]), np.array([0.1]), np.array([3.0]),
                          np.array([10.0 if t < 0.3 else 100.0]))


def test_one_pass_stays_well_below_the_sensor_noise_through_a_noisy_slam() -> None:
    # The one-pass gas path (one evaluation per stage at the predicted unknowns)
    # against the gas path converged to 2e-6 at every stage, both with the same
    # sensor noise in the controller, in units of each sensor's noise.
    runs = [simulate(_slam_to_take_off, 8.0, noise_std=STD, rng=np.random.default_rng(3),
                     record_every=2, gas_path_solution=mode)
            for mode in ("one_pass", "converged")]
    assert np.ptp(runs[1].x[:, 0, 1]) > 1000.0  # the core really accelerates
    gap = np.abs(runs[0].sensors - runs[1].sensors)[:, 0].max(axis=0) / STD
    assert np.all(gap < 0.1), (int(gap.argmax()), float(gap.max()))
    np.testing.assert_array_less(np.abs(runs[0].x - runs[1].x)[:, 0].max(axis=0),
                                 [2.0, 2.0, 0.05, 0.05])  # rpm, degR


def test_one_pass_adds_nothing_to_the_step_size_error_through_a_slam() -> None:
    # Halving the step (and the controller's sample period with it) moves the
    # sensors by up to about 1.3 noise standard deviations at the slam (mostly
    # the controller's zero-order hold); the one-pass gas path at 15 ms must sit
    # as close to the 7.5 ms converged run as the 15 ms converged run does,
    # within a tenth of the noise.
    full, one = (simulate(_slam_to_take_off, 8.0, record_every=2, gas_path_solution=m)
                 for m in ("converged", "one_pass"))
    half = simulate(_slam_to_take_off, 8.0, dt=0.0075, record_every=4,
                    gas_path_solution="converged")
    np.testing.assert_allclose(half.time_s, full.time_s, atol=1e-12)
    step_err = np.abs(full.sensors - half.sensors)[:, 0].max(axis=0) / STD
    one_err = np.abs(one.sensors - half.sensors)[:, 0].max(axis=0) / STD
    assert np.all(step_err < 2.0)
    assert np.all(one_err <= step_err + 0.1)


@pytest.mark.slow
def test_one_pass_against_converged_and_halved_step_over_seed001_take_off() -> None:
    # The busiest 300 s of seed 001's flight (ground idle, slam, take-off, climb),
    # as the two slam tests above do it: with noise against the converged gas path,
    # without noise against a halved step.
    prof = flight_profile()
    one, full = (simulate(prof, 300.0, noise_std=STD, rng=np.random.default_rng(3),
                          record_every=2, gas_path_solution=m)
                 for m in ("one_pass", "converged"))
    gap = np.abs(one.sensors - full.sensors)[:, 0].max(axis=0) / STD
    assert np.all(gap < 0.1), (int(gap.argmax()), float(gap.max()))
    one, full = (simulate(prof, 300.0, record_every=2, gas_path_solution=m)
                 for m in ("one_pass", "converged"))
    half = simulate(prof, 300.0, dt=0.0075, record_every=4, gas_path_solution="converged")
    step_err = np.abs(full.sensors - half.sensors)[:, 0].max(axis=0) / STD
    one_err = np.abs(one.sensors - half.sensors)[:, 0].max(axis=0) / STD
    assert np.all(step_err < 0.5)
    assert np.all(one_err <= step_err + 0.1)
