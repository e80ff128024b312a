"""Posterior over fault hypotheses: against a Monte Carlo of the chi-squared model and Bayes
computed by counting."""

from __future__ import annotations

import numpy as np
import pytest

from estimation import isolation
from estimation.posterior import (
    PosteriorError,
    ambiguity_groups,
    confusion_posterior,
    fault_posterior,
    fit_tempering,
    reliability,
)


def test_wssr_posterior_is_calibrated_on_the_linear_model() -> None:
    """Simulate shifts q = H_i f + v, v ~ N(0, P), i from the prior and f ~ U(-6, 6) (the
    flat magnitude prior the profiled WSSR likelihood stands for; columns of equal weighted
    norm so the Occam factors are equal); events whose posterior for fault a is about p must
    be fault a about p of the time (calibration by binning)."""
    rng = np.random.default_rng(3)
    m, n_f, n = 4, 3, 20000
    H = rng.normal(0.0, 1.0, (m, n_f))
    H /= np.linalg.norm(H, axis=0)
    P = np.eye(m)
    prior = np.array([0.5, 0.3, 0.2])
    true = rng.choice(n_f, n, p=prior)
    f = rng.uniform(-6.0, 6.0, n)
    q = H[:, true].T * f[:, None] + rng.standard_normal((n, m))
    iso = isolation.wssr_isolate(q, H, P)
    post = fault_posterior(iso.wssr, m - 1, ("a", "b", "c"), prior=prior)
    p_true = post.posterior[np.arange(n), true]
    flat = fault_posterior(iso.wssr, m - 1, ("a", "b", "c"))
    assert np.array_equal(flat.posterior.argmax(1), iso.isolated)
    p0 = post.posterior[:, 0]
    for lo, hi in ((0.1, 0.3), (0.4, 0.6), (0.7, 0.9)):
        sel = (p0 >= lo) & (p0 < hi)
        assert sel.sum() > 300
        assert abs(np.mean(true[sel] == 0) - np.mean(p0[sel])) < 0.05
    assert np.all(np.isfinite(p_true))


def test_confusion_bayes_matches_counting() -> None:
    rng = np.random.default_rng(5)
    n_f = 4
    C = rng.dirichlet(np.ones(n_f) * 0.7, n_f) * 100.0
    prior = np.array([0.4, 0.3, 0.2, 0.1])
    true = rng.choice(n_f, 200000, p=prior)
    u = rng.random(len(true))
    cum = np.cumsum(C / 100.0, axis=1)
    iso = (u[:, None] > cum[true]).sum(axis=1)
    counted = np.zeros((n_f, n_f))
    np.add.at(counted, (true, iso), 1.0)
    counted /= counted.sum(axis=0, keepdims=True)
    assert np.allclose(confusion_posterior(C, prior), counted, atol=0.01)


def test_confusion_sharpens_or_widens_the_event() -> None:
    faults = ("HPT", "Wf", "Fan")
    wssr = np.array([1.0, 1.5, 30.0])  # HPT slightly better, Fan ruled out
    C = np.array([[50.0, 50.0, 0.0], [50.0, 50.0, 0.0], [0.0, 0.0, 100.0]])
    post = fault_posterior(wssr, 10, faults, confusion=C)
    assert post.label(0.9) == ["HPT or Wf"]
    sharp = fault_posterior(np.array([1.0, 40.0, 30.0]), 10, faults, confusion=C)
    assert sharp.label(0.9) == ["HPT"]
    with pytest.raises(PosteriorError):
        fault_posterior(wssr, 10, faults[:2])


def test_ambiguity_groups_are_connected_components() -> None:
    names = ("Fan", "LPC", "HPC", "HPT", "Wf")
    C = np.diag([100.0, 80.0, 90.0, 60.0, 55.0])
    C[1, 2], C[2, 1] = 20.0, 10.0
    C[3, 4], C[4, 3] = 40.0, 45.0
    groups = ambiguity_groups(C, names, threshold=10.0)
    assert groups.groups == (("Fan",), ("LPC", "HPC"), ("HPT", "Wf"))
    assert groups.label("Wf") == "HPT or Wf"
    assert groups.group_correct(C, names) == pytest.approx(np.mean([100, 100, 100, 100, 100]))
    assert ambiguity_groups(C, names, threshold=90.0).groups == tuple((n,) for n in names)


def test_reliability_bins_confidence_against_hits() -> None:
    """Events right as often as their confidence says: every bin's hit rate near its mean
    confidence and a small calibration error; the same events claimed at 99 %: a large one."""
    rng = np.random.default_rng(9)
    confidence = rng.uniform(0.3, 1.0, 40000)
    hit = rng.uniform(size=confidence.size) < confidence
    honest = reliability(confidence, hit)
    assert honest.count.sum() == confidence.size
    for lo, hi, n, mean, rate in honest.rows():
        assert lo <= mean <= hi and n > 100
        assert abs(rate - mean) < 0.03
    assert honest.calibration_error < 0.02
    bold = reliability(np.full(confidence.size, 0.99), hit)
    assert [r[2] for r in bold.rows()] == [confidence.size]  # the last bin, closed at 1
    assert bold.calibration_error == pytest.approx(0.99 - hit.mean(), abs=1e-12)
    with pytest.raises(PosteriorError):
        reliability(confidence, hit[:-1])


def test_tempering_recovers_the_model_errors_inflation_and_honest_confidence() -> None:
    """Events whose WSSR is chi-squared times 3 (model error a linear fit does not see): the
    posterior at scale 1 claims more than it knows; the fitted scale is near 3, its log score
    beats the untempered one, and on new events of the same kind it is right as often as it
    says. A confusion that adds nothing gets little weight."""
    rng = np.random.default_rng(12)
    m, n_f = 4, 3
    H = rng.normal(0.0, 1.0, (m, n_f))
    H /= np.linalg.norm(H, axis=0)

    def events(n: int) -> tuple[np.ndarray, np.ndarray]:
        true = rng.integers(0, n_f, n)
        f = rng.uniform(-6.0, 6.0, n)
        q = H[:, true].T * f[:, None] + np.sqrt(3.0) * rng.standard_normal((n, m))
        return isolation.wssr_isolate(q, H, np.eye(m)).wssr, true

    wssr, true = events(3000)
    faults = ("a", "b", "c")
    confusion = np.full((3, 3), 100.0 / 3)  # says nothing
    t = fit_tempering(wssr, m - 1, true, faults, confusion)
    assert 2.2 <= t.scale <= 4.0, t
    assert t.confusion_power <= 0.25 and t.events == 3000
    assert t.log_score > t.default_score
    new_wssr, new_true = events(20000)
    post = fault_posterior(new_wssr, m - 1, faults, confusion=confusion, scale=t.scale,
                           confusion_power=t.confusion_power).posterior
    bold = fault_posterior(new_wssr, m - 1, faults).posterior
    for p, limit in ((post, 0.02), (bold, None)):
        rel = reliability(p.max(1), p.argmax(1) == new_true)
        if limit is None:
            assert rel.calibration_error > 0.05  # untempered: overconfident
        else:
            assert rel.calibration_error < limit
