"""WSSR isolation, max-h rule and misclassification probability (seed 002 eq. 21-26)."""

import numpy as np
import pytest
from scipy.special import ndtr

from estimation import isolation as iso


def _random_problem(rng, m=6, n_f=8):
    H = rng.normal(size=(m, n_f))
    X = rng.normal(size=(m, m))
    P = X @ X.T + 0.5 * np.eye(m)
    return H, P


def _wssr_loop(q, H, P):
    """Eq. 21-23 one hypothesis at a time with explicit solves (no whitening)."""
    out_w, out_f = [], []
    for i in range(H.shape[1]):
        Hi = H[:, i : i + 1]
        PiH = np.linalg.solve(P, Hi)
        f = float(np.linalg.solve(Hi.T @ PiH, PiH.T @ q)[0])
        r = q - Hi[:, 0] * f
        out_w.append(float(r @ np.linalg.solve(P, r)))
        out_f.append(f)
    return np.array(out_w), np.array(out_f)


def test_wssr_batch_equals_per_hypothesis_solve():
    rng = np.random.default_rng(1)
    H, P = _random_problem(rng)
    Q = rng.normal(size=(50, 6))
    res = iso.wssr_isolate(Q, H, P)
    for k in range(Q.shape[0]):
        w, f = _wssr_loop(Q[k], H, P)
        np.testing.assert_allclose(res.wssr[k], w, rtol=1e-9, atol=1e-10)
        np.testing.assert_allclose(res.magnitude[k], f, rtol=1e-9, atol=1e-12)
        assert res.isolated[k] == np.argmin(w)


def test_noise_free_fault_isolates_with_zero_wssr():
    rng = np.random.default_rng(2)
    H, P = _random_problem(rng)
    mags = np.array([1.0, -0.5, 2.0])
    shifts = (H[:, :, None] * mags).transpose(1, 2, 0)  # (n_f, 3, m)
    res = iso.wssr_isolate(shifts, H, P)
    truth = np.arange(H.shape[1])[:, None]
    assert np.all(res.isolated == truth)
    true_wssr = np.take_along_axis(res.wssr, truth[:, :, None].repeat(3, 1), axis=-1)[..., 0]
    weighted = np.linalg.solve(P, shifts.reshape(-1, 6).T).T.reshape(shifts.shape)
    scale = np.einsum("fkm,fkm->fk", shifts, weighted)
    assert np.all(true_wssr <= 1e-9 * scale)
    f_true = np.take_along_axis(res.magnitude, truth[:, :, None].repeat(3, 1), axis=-1)[..., 0]
    np.testing.assert_allclose(f_true, np.broadcast_to(mags, f_true.shape), rtol=1e-10)


def test_singular_covariance_uses_pseudo_inverse():
    rng = np.random.default_rng(3)
    m, r = 5, 3
    X = rng.normal(size=(m, r))
    P = X @ X.T  # rank 3
    H = X @ rng.normal(size=(r, 4))  # signatures inside the range of P
    q = X @ rng.normal(size=r)
    res = iso.wssr_isolate(q, H, P)
    Pp = np.linalg.pinv(P)
    for i in range(4):
        Hi = H[:, i]
        f = (Hi @ Pp @ q) / (Hi @ Pp @ Hi)
        rres = q - Hi * f
        assert res.wssr[i] == pytest.approx(rres @ Pp @ rres, rel=1e-7, abs=1e-9)


def test_shape_errors_name_the_matrix():
    H = np.ones((3, 2))
    with pytest.raises(iso.IsolationError, match=r"expected \(3, 3\)"):
        iso.wssr_isolate(np.zeros(3), H, np.eye(4))
    with pytest.raises(iso.IsolationError, match="positive semidefinite"):
        iso.wssr_isolate(np.zeros(3), H, np.diag([1.0, 1.0, -1.0]))


def test_max_h_rule_matches_module_rss():
    rng = np.random.default_rng(4)
    names = ["fan_eff", "fan_flow", "lpc_eff", "lpc_flow", "hpc_eff", "hpc_flow",
             "hpt_eff", "hpt_flow", "lpt_eff", "lpt_flow", "wf_bias", "vsv_bias", "vbv_bias"]
    faults = iso.default_faults()
    S = iso.signature_matrix(faults, names)
    h = rng.normal(size=(20, 13))
    res = iso.max_h_rule(h, S, [f.name for f in faults])
    for k in range(20):
        scores = [np.hypot(h[k, 2 * i], h[k, 2 * i + 1]) for i in range(5)]
        scores += [abs(h[k, 10 + j]) for j in range(3)]
        np.testing.assert_allclose(res.magnitude[k], scores, rtol=1e-12)
        assert res.isolated[k] == int(np.argmax(scores))


