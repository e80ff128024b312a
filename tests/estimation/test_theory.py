"""Analytic bias^2, variance, P_q: against simulation, Monte Carlo and the batched path."""

from __future__ import annotations

import numpy as np
import pytest

from estimation.kalman import filter_stream, filter_stream_states
from estimation.theory import batched_errors, error_problem
from estimation.tuners import design_filter
from tests.estimation.models import random_model, reference_model, reference_noise


def _design(seed: int = 0, m: int = 5, qh: float = 1e-2):
    model = reference_model()
    noise = reference_noise(model)
    V = np.random.default_rng(seed).standard_normal((m, model.n_health))
    Qh = np.eye(model.n_health) * qh
    return design_filter(model, V, noise["Q"], Qh, noise["Ph"]), noise


def test_batched_errors_equal_the_scipy_path():
    model = reference_model()
    noise = reference_noise(model)
    Qh = np.eye(model.n_health) * 1e-2
    rng = np.random.default_rng(11)
    V = rng.standard_normal((5, 4, model.n_health))
    weights = rng.uniform(0, 2, model.n_aux)
    batch = batched_errors(error_problem(model, noise["Q"], Qh, noise["Ph"], None, weights), V)
    for i in range(5):
        d = design_filter(model, V[i], noise["Q"], Qh, noise["Ph"], aux_weights=weights)
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
    d, _ = _design(2, qh=5e-2)
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
