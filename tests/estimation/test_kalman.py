"""Steady-state gain, doubling solvers, and the batched stream filter."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from estimation.errors import UnobservableDesignError
from estimation.kalman import (
    dare_doubling,
    filter_stream,
    filter_stream_states,
    steady_state_gain,
    stein_doubling,
    unobservable_modes,
)
from estimation.model import LinearModel
from estimation.reduced import reduced_model
from estimation.tuners import design_filter
from tests.estimation.models import random_model, reference_model, reference_noise


def _design_matrices(seed: int = 0, m: int = 6):
    model = reference_model()
    noise = reference_noise(model)
    V = np.random.default_rng(seed).standard_normal((m, model.n_health))
    return model, reduced_model(model, V, noise["Q"], np.eye(model.n_health) * 1e-2)


def _riccati_iteration(A, C, Q, R, tol=1e-14, max_iter=500_000):
    """Independent solution: iterate the a-priori covariance recursion to convergence."""
    P = np.eye(A.shape[0])
    for _ in range(max_iter):
        S = C @ P @ C.T + R
        P_new = A @ (P - P @ C.T @ np.linalg.solve(S, C @ P)) @ A.T + Q
        P_new = 0.5 * (P_new + P_new.T)
        if np.max(np.abs(P_new - P)) <= tol * np.max(np.abs(P_new)):
            return P_new
        P = P_new
    raise AssertionError("Riccati recursion did not converge")


@pytest.mark.parametrize("seed", [0, 1])
def test_gain_matches_converged_riccati_recursion(seed):
    model, red = _design_matrices(seed)
    gain = steady_state_gain(red.A, red.C, red.Q, model.R)
    P = _riccati_iteration(red.A, red.C, red.Q, model.R)
    K = P @ red.C.T @ np.linalg.inv(red.C @ P @ red.C.T + model.R)
    np.testing.assert_allclose(gain.K, K, rtol=0, atol=1e-8 * np.abs(K).max())
    np.testing.assert_allclose(gain.P_prior, P, rtol=0, atol=1e-8 * np.abs(P).max())
    rho = np.max(np.abs(np.linalg.eigvals((np.eye(len(K)) - K @ red.C) @ red.A)))
    assert gain.spectral_radius == pytest.approx(rho) and rho < 1


def test_doubling_solvers_match_scipy_for_a_stack():
    stack = [_design_matrices(seed) for seed in range(4)]
    A = np.stack([r.A for _, r in stack])
    C = np.stack([r.C for _, r in stack])
    Q = np.stack([r.Q for _, r in stack])
    R = stack[0][0].R
    P = dare_doubling(A, C, Q, R)
    for i, (_, r) in enumerate(stack):
        ref = scipy.linalg.solve_discrete_are(r.A.T, r.C.T, r.Q, R)
        np.testing.assert_allclose(P[i], ref, rtol=0, atol=1e-9 * np.abs(ref).max())
        K = np.linalg.solve(r.C @ ref @ r.C.T + R, r.C @ ref).T
        Phi = (np.eye(len(K)) - K @ r.C) @ r.A
        W = K @ R @ K.T
        X = stein_doubling(Phi[None], W[None])[0]
        ref_x = scipy.linalg.solve_discrete_lyapunov(Phi, W)
        np.testing.assert_allclose(X, ref_x, rtol=0, atol=1e-9 * np.abs(ref_x).max())


def test_more_tuners_than_sensors_refused():
    model = reference_model().select_sensors(["Nf", "Nc", "T48"])
    noise = reference_noise(model)
    V = np.random.default_rng(0).standard_normal((4, model.n_health))
    with pytest.raises(UnobservableDesignError, match="4 tuners"):
        design_filter(model, V, noise["Q"], noise["Qh"], noise["Ph"])


def test_tuner_invisible_to_sensors_refused_even_when_scipy_returns():
    # Health parameter h1 moves nothing: a tuner equal to it is unobservable.
    base = random_model(np.random.default_rng(5), n_health=4, n_sensors=5)
    d = base.to_dict()
    for name in ("L", "M"):
        for row in d["matrices"][name]:
            row[0] = 0.0
    model = LinearModel.from_dict(d)
    V = np.eye(4)[:2]
    red = reduced_model(model, V, np.eye(2) * 1e-4, np.eye(4) * 1e-2)
    assert unobservable_modes(red.A, red.C)  # the PBH test sees it
    # The trap: scipy (1.17) returns a solution here without raising, and its gain does
    # not stabilise the filter.
    try:
        P = scipy.linalg.solve_discrete_are(red.A.T, red.C.T, red.Q, model.R)
    except (np.linalg.LinAlgError, ValueError):
        P = None
    if P is not None:
        K = np.linalg.solve(red.C @ P @ red.C.T + model.R, red.C @ P).T
        closed = (np.eye(len(K)) - K @ red.C) @ red.A
        assert np.max(np.abs(np.linalg.eigvals(closed))) > 1 - 1e-9
    with pytest.raises(UnobservableDesignError, match="cannot observe"):
        steady_state_gain(red.A, red.C, red.Q, model.R)


def test_tuner_without_random_walk_is_not_stabilising():
    model, red = _design_matrices(0, m=3)
    Q = red.Q.copy()
    Q[2:, 2:] = 0.0  # no tuner noise: the filter gain on q tends to zero
    with pytest.raises(UnobservableDesignError, match="not stabilising|no stabilising"):
        steady_state_gain(red.A, red.C, Q, model.R)


def _sequential(A, B, C, D, K, y, u):
    """Reference: one engine at a time, predict then update, written out."""
    T, E, _ = y.shape
    out = np.zeros((T, E, A.shape[0]))
    for e in range(E):
        x = np.zeros(A.shape[0])
        u_prev = np.zeros(B.shape[1])
        for k in range(T):
            x_pred = A @ x + B @ u_prev
            x = x_pred + K @ (y[k, e] - C @ x_pred - D @ u[k, e])
            u_prev = u[k, e]
            out[k, e] = x
    return out


def test_batch_equals_sequential_with_inputs():
    model, red = _design_matrices(2)
    gain = steady_state_gain(red.A, red.C, red.Q, model.R)
    rng = np.random.default_rng(7)
    y = rng.standard_normal((40, 5, model.n_sensors))
    u = rng.standard_normal((40, 5, model.n_inputs))
    batch = filter_stream(red, gain.K, y, u)
    ref = _sequential(red.A, red.B, red.C, red.D, gain.K, y, u)
    np.testing.assert_allclose(batch.x_hat, ref, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(batch.h_hat, ref[..., 2:] @ red.vstar_pinv.T, rtol=1e-10)
    np.testing.assert_allclose(batch.z_hat, ref @ red.F.T + u @ red.G.T, rtol=1e-10, atol=1e-12)


def test_stream_restart_equals_uninterrupted():
    model, red = _design_matrices(3)
    gain = steady_state_gain(red.A, red.C, red.Q, model.R)
    rng = np.random.default_rng(8)
    y = rng.standard_normal((60, 4, model.n_sensors))
    u = rng.standard_normal((60, 4, model.n_inputs))
    whole = filter_stream_states(red.A, red.C, gain.K, y, u, red.B, red.D)
    first = filter_stream_states(red.A, red.C, gain.K, y[:25], u[:25], red.B, red.D)
    second = filter_stream_states(
        red.A, red.C, gain.K, y[25:], u[25:], red.B, red.D, x0=first[-1], u_prev=u[24]
    )
    np.testing.assert_allclose(np.concatenate([first, second]), whole, rtol=1e-12, atol=1e-13)


def test_noise_free_stream_settles_at_the_analytic_steady_state():
    model, red = _design_matrices(4)
    gain = steady_state_gain(red.A, red.C, red.Q, model.R)
    Gy, _ = model.steady_state_gains()
    h = np.random.default_rng(9).normal(0, 2, (3, model.n_health))
    # Truth: the full model with constant h, simulated to steady state (x[k+1] = A x + L h).
    x = np.zeros((3, model.n_states))
    T = 20000
    y = np.zeros((T, 3, model.n_sensors))
    for k in range(T):
        y[k] = x @ model.C.T + h @ model.M.T
        x = x @ model.A.T + h @ model.L.T
    est = filter_stream(red, gain.K, y)
    n = red.A.shape[0]
    Gamma_K_Gy = np.linalg.solve(np.eye(n) - (np.eye(n) - gain.K @ red.C) @ red.A, gain.K @ Gy)
    np.testing.assert_allclose(est.x_hat[-1], h @ Gamma_K_Gy.T, rtol=1e-6, atol=1e-8)


def test_solve_or_nan_gives_nan_only_for_singular_batch_elements():
    from estimation.kalman import solve_or_nan

    rng = np.random.default_rng(3)
    a = rng.standard_normal((4, 3, 3))
    a[2, :, 1] = 0.0  # exactly singular
    b = rng.standard_normal((4, 3, 2))
    out = solve_or_nan(a, b)
    assert np.all(np.isnan(out[2]))
    for i in (0, 1, 3):
        np.testing.assert_allclose(a[i] @ out[i], b[i], atol=1e-10)
    # Without a singular element it is np.linalg.solve itself.
    good_a, good_b = a[[0, 1]], b[[0, 1]]
    np.testing.assert_array_equal(solve_or_nan(good_a, good_b), np.linalg.solve(good_a, good_b))
