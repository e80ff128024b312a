"""The stream filter's segment gain where the sensors cannot estimate the tuners."""

from __future__ import annotations

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
