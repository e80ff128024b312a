"""Tuner selection: subset, SVD, optimal, diagnostics-aware, sensor selection."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from estimation import tuners
from estimation.errors import ConvergenceWarning, UnobservableDesignError
from estimation.theory import error_problem
from tests.estimation.models import random_model, reference_model, reference_noise


def _noise(model, qh=1e-2):
    n = reference_noise(model)
    return n["Q"], np.eye(model.n_health) * qh, n["Ph"]


def _objective(model, V, Q, Qh, Ph, **kw):
    """Objective by the scipy path (design_filter), not the batched search path."""
    return tuners.design_filter(model, V, Q, Qh, Ph, **kw).objective


MODELS = {
    "reference": lambda: reference_model(),
    "reference+bias": lambda: reference_model(actuator_bias=True, extra_sensors=1),
    "random": lambda: random_model(np.random.default_rng(21), n_health=8, n_sensors=5),
}


@pytest.mark.parametrize("name", sorted(MODELS))
@pytest.mark.parametrize("m", [2, 4])
def test_optimal_never_worse_than_subset_or_svd(name, m):
    model = MODELS[name]()
    Q, Qh, Ph = _noise(model)
    opt = tuners.optimal_tuners(model, m, Q, Qh, Ph)
    sub = tuners.subset_tuners(model, m, Q, Qh, Ph)
    svd = tuners.svd_tuners(model, m, Q, Qh, Ph)
    assert opt.theory.ssee_health <= sub.theory.ssee_health * (1 + 1e-10)
    assert opt.theory.ssee_health <= svd.theory.ssee_health * (1 + 1e-10)


def test_optimal_on_aux_objective_never_worse_than_its_starts():
    model = reference_model()
    Q, Qh, Ph = _noise(model)
    w = np.array([1.0, 0.5, 0.5, 0.5, 0.0])  # thrust and margins
    with pytest.warns(ConvergenceWarning, match="iteration limit"):
        opt = tuners.optimal_tuners(
            model, 3, Q, Qh, Ph, health_weights=np.zeros(10), aux_weights=w, max_iter=15
        )
    sub = tuners.subset_tuners(model, 3, Q, Qh, Ph, health_weights=np.zeros(10), aux_weights=w)
    svd_V = tuners.svd_vstar(model, 3, aux=["Fn", "SmFan", "SmLPC", "SmHPC"])
    f_svd = _objective(model, svd_V, Q, Qh, Ph, health_weights=np.zeros(10), aux_weights=w)
    assert opt.objective <= min(sub.objective, f_svd) * (1 + 1e-10)
    recomputed = opt.theory.aux_squared_error @ w
    assert opt.objective == pytest.approx(recomputed, rel=1e-12)


def test_all_methods_agree_with_as_many_tuners_as_health_parameters():
    model = random_model(np.random.default_rng(3), n_health=4, n_sensors=6)
    Q, Qh, Ph = _noise(model)
    designs = [
        tuners.subset_tuners(model, 4, Q, Qh, Ph),
        tuners.svd_tuners(model, 4, Q, Qh, Ph),
        tuners.optimal_tuners(model, 4, Q, Qh, Ph),
    ]
    ref = designs[0]
    for d in designs[1:]:
        np.testing.assert_allclose(d.theory.health_bias2, ref.theory.health_bias2, atol=1e-10)
        np.testing.assert_allclose(d.theory.health_variance, ref.theory.health_variance, rtol=1e-6)
        np.testing.assert_allclose(d.theory.aux_variance, ref.theory.aux_variance, rtol=1e-6)
    # V* = rows of the identity vs orthogonal V*: the same h_hat only if Qh maps alike,
    # which it does for Qh = c I (V Qh V^T = c I for orthonormal V).
    np.testing.assert_allclose(designs[1].health_gain(), ref.health_gain(), rtol=1e-6, atol=1e-9)


def test_objective_depends_on_the_row_space_only():
    model = reference_model()
    Q, Qh, Ph = _noise(model)
    rng = np.random.default_rng(2)
    V = rng.standard_normal((4, 10))
    T = rng.standard_normal((4, 4)) + 3 * np.eye(4)
    assert _objective(model, T @ V, Q, Qh, Ph) == pytest.approx(
        _objective(model, V, Q, Qh, Ph), rel=1e-7
    )


def test_chart_gradient_matches_scipy_path_directional_derivative():
    model = reference_model()
    Q, Qh, Ph = _noise(model)
    problem = error_problem(model, Q, Qh, Ph)
    rng = np.random.default_rng(4)
    V = rng.standard_normal((4, 10))
    base, comp = tuners._chart(V)
    X = 0.1 * rng.standard_normal((4, 6))
    _, grad = tuners.chart_gradient(lambda W: tuners._evaluate(problem, W), base, comp, X)
    D = rng.standard_normal((4, 6))
    t = 1e-4
    fp = _objective(model, base + (X + t * D) @ comp, Q, Qh, Ph)
    fm = _objective(model, base + (X - t * D) @ comp, Q, Qh, Ph)
    directional = (fp - fm) / (2 * t)
    assert np.sum(grad * D) == pytest.approx(directional, rel=1e-5)


def test_best_subset_equals_brute_force_over_design_filter():
    model = random_model(np.random.default_rng(8), n_health=5, n_sensors=4)
    Q, Qh, Ph = _noise(model)
    sub = tuners.subset_tuners(model, 2, Q, Qh, Ph)
    values = {
        c: _objective(model, np.eye(5)[list(c)], Q, Qh, Ph)
        for c in itertools.combinations(range(5), 2)
    }
    best = min(values, key=values.get)
    np.testing.assert_array_equal(sub.vstar, np.eye(5)[list(best)])
    assert sub.objective == pytest.approx(values[best], rel=1e-12)


def test_svd_tuners_span_the_top_right_singular_space_of_the_scaled_g():
    model = reference_model()
    w_extra = np.ones(2 + 6 + 5)
    w_extra[-5] = 2.0  # thrust weighted double, as seed 000's example
    V = tuners.svd_vstar(model, 4, row_weights=w_extra)
    G = np.vstack([model.L, model.M, model.N])
    keep = np.linalg.norm(G, axis=1) > 0  # speed sensors see health only through L
    G, w_extra = G[keep], w_extra[keep]
    W = np.diag(w_extra / np.linalg.norm(G, axis=1))
    # Independent: eigenvectors of (WG)^T (WG) for the 4 largest eigenvalues.
    lam, vec = np.linalg.eigh((W @ G).T @ (W @ G))
    top = vec[:, np.argsort(lam)[::-1][:4]]
    np.testing.assert_allclose(V.T @ V, top @ top.T, atol=1e-10)
    np.testing.assert_allclose(V @ V.T, np.eye(4), atol=1e-12)


def test_optimal_from_a_good_start_is_not_worse():
    model = reference_model()
    Q, Qh, Ph = _noise(model)
    first = tuners.optimal_tuners(model, 3, Q, Qh, Ph)
    again = tuners.optimal_tuners(model, 3, Q, Qh, Ph, start=first.vstar)
    assert again.objective <= first.objective * (1 + 1e-10)


def test_too_many_tuners_refused():
    model = reference_model().select_sensors(["Nf", "Nc", "T48"])
    Q, Qh, Ph = _noise(model)
    for method in (tuners.subset_tuners, tuners.svd_tuners, tuners.optimal_tuners):
        with pytest.raises(UnobservableDesignError, match="4 tuners"):
            method(model, 4, Q, Qh, Ph)


def test_diagnostic_design_trades_ssee_for_misclassification():
    model = reference_model()
    Q, Qh, Ph = _noise(model)
    lam = 20.0
    opt = tuners.optimal_tuners(model, 4, Q, Qh, Ph)
    diag = tuners.diagnostic_tuners(model, 4, Q, Qh, Ph, lam)
    pmc_opt = tuners.diagnostic_objective_terms(opt).sum()
    pmc_diag = tuners.diagnostic_objective_terms(diag).sum()
    assert pmc_diag < pmc_opt
    assert diag.theory.ssee_health >= opt.theory.ssee_health * (1 - 1e-10)
    # Never worse than its start under its own objective, recomputed from the designs.
    total_diag = diag.theory.ssee_health + lam * pmc_diag
    assert total_diag <= opt.theory.ssee_health + lam * pmc_opt
    assert diag.objective == pytest.approx(total_diag, rel=1e-6)


def test_sensor_selection_matches_per_suite_designs():
    model = reference_model(extra_sensors=3)
    Q, Qh, Ph = _noise(model)
    base, optional = model.sensor_names[:5], model.sensor_names[5:]
    suites = tuners.sensor_selection(model, base, optional, Q, Qh, Ph)
    assert len(suites) == 2 ** len(optional)
    full = next(s for s in suites if len(s.sensors) == len(model.sensor_names))
    sub_model = model.select_sensors(list(full.sensors))
    direct = tuners.optimal_tuners(sub_model, full.n_tuners, Q, Qh, Ph)
    assert full.optimal_objective == pytest.approx(direct.objective, rel=1e-6)
    best = tuners.best_suites(suites)
    assert sorted(best) == list(range(5, 10))
    for s in suites:
        if np.isfinite(s.subset_objective):
            assert s.optimal_objective <= s.subset_objective * (1 + 1e-10)
    # Adding a sensor never hurts the best design (seed 003 table is monotone).
    values = [best[n].optimal_objective for n in sorted(best)]
    assert all(b <= a * (1 + 1e-9) for a, b in zip(values, values[1:], strict=False))


def test_multi_start_is_never_worse_than_the_single_start():
    model = reference_model()
    Q, Qh, Ph = _noise(model)
    one = tuners.optimal_tuners(model, 3, Q, Qh, Ph)
    both = tuners.optimal_tuners(model, 3, Q, Qh, Ph, multi_start=True)
    assert both.objective <= one.objective * (1 + 1e-10)


def test_ols_first_pick_is_the_best_single_column_and_orthogonal_columns_are_exact():
    rng = np.random.default_rng(31)
    A = rng.standard_normal((9, 6))
    deltas = rng.standard_normal((40, 9))

    def residual(cols, d):
        sub = A[:, list(cols)]
        x, *_ = np.linalg.lstsq(sub, d, rcond=None)
        return np.sum((d - sub @ x) ** 2)

    first = tuners.ols_select(A, deltas, 1)[:, 0]
    for d, j in zip(deltas, first, strict=True):
        assert j == min(range(6), key=lambda c: residual([c], d))
    # With orthogonal columns greedy selection is the exhaustive best subset.
    Qo, _ = np.linalg.qr(A)
    A = Qo * np.array([3.0, 1.0, 2.0, 0.5, 1.5, 2.5])
    picks = tuners.ols_select(A, deltas, 3)
    for d, pick in zip(deltas, picks, strict=True):
        best = min(itertools.combinations(range(6), 3), key=lambda c: residual(c, d))
        assert sorted(pick) == sorted(best)


def test_ols_tally_returns_the_most_selected_parameters():
    model = reference_model()
    V, tally = tuners.ols_tally(model, 4, np.random.default_rng(0), n_draws=500)
    assert tally.sum() == 500 * 4
    chosen = np.flatnonzero(V.sum(axis=0))
    assert set(chosen) == set(np.argsort(-tally, kind="stable")[:4])
    d = tuners.design_filter(model, V, *_noise(model))
    assert np.isfinite(d.theory.ssee_health)


def _with_redundant_sensor(model):
    """The model plus a sensor that reads twice the first one: G_y loses rank."""
    import dataclasses

    from estimation.model import Signal

    return dataclasses.replace(
        model,
        sensors=model.sensors + (Signal("Nf_twice", "%"),),
        C=np.vstack([model.C, 2.0 * model.C[:1]]),
        D=np.vstack([model.D, 2.0 * model.D[:1]]),
        M=np.vstack([model.M, 2.0 * model.M[:1]]),
        sensor_noise_std=np.append(model.sensor_noise_std, model.sensor_noise_std[0]),
    )


def test_suites_with_redundant_sensors_are_unobservable_not_fatal():
    model = _with_redundant_sensor(reference_model(extra_sensors=1))
    Q, Qh, Ph = _noise(model)
    # As many tuners as sensors, one sensor redundant: the PBH test at the tuners'
    # eigenvalue 1 fails; the direct design refuses it and the batch marks it NaN.
    V = np.random.default_rng(2).standard_normal((model.n_sensors, model.n_health))
    with pytest.raises(UnobservableDesignError):
        tuners.design_filter(model, V, Q, Qh, Ph)
    keep = model.sensor_names[:-1]
    ok = np.random.default_rng(3).standard_normal((len(keep), model.n_health))
    batch = tuners._evaluate(error_problem(model, Q, Qh, Ph), np.stack([V, V]))
    assert np.all(np.isnan(batch))
    base, optional = model.sensor_names[:5], model.sensor_names[5:]
    suites = tuners.sensor_selection(model, base, optional, Q, Qh, Ph)
    for s in suites:
        redundant = "Nf_twice" in s.sensors
        assert np.isnan(s.optimal_objective) == redundant, s.sensors
    # The suites without it are designed as on the model without the sensor.
    direct = tuners.optimal_tuners(model.select_sensors(keep), len(keep), Q, Qh, Ph, start=ok)
    full = next(s for s in suites if s.sensors == tuple(keep))
    assert full.optimal_objective <= direct.objective * (1 + 1e-6)