def test_signature_matrix_and_unknown_name():
    names = ["Fan_Eff", "fan_flow", "wf_bias"]
    S = iso.signature_matrix([iso.Fault("Fan", {"fan_eff": -2, "fan_flow": -2})], names)
    np.testing.assert_array_equal(S[:, 0], [-2.0, -2.0, 0.0])
    with pytest.raises(iso.IsolationError, match="unknown health parameter 'hpc_eff'"):
        iso.signature_matrix([iso.Fault("HPC", {"hpc_eff": -2})], names)


def test_fault_dict_round_trip_and_default_library():
    faults = iso.default_faults()
    back = iso.faults_from_list([f.to_dict() for f in faults])
    assert back == faults
    assert [f.name for f in faults] == ["Fan", "LPC", "HPC", "HPT", "LPT", "Wf", "VSV", "VBV"]
    with pytest.raises(iso.IsolationError, match="unique"):
        iso.faults_from_list([faults[0].to_dict(), faults[0].to_dict()])


def test_full_health_appends_actuator_bias_columns():
    rng = np.random.default_rng(5)
    L, M, N = rng.normal(size=(2, 3)), rng.normal(size=(4, 3)), rng.normal(size=(1, 3))
    B, D, G = rng.normal(size=(2, 2)), rng.normal(size=(4, 2)), rng.normal(size=(1, 2))
    fh = iso.full_health(L, M, N, B, D, G, ["a", "b", "wf_bias"], ["Wf", "VSV"])
    assert fh.names == ("a", "b", "wf_bias", "vsv_bias")
    np.testing.assert_array_equal(fh.L[:, 3], B[:, 1])
    np.testing.assert_array_equal(fh.M[:, 3], D[:, 1])
    np.testing.assert_array_equal(fh.N[:, 3], G[:, 1])


def test_misclassification_probability_matches_monte_carlo():
    """Eq. 24-26 is the error rate of the two-class nearest-mean rule between q_a and +-q_b."""
    rng = np.random.default_rng(6)
    m = 4
    H = rng.normal(size=(m, 3)) * 0.8
    X = rng.normal(size=(m, m))
    P = X @ X.T / m + 0.3 * np.eye(m)
    pmc = iso.misclassification_probability(H, P)
    Pi = np.linalg.inv(P)
    n = 200_000
    noise = rng.multivariate_normal(np.zeros(m), P, size=n)
    for a in range(3):
        qa = H[:, a]
        for b in range(3):
            if a == b:
                continue
            qb = H[:, b] * np.sqrt(qa @ Pi @ qa) / np.sqrt(H[:, b] @ Pi @ H[:, b])
            # the nearer of +q_b and -q_b competes with q_a
            sign = 1.0 if (qa - qb) @ Pi @ (qa - qb) <= (qa + qb) @ Pi @ (qa + qb) else -1.0
            qb = sign * qb
            obs = qa + noise
            da = np.einsum("ki,ij,kj->k", obs - qa, Pi, obs - qa)
            db = np.einsum("ki,ij,kj->k", obs - qb, Pi, obs - qb)
            mc = np.mean(db < da)
            se = np.sqrt(pmc[a, b] * (1 - pmc[a, b]) / n)
            assert abs(mc - pmc[a, b]) < 5 * se + 1e-4, (a, b, mc, pmc[a, b])
    assert np.all(np.diag(pmc) == 0.0)


def test_misclassification_probability_scales_with_magnitude():
    """Doubling the fault magnitude doubles D_M: compare with the closed form on one pair."""
    H = np.array([[1.0, 0.0], [0.0, 1.0]])
    P = np.eye(2)
    for f in (0.5, 1.0, 2.0):
        pmc = iso.misclassification_probability(H, P, f)
        d = f * np.sqrt(2.0)  # orthogonal unit signatures of equal length f
        assert pmc[0, 1] == pytest.approx(1.0 - ndtr(d / 2.0), rel=1e-12)


