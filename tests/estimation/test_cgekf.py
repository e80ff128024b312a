"""Constant-gain EKF (seed 001 eq. 4): equivalences, invariants and a short stability run."""

from __future__ import annotations

import numpy as np
import pytest

from estimation.cgekf import (
    LinearPlant,
    cgekf_design,
    filter_flights,
    run_cgekf,
)
from estimation.engine.flight import FlightProfile
from estimation.engine.linearize import linearize
from estimation.engine.sensors import AUX_NAMES, SENSOR_NAMES, noise_std
from estimation.engine.transient import simulate
from estimation.kalman import filter_stream_states, steady_state_gain

DT = 0.05


@pytest.fixture(scope="module")
def design():
    return cgekf_design(dt=DT)


def test_gain_is_the_reduced_models_steady_state_gain(design):
    red = design.reduced
    assert design.K.shape == (red.A.shape[0], len(design.sensors))
    np.testing.assert_allclose(design.K_pred, red.A @ design.K)
    assert design.gain.spectral_radius < 1.0


def test_r_held_at_an_interval_is_r_per_sample_there_and_scaled_elsewhere(design):
    """``noise_interval_s`` (a calibrated design's streams): at its own interval the gain is
    the one of R per sample, bit for bit; at a tenth of it, the gain of R times ten."""
    np.testing.assert_array_equal(cgekf_design(dt=DT, noise_interval_s=DT).K, design.K)
    held = cgekf_design(dt=DT, noise_interval_s=10 * DT)
    red = design.reduced
    scaled = steady_state_gain(red.A, red.C, red.Q, 10.0 * design.model.R)
    np.testing.assert_allclose(held.K, scaled.K, rtol=1e-12, atol=1e-15)
    assert not np.allclose(held.K, design.K)


def test_on_the_linear_plant_equals_the_steady_state_filter(design):
    """CGEKF on the design model itself = kalman.filter_stream_states to rounding."""
    rng = np.random.default_rng(3)
    red = design.reduced
    T, B = 300, 3
    y = rng.normal(0.0, 1.0, (T, B, len(design.sensors)))
    u = rng.normal(0.0, 1.0, (T, B, 3))
    n = red.A.shape[0]
    x0 = rng.normal(0.0, 0.5, (B, n))
    ref = filter_stream_states(red.A, red.C, design.K, y, u=u, B=red.B, D=red.D, x0=x0)
    # x_hat[-1] = x0 and u[-1] = 0: the CGEKF's a-priori start is A x0.
    prior = x0 @ red.A.T
    nx = red.n_states
    res = run_cgekf(design, LinearPlant(design, u), y, prior[:, :nx], prior[:, nx:])
    got = np.concatenate([res.x_hat, res.d_hat], axis=2)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-10 * np.abs(ref).max())
    np.testing.assert_allclose(res.h_hat, res.d_hat @ red.vstar_pinv.T)
    np.testing.assert_allclose(res.z_hat, ref @ red.F.T + u @ red.G.T, atol=1e-9)


def test_health_step_in_tuner_space_converges_to_truth(design):
    """Linear plant with a constant tuner shift and no noise: d_hat -> d."""
    red = design.reduced
    nx, m = red.n_states, red.n_tuners
    d_true = np.linspace(-3.0, 2.0, m)
    s = np.concatenate([np.zeros(nx), d_true])
    # Steady state of x for the true tuners: x = (I - A_x)^-1 L V*^+ d.
    Ax, Lx = red.A[:nx, :nx], red.A[:nx, nx:]
    s[:nx] = np.linalg.solve(np.eye(nx) - Ax, Lx @ d_true)
    y = np.broadcast_to(red.C @ s, (20000, 1, len(design.sensors)))
    res = run_cgekf(design, LinearPlant(design), y, np.zeros((1, nx)))
    np.testing.assert_allclose(res.d_hat[-1, 0], d_true, atol=1e-5)
    assert np.abs(res.residual[-1]).max() < 1e-5


def _one_flight(seconds: float, n: int, health: np.ndarray | None, rng, noise: bool):
    t = np.array([0.0, 20.0, 26.0, seconds])
    prof = FlightProfile(t, np.zeros((n, 4)), np.tile([0.0, 0.0, 0.0, 0.1], (n, 1)),
                         np.tile([0.0, 0.0, 100.0, 100.0], (n, 1)), np.zeros(n))
    ty = np.array([linearize(0.0, 0.0, 100.0, dt=DT).trim[s] for s in SENSOR_NAMES])
    return simulate(prof, seconds, health=health, dt=DT,
                    noise_std=noise_std(ty) if noise else None, rng=rng)


def _run(design, sim):
    idx = [SENSOR_NAMES.index(s) for s in design.sensors]
    zi = [AUX_NAMES.index(a) for a in design.aux]
    c = sim.condition
    env = np.stack([c.alt_ft, c.mach, c.dtamb_k], axis=-1)
    return filter_flights(design, sim.measured[:, :, idx], sim.u, env,
                          z_true=sim.aux[:, :, zi])


def test_zero_noise_nominal_engine_stays_at_the_truth(design):
    """Healthy engine, no noise, idle then a slam to take-off: the on-board model is the
    plant, so the tuners stay near zero and the aux estimates near the truth."""
    sim = _one_flight(40.0, 1, None, np.random.default_rng(0), noise=False)
    res = _run(design, sim)
    idle = sim.time_s < 20.0
    assert np.abs(res.d_hat[idle]).max() < 1e-3
    assert np.abs(res.z_residual[idle]).max() < 1e-2
    # Through the slam the filter's Euler step against the simulator's RK2 leaves a
    # transient mismatch that the tuners take up, a small fraction of a percent.
    assert np.abs(res.d_hat).max() < 0.3
    assert np.abs(res.z_residual).max() < 1.0


