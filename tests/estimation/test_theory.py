"""Analytic bias^2, variance, P_q: against simulation, Monte Carlo and the batched path."""

from __future__ import annotations

import numpy as np
import pytest

from estimation import evaluate as ev
from estimation import theory
from estimation.kalman import filter_stream, filter_stream_states
from estimation.theory import (
    SENSOR_NOISE_ONLY,
    WITH_PROCESS_NOISE,
    analytic_errors,
    batched_errors,
    error_problem,
)
from estimation.tuners import design_filter, optimal_tuners
from tests.estimation.models import random_model, reference_model, reference_noise


def _design(seed: int = 0, m: int = 5, qh: float = 1e-2, variance: str = WITH_PROCESS_NOISE):
    model = reference_model()
    noise = reference_noise(model)
    V = np.random.default_rng(seed).standard_normal((m, model.n_health))
    Qh = np.eye(model.n_health) * qh
    return design_filter(model, V, noise["Q"], Qh, noise["Ph"], variance=variance), noise


@pytest.mark.parametrize("variance", [WITH_PROCESS_NOISE, SENSOR_NOISE_ONLY])
def test_batched_errors_equal_the_scipy_path(variance):
    model = reference_model()
    noise = reference_noise(model)
    Qh = np.eye(model.n_health) * 1e-2
    Q = noise["Q"] * 100.0  # process noise large enough to matter
    rng = np.random.default_rng(11)
    V = rng.standard_normal((5, 4, model.n_health))
    weights = rng.uniform(0, 2, model.n_aux)
    problem = error_problem(model, Q, Qh, noise["Ph"], None, weights, variance)
    batch = batched_errors(problem, V)
    for i in range(5):
        d = design_filter(model, V[i], Q, Qh, noise["Ph"], aux_weights=weights, variance=variance)
        t = d.theory
        np.testing.assert_allclose(batch.health_bias2[i], t.health_bias2, rtol=1e-8, atol=1e-12)
        np.testing.assert_allclose(batch.health_variance[i], t.health_variance, rtol=1e-7)
        np.testing.assert_allclose(batch.aux_bias2[i], t.aux_bias2, rtol=1e-8, atol=1e-12)
        np.testing.assert_allclose(batch.aux_variance[i], t.aux_variance, rtol=1e-7)
        assert batch.objective[i] == pytest.approx(d.objective, rel=1e-8)


def test_bias_equals_noise_free_simulation_of_unit_health_shifts():
    d, _ = _design(1)
    model, red = d.model, d.reduced
    p = model.n_health
    # Truth with h = e_j for every j at once (batch over j), no noise, to steady state.
    H = np.eye(p)
    x = np.zeros((p, model.n_states))
    T = 30000
    y = np.zeros((T, p, model.n_sensors))
    for k in range(T):
        y[k] = x @ model.C.T + H @ model.M.T
        x = x @ model.A.T + H @ model.L.T
    est = filter_stream(red, d.gain, y)
    B_h = est.h_hat[-1].T - np.eye(p)  # column j: error of h_hat for h = e_j
    Gz = model.F @ np.linalg.solve(np.eye(model.n_states) - model.A, model.L) + model.N
    B_z = est.z_hat[-1].T - Gz
    np.testing.assert_allclose(np.diag(B_h @ d.Ph @ B_h.T), d.theory.health_bias2, rtol=1e-5)
    np.testing.assert_allclose(np.diag(B_z @ d.Ph @ B_z.T), d.theory.aux_bias2, rtol=1e-5)