def test_confusion_percent_rows():
    t = np.repeat(np.arange(3), 4)
    i = np.array([0, 0, 0, 1, 1, 1, 1, 1, 2, 2, 0, 2])
    c = iso.confusion_percent(t, i, 3)
    np.testing.assert_allclose(c.sum(axis=1), 100.0)
    assert c[0, 0] == 75.0 and c[2, 0] == 25.0
    assert iso.correct_rate(c) == pytest.approx((75 + 100 + 75) / 3)


def test_bounded_fit_is_the_least_wssr_within_the_bounds():
    """The magnitude held to an interval: the free fit where it lies inside, else the bound;
    WSSR is the least of the parabola on the interval (checked on a fine grid of f); a fault
    without signature keeps f = 0 and WSSR = c."""
    rng = np.random.default_rng(5)
    a = rng.uniform(0.01, 4.0, (50, 6))
    b = rng.normal(0.0, 3.0, (50, 6))
    c = np.sum(b**2 / a, axis=1) + rng.uniform(0.0, 5.0, 50)  # c >= b^2 / a (Cauchy-Schwarz)
    wssr, f = iso.bounded_fit(a, b, c, (0.5, 3.0))
    grid = np.linspace(0.5, 3.0, 25001)
    brute = c[:, None, None] - 2 * grid * b[..., None] + grid**2 * a[..., None]
    np.testing.assert_allclose(wssr, brute.min(axis=-1), atol=1e-6)
    assert np.all((f >= 0.5) & (f <= 3.0))
    inside = (b / a >= 0.5) & (b / a <= 3.0)
    np.testing.assert_allclose(f[inside], (b / a)[inside])
    np.testing.assert_allclose(wssr[inside], (c[:, None] - b**2 / a)[inside], atol=1e-9)
    w0, f0 = iso.bounded_fit(np.array([0.0, 1.0]), np.array([0.0, 1.0]), 2.0, (0.5, 3.0))
    assert f0[0] == 0.0 and w0[0] == 2.0 and w0[1] == pytest.approx(1.0)


def test_a_fault_without_signature_does_not_win_at_fifty_times_its_magnitude():
    """The sensor-space fit of an alarm (``shift_detector.SensorFit``): a change along a
    fault's direction but far larger than the fault can make (its free fit 100 times its
    nominal shift, WSSR 0.01) is not that fault; held to ``MAGNITUDE_RANGE`` it costs 0.95 and
    the fault that explains the change at half its nominal shift (WSSR 0.4) is named."""
    from estimation.shift_detector import MAGNITUDE_RANGE, SensorFit

    # g_1 = (1, 1), g_2 = (0.01, 0), r = (1, 0.1), unit weights
    fit = SensorFit(a=(2.0, 1e-4), b=(1.1, 0.01), c=1.01, n=2)
    free_w = np.array(fit.c) - np.array(fit.b) ** 2 / np.array(fit.a)
    assert np.argmin(free_w) == 1
    wssr, f = fit.solve()
    assert np.argmin(wssr) == 0
    assert f[0] == pytest.approx(0.55) and f[1] == MAGNITUDE_RANGE[1]
    assert wssr[0] == pytest.approx(0.405) and wssr[1] == pytest.approx(0.9509)


def test_a_fault_is_named_on_evidence_not_by_elimination():
    """An alarm's isolation in sensor space (``shift_detector.isolate``): with the magnitudes
    held to their range, a fault of no signature fits an unchanged engine best (20 sensor
    values of noise, c = 20), but it explains none of the change, so it is not named (the
    alarm is then dropped); a fault that explains a change of 50 beyond the noise is named."""
    from typing import Any, cast

    from estimation.shift_detector import EVIDENCE_THRESHOLD, PendingAlarm, SensorFit, isolate

    def outcome(fit: SensorFit):
        alarm = PendingAlarm(0, 0.0, 0.0, 0, (0.0,), fit=fit)
        return isolate(cast(Any, None), alarm, np.zeros(1), np.eye(1))

    quiet = outcome(SensorFit(a=(2.0, 1e-6), b=(0.1, 0.0), c=20.0, n=20))
    assert quiet.nearest == 1 and quiet.wssr[1] <= quiet.wssr_threshold
    assert quiet.distance - quiet.wssr[1] < EVIDENCE_THRESHOLD
    assert not quiet.isolated and quiet.dropped
    fault = outcome(SensorFit(a=(50.0, 1e-6), b=(50.0, 0.0), c=70.0, n=20))
    assert fault.nearest == 0 and fault.f[0] == pytest.approx(1.0) and fault.isolated
