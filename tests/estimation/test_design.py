"""Design spec -> design result: parsing, methods, result contents, rebuild."""

from __future__ import annotations

import json

import numpy as np
import pytest

from estimation import isolation
from estimation.design import DESIGN_FORMAT, SPEC_FORMAT, design_from_result, run_design
from estimation.errors import ConvergenceWarning, DesignSpecError, UnobservableDesignError
from estimation.model import LinearModel
from estimation.tuners import design_filter, optimal_tuners
from tests.estimation.models import random_model, reference_model


def _spec(**over):
    spec = {
        "format": SPEC_FORMAT,
        "model": "cruise.json",
        "method": "optimal",
        "tuners": 4,
        "noise": {"Q": [0.01, 0.01], "Qh": [0.1] * 10, "Ph": [2.0] * 10},
    }
    spec.update(over)
    return spec


def test_optimal_design_result_matches_a_direct_design():
    model = reference_model()
    result = json.loads(json.dumps(run_design(_spec(), model.to_dict())))
    assert result["format"] == DESIGN_FORMAT and result["method"] == "optimal"
    direct = optimal_tuners(
        model, 4, np.eye(2) * 1e-4, np.eye(10) * 0.01, np.eye(10) * 4.0
    )
    assert result["theory"]["ssee_health"] == pytest.approx(direct.theory.ssee_health, rel=1e-9)
    health = result["theory"]["health"]
    assert result["theory"]["ssee_health"] == pytest.approx(
        sum(health["bias2"]) + sum(health["variance"])
    )
    assert np.shape(result["gain"]) == (2 + 4, 6) and np.shape(result["Pq"]) == (4, 4)
    rebuilt = design_from_result(result)
    np.testing.assert_allclose(rebuilt.gain, result["gain"], rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(rebuilt.P_q, result["Pq"], rtol=1e-10, atol=1e-16)


def test_fault_section_matches_the_isolation_influence_matrix():
    model = reference_model()
    result = run_design(_spec(method="subset"), model)
    faults = result["faults"]
    assert faults["names"] == [f.name for f in isolation.default_faults()]
    design = design_from_result(result)
    full = isolation.full_health(
        model.L, model.M, model.N, model.B, model.D, model.G,
        model.health_names, model.input_names,
    )
    Gy_full = isolation.steady_state_gain(model.A, full.L, model.C, full.M)
    S = isolation.signature_matrix(isolation.default_faults(), full.names)
    red = design.reduced
    H = isolation.tuner_fault_influence(red.A, red.C, design.gain, Gy_full, S, 4)
    np.testing.assert_allclose(faults["H"], H, rtol=1e-9, atol=1e-12)
    pmc = isolation.misclassification_probability(H, np.asarray(result["Pq"]))
    np.testing.assert_allclose(faults["pmc"], pmc, rtol=1e-8, atol=1e-14)


def test_explicit_vstar_replaces_the_method_and_sensor_health_selection():
    model = reference_model(actuator_bias=True, extra_sensors=2)
    V = np.random.default_rng(1).standard_normal((3, 10))
    spec = _spec(
        vstar=V.tolist(), tuners=3, sensors=["Nf", "Nc", "T48", "P24"],
        health=model.health_names[:10],
    )
    result = run_design(spec, model)
    assert result["method"] == "explicit" and result["sensors"] == ["Nf", "Nc", "T48", "P24"]
    sub = model.select_sensors(["Nf", "Nc", "T48", "P24"]).select_health(model.health_names[:10])
    direct = design_filter(sub, V, np.eye(2) * 1e-4, np.eye(10) * 0.01, np.eye(10) * 4.0)
    np.testing.assert_allclose(result["gain"], direct.gain, rtol=1e-10, atol=1e-14)
    # The source model keeps every health parameter for simulating faults and biases.
    assert len(LinearModel.from_dict(result["source_model"]).health_names) == 13


def test_aux_objective_is_the_weighted_aux_error():
    model = reference_model()
    spec = _spec(objective={"aux": {"Fn": 2.0, "SmHPC": 1.0}}, max_iter=15)
    with pytest.warns(ConvergenceWarning):  # 15 iterations are not enough for this objective
        result = run_design(spec, model)
    aux = result["theory"]["aux"]
    err = dict(zip(aux["names"], np.add(aux["bias2"], aux["variance"]), strict=True))
    assert result["objective"] == pytest.approx(2.0 * err["Fn"] + err["SmHPC"], rel=1e-9)


def test_models_without_the_library_names_skip_faults_unless_given():
    model = random_model(np.random.default_rng(2), n_health=5, n_sensors=4)
    spec = _spec(tuners=2, noise={"Qh": [0.1] * 5, "Ph": np.eye(5).tolist()})
    assert "faults" not in run_design(spec, model)
    spec["faults"] = [{"name": "A", "shifts": {"h1": -2}}, {"name": "B", "shifts": {"h2": 1}}]
    result = run_design(spec, model)
    assert result["faults"]["names"] == ["A", "B"]
    assert np.shape(result["faults"]["pmc"]) == (2, 2)


@pytest.mark.parametrize(
    ("over", "message"),
    [
        ({"format": "x"}, "format"),
        ({"sensors": ["Nf", "Bogus"]}, "Bogus"),
        ({"method": "magic"}, "method"),
        ({"tuners": 0}, "tuners"),
        ({"noise": {"Q": [0.1, 0.1], "Ph": [2.0] * 10}}, "noise.Qh"),
        ({"noise": {"Qh": [0.1] * 9, "Ph": [2.0] * 10}}, "noise.Qh"),
        ({"vstar": [[1.0, 0.0]]}, "vstar"),
        ({"objective": {"aux": {"Thrust": 1}}}, "Thrust"),
        ({"lambda": -1}, "lambda"),
    ],
)
def test_bad_specs_name_the_key(over, message):
    with pytest.raises(DesignSpecError, match=message):
        run_design(_spec(**over), reference_model())


def test_too_many_tuners_for_the_sensors_refused():
    spec = _spec(sensors=["Nf", "Nc", "T48"], tuners=4)
    with pytest.raises(UnobservableDesignError):
        run_design(spec, reference_model())


def test_variance_key_selects_the_formula_and_survives_the_round_trip():
    model = reference_model()
    V = np.random.default_rng(3).standard_normal((4, 10))
    results = {
        v: json.loads(json.dumps(run_design(_spec(vstar=V.tolist(), variance=v), model)))
        for v in ("with_process_noise", "sensor_noise_only")
    }
    for v, result in results.items():
        assert result["variance"] == v
        direct = design_filter(
            model, V, np.eye(2) * 1e-4, np.eye(10) * 0.01, np.eye(10) * 4.0, variance=v
        )
        np.testing.assert_allclose(
            result["theory"]["health"]["variance"], direct.theory.health_variance, rtol=1e-9
        )
        rebuilt = design_from_result(result)
        assert rebuilt.variance == v
        np.testing.assert_allclose(rebuilt.P_hat, result["P_hat"], rtol=1e-9, atol=1e-16)
    joint = np.array(results["with_process_noise"]["theory"]["health"]["variance"])
    seed = np.array(results["sensor_noise_only"]["theory"]["health"]["variance"])
    assert np.all(joint > seed)  # process noise only adds variance
    # Same gain either way: the variance formula does not change the filter.
    np.testing.assert_allclose(
        results["with_process_noise"]["gain"], results["sensor_noise_only"]["gain"], rtol=1e-12
    )
    with pytest.raises(DesignSpecError, match="variance"):
        run_design(_spec(variance="both"), model)
