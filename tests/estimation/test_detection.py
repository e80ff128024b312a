"""Chi-squared CUSUM: false-alarm rate and detection delay, theory vs Monte Carlo."""

import functools
from collections.abc import Callable

import numpy as np
import pytest

from estimation import detection as det
from estimation import isolation as iso

Detect = Callable[..., det.Detection]


@pytest.fixture(params=["scan", "step"])
def cusum(request: pytest.FixtureRequest) -> Detect:
    """The CUSUM's two implementations: vectorised over sequences (``cusum_scan``) and one
    sample at a time (``cusum_step``); every detection test runs on both."""
    scan = det.cusum_scan if request.param == "scan" else det.cusum_steps
    return functools.partial(det.cusum_detect, scan=scan)


def _correlated_cov(rng, m):
    X = rng.normal(size=(m, m))
    return X @ X.T / m + 0.2 * np.eye(m)


def _false_alarm_check(cusum, rng, m, arl0, engines, steps):
    design = det.design_cusum(m, arl0)
    P = _correlated_cov(rng, m)
    base = rng.normal(size=m)
    q = base + rng.multivariate_normal(np.zeros(m), P, size=(engines, steps))
    out = cusum(q, base, P, design)
    n_alarms = out.alarms.sum()
    expected = engines * steps / design.arl0
    # Renewal process: alarms ~ Poisson-like; run lengths are near geometric.
    assert abs(n_alarms - expected) < 5 * np.sqrt(expected), (n_alarms, expected)
    return n_alarms, expected


def test_false_alarm_rate_matches_design(cusum):
    _false_alarm_check(cusum, np.random.default_rng(10), m=4, arl0=100.0, engines=100, steps=3000)


@pytest.mark.slow
def test_false_alarm_rate_matches_design_long(cusum):
    rng = np.random.default_rng(11)
    n, e = _false_alarm_check(cusum, rng, 6, 1000.0, engines=1000, steps=20000)
    assert abs(n / e - 1.0) < 0.03


def _delay_check(cusum, rng, m, arl0, n_runs):
    """A library-like fault: shift d = H_i appears at sample 0 with S = 0."""
    design = det.design_cusum(m, arl0)
    P = _correlated_cov(rng, m)
    H = rng.normal(size=(m, 3))
    scale = np.sqrt(m / (H[:, 0] @ np.linalg.solve(P, H[:, 0])))  # noncentrality m
    d = H[:, 0] * scale
    lam = float(d @ np.linalg.solve(P, d))
    steps = 80
    q = d + rng.multivariate_normal(np.zeros(m), P, size=(n_runs, steps))
    out = cusum(q, np.zeros(m), P, design)
    delay = np.where(out.first_alarm >= 0, out.first_alarm + 1, steps + 1)
    sf = det.run_length_survival(m, design.reference, design.threshold, lam, steps)
    for n in (2, 5, 10, 20, 40):
        se = np.sqrt(sf[n] * (1 - sf[n]) / n_runs)
        assert abs(np.mean(delay > n) - sf[n]) < 5 * se + 2e-3, (n, np.mean(delay > n), sf[n])
    arl1 = det.average_run_length(m, design.reference, design.threshold, lam)
    assert abs(delay.mean() - arl1) < 5 * delay.std() / np.sqrt(n_runs)
    # The library's isolation then names the fault from the mean shift since the alarm.
    fired = out.first_alarm >= 0
    assert fired.mean() > 0.99


def test_detection_delay_distribution_matches_markov_chain(cusum):
    _delay_check(cusum, np.random.default_rng(12), m=6, arl0=200.0, n_runs=4000)


@pytest.mark.slow
def test_detection_delay_distribution_matches_markov_chain_long(cusum):
    _delay_check(cusum, np.random.default_rng(13), m=6, arl0=2000.0, n_runs=40000)


def test_steady_start_delay_matches_monte_carlo(cusum):
    """Fault after a long healthy run: S starts from its quasi-stationary law."""
    rng = np.random.default_rng(14)
    m, lam = 3, 4.0
    design = det.design_cusum(m, 100.0)
    n_runs, warm, after = 2000, 200, 60
    d = np.zeros(m)
    d[0] = np.sqrt(lam)
    noise = rng.standard_normal((n_runs, warm + after, m))
    noise[:, warm:] += d
    out = cusum(noise, np.zeros(m), np.eye(m), design)
    # Runs without a false alarm before the fault (conditioning of the quasi-stationary law).
    clean = ~out.alarms[:, :warm].any(axis=1)
    first_after = np.argmax(out.alarms[clean, warm:], axis=1) + 1
    first_after[~out.alarms[clean, warm:].any(axis=1)] = after + 1
    theory = det.average_run_length(m, design.reference, design.threshold, lam, start="steady")
    zero = det.average_run_length(m, design.reference, design.threshold, lam, start="zero")
    se = first_after.std() / np.sqrt(first_after.size)
    assert abs(first_after.mean() - theory) < 5 * se
    assert theory < zero  # a warm statistic is already part way to the threshold