def test_degraded_and_biased_engines_stay_stable_short(design):
    """Reduced form of the 200-flight stability check: 8 engines, 40 s with a slam."""
    rng = np.random.default_rng(7)
    n = 8
    h = np.zeros((n, 13))
    sign = -np.ones(10)
    sign[[7, 9]] = 1.0
    h[:4, :10] = sign * rng.uniform(1.0, 5.0, (4, 10))
    h[4:, 10:] = rng.uniform(-10.0, 10.0, (4, 3))
    sim = _one_flight(40.0, n, h, rng, noise=True)
    res = _run(design, sim)
    assert np.isfinite(res.h_hat).all() and np.isfinite(res.z_hat).all()
    assert np.abs(res.d_hat).max() < 50.0
    # The innovations are brought down to the noise level (the tuners absorb the shift).
    late = np.abs(res.residual[-100:]).mean(axis=(0, 2))
    early = np.abs(res.residual[:5]).mean(axis=(0, 2))
    assert (late < 1.0).all()
    assert late.mean() < early.mean()


@pytest.mark.slow
def test_hpc_step_converges_near_truth(design):
    """A -2 % HPC efficiency and flow step (seed 002 fault) on the nonlinear engine at
    take-off power, no noise: the HPC tuners settle near the truth."""
    h = np.zeros(13)
    h[4], h[5] = -2.0, -2.0
    sim = _one_flight(150.0, 1, h, np.random.default_rng(0), noise=False)
    res = _run(design, sim)
    np.testing.assert_allclose(res.h_hat[-1, 0, [4, 5]], [-2.0, -2.0], atol=0.3)


def test_chunks_continue_as_one_run(design):
    """Two chunks, the second from the first's a-priori state, equal one run."""
    rng = np.random.default_rng(5)
    red = design.reduced
    nx = red.n_states
    y = rng.normal(0.0, 1.0, (200, 2, len(design.sensors)))
    u = rng.normal(0.0, 1.0, (200, 2, 3))
    whole = run_cgekf(design, LinearPlant(design, u), y, np.zeros((2, nx)))
    a = run_cgekf(design, LinearPlant(design, u[:80]), y[:80], np.zeros((2, nx)))
    b = run_cgekf(design, LinearPlant(design, u[80:]), y[80:], a.x_next, a.d_next)
    np.testing.assert_array_equal(np.concatenate([a.d_hat, b.d_hat]), whole.d_hat)


def test_one_engine_on_floats_equals_the_batched_run_and_continues_exactly(design):
    """``filter_one`` (one engine on floats) against ``run_cgekf`` with ``EnginePlant`` at
    B = 1 (numpy): the same recursion to rounding, through a slam with noise; two calls, the
    second from the first's state through JSON, equal one call bit for bit; a sensor
    missing at a sample gives a NaN residual and no correction from it."""
    import json

    from estimation.cgekf import EnginePlant, filter_one

    sim = _one_flight(30.0, 1, np.r_[np.full(10, -1.0), np.zeros(3)],
                      np.random.default_rng(11), noise=True)
    idx = [SENSOR_NAMES.index(s) for s in design.sensors]
    c = sim.condition
    env = np.stack([c.alt_ft, c.mach, c.dtamb_k], axis=-1)
    y = sim.measured[:, :, idx]
    plant = EnginePlant(design, sim.u, env)
    batched = run_cgekf(design, plant, y, plant.initial_state())
    one, _ = filter_one(design, y[:, 0], sim.u[:, 0], env[:, 0])
    np.testing.assert_allclose(one.d_hat, batched.d_hat, rtol=0, atol=1e-8)
    np.testing.assert_allclose(one.z_hat, batched.z_hat, rtol=1e-7)
    np.testing.assert_allclose(one.residual, batched.residual, rtol=0, atol=1e-6)
    assert np.abs(one.d_hat[-1]).max() > 0.1  # the tuners moved: the comparison is not 0 = 0
    k = 437  # after the slam, not on a refresh (every 200 samples)
    a, state = filter_one(design, y[:k, 0], sim.u[:k, 0], env[:k, 0])
    state = json.loads(json.dumps(state))
    b, _ = filter_one(design, y[k:, 0], sim.u[k:, 0], env[k:, 0], a.d_next[0], state,
                      a.x_next[0])
    np.testing.assert_array_equal(np.concatenate([a.d_hat, b.d_hat]), one.d_hat)
    np.testing.assert_array_equal(b.x_next, one.x_next)
    gap = y[:, 0].copy()
    gap[300, 2] = np.nan
    holed, _ = filter_one(design, gap, sim.u[:, 0], env[:, 0])
    np.testing.assert_array_equal(holed.d_hat[:300], one.d_hat[:300])
    assert np.isnan(holed.residual[300, 0, 2]) and np.isfinite(holed.d_hat).all()
    # Sample 300 was corrected by the other sensors only: K r with r[2] = 0.
    r = one.residual[300, 0].copy()
    r[2] = 0.0
    nx = design.reduced.n_states
    expected = (one.d_hat[300, 0] - (design.K @ one.residual[300, 0])[nx:]
                + (design.K @ r)[nx:])
    np.testing.assert_allclose(holed.d_hat[300, 0], expected, rtol=0, atol=1e-9)
