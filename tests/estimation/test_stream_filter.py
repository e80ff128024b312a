"""The stream filter's segment gain where the sensors cannot estimate the tuners."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from estimation.stream_filter import filter_run, segment_gain
from estimation.tuners import svd_vstar
from tests.estimation.models import reference_model, reference_noise


def test_a_segment_whose_tuners_are_unobservable_runs_on_the_prediction_alone() -> None:
    """Seven tuners from six sensors: no stabilising steady-state gain. The segment keeps the
    model's prediction (K = 0: the tuners hold, the spool states follow the inputs) and says
    its 1-sigma are not estimated (NaN) instead of failing the recording; six tuners still
    get a gain."""
    model = reference_model()
    noise = reference_noise(model)
    for m, observable in ((6, True), (7, False)):
        vstar = svd_vstar(model, m)
        Vp = np.linalg.solve(vstar @ vstar.T, vstar).T
        g = segment_gain(model, vstar, Vp, noise["Q"], noise["Qh"], model.dt)
        assert g.K.any() == observable
        assert np.isnan(g.sigma).all() != observable
    rng = np.random.default_rng(4)
    n = g.A.shape[0]
    x0, u0 = rng.normal(size=n), rng.normal(size=model.n_inputs)
    ys = rng.normal(size=(50, model.n_sensors))
    us = rng.normal(size=(50, model.n_inputs))
    x = filter_run(g, ys, us, x0, u0)
    expected, x_prev, u_prev = np.empty_like(x), x0, u0
    for k in range(50):
        expected[k] = x_prev = g.A @ x_prev + g.B @ u_prev
        u_prev = us[k]
    np.testing.assert_allclose(x, expected, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(x[:, 2:], np.broadcast_to(x0[2:], (50, n - 2)))


def test_a_gains_run_follows_the_textbook_filter_and_its_own_gain_after_replace() -> None:
    """``filter_run`` (the products of K formed once with the gain) gives the textbook
    prediction-correction recursion sample by sample, a missing sample included; a gain made
    from another by ``replace`` forms its own products (a zero gain predicts only)."""
    model = reference_model()
    noise = reference_noise(model)
    vstar = svd_vstar(model, 4)
    Vp = np.linalg.solve(vstar @ vstar.T, vstar).T
    g = segment_gain(model, vstar, Vp, noise["Q"], noise["Qh"], model.dt)
    rng = np.random.default_rng(7)
    n = g.A.shape[0]
    x0, u0 = rng.normal(size=n), rng.normal(size=model.n_inputs)
    ys = rng.normal(size=(40, model.n_sensors))
    us = rng.normal(size=(40, model.n_inputs))
    ys[17, 3] = np.nan  # not a measurement: the prediction alone there

    def textbook(K: np.ndarray) -> np.ndarray:
        out, x_prev, u_prev = np.empty((40, n)), x0, u0
        for k in range(40):
            pred = g.A @ x_prev + g.B @ u_prev
            if not np.isnan(ys[k]).any():
                pred = pred + K @ (ys[k] - g.C @ pred - g.D @ us[k])
            out[k] = x_prev = pred
            u_prev = us[k]
        return out

    np.testing.assert_allclose(filter_run(g, ys, us, x0, u0), textbook(g.K),
                               rtol=1e-10, atol=1e-12)
    still = replace(g, K=np.zeros_like(g.K))
    assert not still.terms.KT.any()
    np.testing.assert_allclose(filter_run(still, ys, us, x0, u0), textbook(still.K),
                               rtol=1e-12, atol=1e-12)


def test_r_held_at_an_interval_keeps_the_filters_information_per_second_at_every_rate() -> None:
    """With R held at 0.5 s (``noise_interval_s``), the gain at 0.5 s is the one of R per sample,
    bit for bit, and at 10 and 20 Hz the tuners' steady-state 1-sigma stays that of 2 Hz (the
    sensors tell the filter as much per second); with R per sample it shrinks with the rate."""
    model = reference_model()
    noise = reference_noise(model)
    vstar = svd_vstar(model, 4)
    Vp = np.linalg.solve(vstar @ vstar.T, vstar).T

    def gain(dt: float, interval: float | None) -> np.ndarray:
        return segment_gain(model, vstar, Vp, noise["Q"], noise["Qh"], dt, None, interval)

    held = gain(0.5, 0.5)
    per_sample = gain(0.5, None)
    np.testing.assert_array_equal(held.K, per_sample.K)
    np.testing.assert_array_equal(held.sigma, per_sample.sigma)
    for dt in (0.1, 0.05):
        np.testing.assert_allclose(gain(dt, 0.5).sigma[:4], held.sigma[:4], rtol=0.03)
        assert np.all(gain(dt, None).sigma[:4] < 0.75 * held.sigma[:4])