def test_batch_equals_sequential(cusum):
    rng = np.random.default_rng(15)
    m = 3
    design = det.CusumDesign(m, 1.0, 8.0, np.nan)
    P = _correlated_cov(rng, m)
    base = rng.normal(size=(5, m))
    q = rng.normal(size=(5, 200, m)) * 1.5 + base[:, None, :]
    batch = cusum(q, base, P, design)
    Pi = np.linalg.inv(P)
    for e in range(5):
        S, stats, alarms = 0.0, [], []
        for k in range(200):
            r = q[e, k] - base[e]
            S = max(0.0, S + r @ Pi @ r - m - 1.0)
            alarms.append(S > 8.0)
            stats.append(S)
            if S > 8.0:
                S = 0.0
        np.testing.assert_allclose(batch.statistic[e], stats, rtol=1e-9, atol=1e-9)
        np.testing.assert_array_equal(batch.alarms[e], alarms)
        expect_first = alarms.index(True) if any(alarms) else -1
        assert batch.first_alarm[e] == expect_first


def test_scan_equals_steps_bit_for_bit():
    """The vectorised CUSUM and the scalar step do the same operations: equal statistics,
    alarms and first alarms, NaN samples included."""
    rng = np.random.default_rng(18)
    design = det.CusumDesign(3, 1.0, 8.0, np.nan)
    s = rng.chisquare(3, size=(4, 2, 300)) * 1.6
    s[0, 1, 17] = np.nan
    scan, steps = det.cusum_scan(s, design), det.cusum_steps(s, design)
    assert scan.statistic.tobytes() == steps.statistic.tobytes()
    np.testing.assert_array_equal(scan.alarms, steps.alarms)
    np.testing.assert_array_equal(scan.first_alarm, steps.first_alarm)
    assert scan.alarms.any()


def test_markov_chain_converges_with_cells():
    coarse = det.average_run_length(4, 2.0, 10.0, 0.0, n_cells=100)
    fine = det.average_run_length(4, 2.0, 10.0, 0.0, n_cells=800)
    assert abs(coarse / fine - 1) < 2e-3


def test_decorrelation_stride_scalar_closed_form():
    a, level = 0.97, 0.05
    Phi = np.array([[a]])
    P_hat = np.array([[2.0]])
    expected = int(np.ceil(np.log(level) / np.log(a)))
    assert det.decorrelation_stride(Phi, P_hat, 1, level) == expected


def test_detect_then_isolate_library_fault(cusum):
    """Detection followed by WSSR isolation on the mean shift since the alarm."""
    rng = np.random.default_rng(16)
    m, n_f = 6, 8
    H = rng.normal(size=(m, n_f)) * 2.0
    P = _correlated_cov(rng, m)
    design = det.design_cusum(m, 500.0)
    true = 3
    q = rng.multivariate_normal(np.zeros(m), P, size=(200, 120))
    q[:, 60:] += H[:, true]
    out = cusum(q, np.zeros(m), P, design)
    after = out.alarms[:, 60:].any(axis=1)
    assert after.mean() == 1.0
    # 20 samples after the fault, averaged: noise covariance P / 20.
    mean_shift = q[:, 60:80].mean(axis=1)
    res = iso.wssr_isolate(mean_shift, H, P / 20.0)
    pmc = iso.misclassification_probability(H, P / 20.0)
    assert np.mean(res.isolated == true) >= 1.0 - pmc[true].sum() - 0.02


def test_design_errors(cusum):
    with pytest.raises(det.DetectionError, match="ARL"):
        det.design_cusum(3, 0.5)
    with pytest.raises(det.DetectionError, match="P_q"):
        cusum(np.zeros((2, 5, 3)), np.zeros(3), np.eye(2), det.CusumDesign(3, 1, 5, 1))


def test_library_fault_delay_on_reference_design(cusum):
    """Delay of the seed 002 library fault hardest to see (smallest P_q-weighted size) on
    the reference design with noisy sensors: snapshots q ~ N(q_0 + H_i, P_q), one per
    decorrelation stride of the stream, against the Markov-chain delay distribution."""
    import dataclasses

    from estimation import evaluate as ev
    from estimation import tuners
    from tests.estimation.models import reference_model, reference_noise

    model = reference_model()
    model = dataclasses.replace(model, sensor_noise_std=model.sensor_noise_std * 100.0)
    d = tuners.optimal_tuners(model, 6, **reference_noise(model))
    infl = ev.fault_influence(d)
    lam = np.einsum("mi,mi->i", infl.H_q, np.linalg.solve(infl.P_q, infl.H_q))
    i = int(np.argmin(lam))
    assert infl.faults[i] == "VSV"
    design = det.design_cusum(d.n_tuners, 500.0)
    rng = np.random.default_rng(17)
    base = rng.normal(size=d.n_tuners)
    n_runs, steps = 4000, 200
    q = base + infl.H_q[:, i] + rng.multivariate_normal(
        np.zeros(d.n_tuners), d.P_q, size=(n_runs, steps)
    )
    out = cusum(q, base, d.P_q, design)
    delay = np.where(out.first_alarm >= 0, out.first_alarm + 1, steps + 1)
    sf = det.run_length_survival(design.m, design.reference, design.threshold, lam[i], steps)
    for n in (1, 3, 10, 30):
        se = np.sqrt(sf[n] * (1 - sf[n]) / n_runs)
        assert abs(np.mean(delay > n) - sf[n]) < 5 * se + 2e-3
    arl1 = det.average_run_length(design.m, design.reference, design.threshold, lam[i])
    assert abs(delay.mean() - arl1) < 5 * delay.std() / np.sqrt(n_runs)