def test_variance_and_pq_equal_monte_carlo_within_sampling_error():
    # The simulation below has sensor noise only, so the seeds' formula is the one to match.
    d, _ = _design(2, qh=5e-2, variance=SENSOR_NOISE_ONLY)
    model, red = d.model, d.reduced
    rng = np.random.default_rng(12)
    E, T, chunk = 4000, 1500, 100
    # h = 0 and x = 0: the sensors see noise only, so the estimate's spread is the variance.
    # Filtered in chunks (restarting from the last estimate) to keep memory small.
    x = np.zeros((E, red.A.shape[0]))
    for _ in range(T // chunk):
        y = rng.standard_normal((chunk, E, model.n_sensors)) * model.sensor_noise_std
        x = filter_stream_states(red.A, red.C, d.gain, y, x0=x)[-1]
    q = x[:, red.n_states :]
    rho = np.max(np.abs(np.linalg.eigvals(red.A - d.gain @ red.C @ red.A)))
    assert rho**T < 1e-6  # the filter has forgotten its start
    h_var = (q @ red.vstar_pinv.T).var(axis=0)
    # Relative standard error of a variance from E samples: sqrt(2 / E) ~ 2.2 %.
    np.testing.assert_allclose(h_var, d.theory.health_variance, rtol=5 * np.sqrt(2 / E))
    z_var = (x @ red.F.T).var(axis=0)
    np.testing.assert_allclose(z_var, d.theory.aux_variance, rtol=5 * np.sqrt(2 / E))
    Pq_mc = np.cov(q.T)
    scale = np.sqrt(np.outer(np.diag(d.P_q), np.diag(d.P_q)))
    assert np.max(np.abs(Pq_mc - d.P_q) / scale) < 5 * np.sqrt(2 / E)


def test_as_many_tuners_as_identifiable_health_parameters_has_no_bias():
    # 4 health parameters, 6 sensors: G_y has full column rank, q = h is estimable exactly.
    model = random_model(np.random.default_rng(4), n_health=4, n_sensors=6)
    d = design_filter(model, np.eye(4), np.eye(2) * 1e-4, np.eye(4) * 1e-2, np.eye(4) * 4.0)
    assert np.linalg.matrix_rank(model.steady_state_gains()[0]) == 4
    np.testing.assert_allclose(d.theory.health_bias2, 0.0, atol=1e-18 * 4)
    np.testing.assert_allclose(d.theory.aux_bias2, 0.0, atol=1e-12)
    assert d.theory.ssee_health == pytest.approx(d.theory.health_variance.sum())


def test_theory_dict_sums():
    d, _ = _design(3)
    t = d.theory.to_dict()
    health = t["health"]
    assert t["ssee_health"] == pytest.approx(sum(health["bias2"]) + sum(health["variance"]))
    assert t["ssee_aux"] == pytest.approx(sum(t["aux"]["bias2"]) + sum(t["aux"]["variance"]))
    assert t["health"]["names"] == d.model.health_names


def test_joint_variance_reduces_to_the_seed_formula_without_process_noise():
    model = reference_model()
    noise = reference_noise(model)
    V = np.random.default_rng(5).standard_normal((5, model.n_health))
    Qh = np.eye(model.n_health) * 1e-2
    d = design_filter(model, V, noise["Q"], Qh, noise["Ph"])
    # Joint Lyapunov with Q = 0 (forced through joint_covariance) against scipy on Phi alone.
    joint = theory.joint_covariance(model, d.reduced, d.gain, np.zeros_like(noise["Q"]))
    seed = analytic_errors(model, d.reduced, d.gain, d.Ph, SENSOR_NOISE_ONLY)
    nx = model.n_states
    np.testing.assert_allclose(joint[nx:, nx:], seed.P_hat, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(joint[:nx], 0.0, atol=1e-15)
    # With Q > 0 the plant block is the plant's own Lyapunov solution X = A X A^T + Q.
    full = theory.joint_covariance(model, d.reduced, d.gain)
    X = full[:nx, :nx]
    np.testing.assert_allclose(X, model.A @ X @ model.A.T + noise["Q"], rtol=1e-9, atol=1e-15)
    assert np.all(d.theory.health_variance > seed.theory.health_variance)


@pytest.fixture(scope="module")
def cruise_design():
    """Optimal tuners on the built-in engine's cruise model (4 states: spools and metal
    temperatures), seed 002's six sensors; Ph = 0 so the squared error is the variance."""
    from estimation.engine.linearize import linearize

    model = linearize(35000.0, 0.8, 85.0)
    sensors = ["Nf", "Nc", "T24", "Ps30", "T30", "T48"]  # seed 002 Table 2
    dm = model.select_sensors(sensors).select_health(model.health_names[:10])
    nx = dm.n_states
    d = optimal_tuners(dm, 6, np.eye(nx) * 1e-4, np.eye(10) * 1e-4, np.eye(10) * 4.0)
    return design_filter(dm, d.vstar, d.Q, d.Qh, np.zeros((10, 10)))


def test_variance_with_process_noise_matches_monte_carlo_per_parameter(cruise_design):
    """Theory with process noise (joint Lyapunov) against a Monte Carlo plant WITH process
    noise, per health parameter, within sampling error; the seeds' sensor-only formula
    is rejected on the same data."""
    d = cruise_design
    exp = ev.ssee_monte_carlo(
        d, 3000, rng=np.random.default_rng(40), duration=2.0, window=2.0, start="steady"
    )
    np.testing.assert_array_equal(exp.theory_variance, d.theory.health_variance)
    assert np.all(exp.theory_bias2 == 0.0)
    z = (exp.squared_error - exp.theory_variance) / exp.standard_error
    assert np.all(exp.standard_error < 0.03 * exp.squared_error)  # tight enough to decide
    assert np.all(np.abs(z) < 4.0), z
    seed = analytic_errors(d.model, d.reduced, d.gain, d.Ph, SENSOR_NOISE_ONLY).theory
    z_seed = (exp.squared_error - seed.health_variance) / exp.standard_error
    assert np.sum(z_seed > 6.0) >= 5, z_seed  # process noise adds 20-50 % to most
    # Without process noise in the plant the experiment compares with the seeds' formula.
    exp0 = ev.ssee_monte_carlo(
        d, 3000, rng=np.random.default_rng(41), duration=2.0, window=2.0, start="steady",
        process_noise=False,
    )
    np.testing.assert_allclose(exp0.theory_variance, seed.health_variance, rtol=1e-9)
    assert np.all(np.abs(exp0.squared_error - seed.health_variance) < 4.0 * exp0.standard_error)


def test_batched_errors_mark_a_singular_design_nan_and_evaluate_the_rest():
    model = reference_model()
    noise = reference_noise(model)
    rng = np.random.default_rng(13)
    V = rng.standard_normal((3, 4, model.n_health))
    V[1, 2] = 0.0  # a zero tuner row: V V^T exactly singular
    problem = error_problem(model, noise["Q"], noise["Qh"], noise["Ph"])
    batch = batched_errors(problem, V)
    assert np.isnan(batch.objective[1])
    for i in (0, 2):
        d = design_filter(model, V[i], noise["Q"], noise["Qh"], noise["Ph"])
        assert batch.objective[i] == pytest.approx(d.objective, rel=1e-8)


def test_information_floor_is_the_posterior_of_stacked_snapshots() -> None:
    """One sensor, one parameter: 1 / sqrt(N g^2 / s^2 + 1 / prior^2); two points add."""
    floor = theory.information_floor([np.array([[2.0]])], [np.array([0.5])], np.array([0.4]), 9)
    assert floor[0] == pytest.approx(1.0 / np.sqrt(9 * 16.0 + 1 / 0.16))
    two = theory.information_floor([np.array([[2.0]]), np.array([[1.0]])],
                                   [np.array([0.5]), np.array([0.5])], np.array([0.4]), 9)
    assert two[0] == pytest.approx(1.0 / np.sqrt(9 * (16.0 + 4.0) + 1 / 0.16))


def test_the_built_in_engine_cannot_tell_hpc_flow_from_vsv_rigging_in_any_phase() -> None:
    """The built-in engine's take-off, climb and cruise together, the eleven sensors of the
    demo's designs, the fleet's scatter (0.4 %) and rigging (Wf 0.5, VSV 1, VBV 2 %) as prior:
    HPC efficiency is known to a few hundredths of a percent after 1,000 records of each phase,
    while HPC flow capacity stays near 0.24 % even after a million: one mix of it and the VSV
    rigging no phase sees, so each engine carries that part of its hpc_flow level for life
    (docs/math.md section 15). The fuel-metering bias, unlike it, is observable across phases."""
    from estimation.engine.fleet import FleetConfig
    from estimation.engine.health import HEALTH_NAMES
    from estimation.engine.linearize import linearize

    gains, noise = [], []
    for alt, mach, power in ((0.0, 0.25, 95.0), (20000.0, 0.6, 92.0), (35000.0, 0.8, 80.0)):
        model = linearize(alt, mach, power)
        keep = [i for i, s in enumerate(model.sensors) if s.name != "Wf"]
        gains.append(model.steady_state_gains()[0][keep])
        noise.append(np.asarray(model.sensor_noise_std)[keep])
    cfg = FleetConfig()
    prior = np.r_[np.full(10, cfg.scatter_std), cfg.bias_std]
    k = {n: i for i, n in enumerate(HEALTH_NAMES)}
    floor = theory.information_floor(gains, noise, prior, 1000)
    assert floor[k["hpc_eff"]] < 0.05 and floor[k["hpt_flow"]] < 0.05
    assert floor[k["wf_bias"]] < 0.05
    assert 0.2 < floor[k["hpc_flow"]] < 0.3 and floor[k["vsv_bias"]] > 0.7
    forever = theory.information_floor(gains, noise, prior, 1_000_000)
    assert forever[k["hpc_flow"]] > 0.2 and forever[k["hpc_eff"]] < 0.002
