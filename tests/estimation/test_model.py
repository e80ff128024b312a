"""LinearModel: validation, dict format round trip, subsets, steady-state gains."""

from __future__ import annotations

import json

import numpy as np
import pytest

from estimation.errors import DimensionError, ModelFormatError, UnknownSignalError
from estimation.model import MODEL_FORMAT, LinearModel, Signal
from tests.estimation.models import random_model, reference_model
from tests.support.paths import ROOT


def test_round_trip_through_json_keeps_everything():
    m = reference_model(actuator_bias=True, extra_sensors=2)
    back = LinearModel.from_dict(json.loads(json.dumps(m.to_dict())))
    for name in "ABCDLMFGN":
        np.testing.assert_array_equal(getattr(back, name), getattr(m, name))
    assert back.health == m.health and back.sensors == m.sensors and back.aux == m.aux
    assert back.trim == m.trim and back.dt == m.dt
    np.testing.assert_array_equal(back.sensor_noise_std, m.sensor_noise_std)
    assert back.operating_condition == m.operating_condition


def test_extra_keys_ignored_and_optional_matrices_default_to_zero():
    d = reference_model().to_dict()
    d["exported_by"] = {"tool": "vendor deck", "version": 3}
    d["signals"]["sensors"][0]["description"] = "fan speed"
    for name in ("D", "F", "G", "M", "N"):
        del d["matrices"][name]
    m = LinearModel.from_dict(d)
    assert m.D.shape == (6, 3) and not m.D.any()
    assert m.N.shape == (5, 10) and not m.N.any()


def test_wrong_shape_names_the_matrix_and_expected_shape():
    d = reference_model().to_dict()
    d["matrices"]["L"] = [row[:-1] for row in d["matrices"]["L"]]
    with pytest.raises(DimensionError, match=r"L matrix; expected \(2, 10\) but found \(2, 9\)"):
        LinearModel.from_dict(d)


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda d: d.update(format="other/1"), "format"),
        (lambda d: d.pop("trim"), "trim"),
        (lambda d: d["signals"].pop("aux"), "signals.aux"),
        (lambda d: d["matrices"].pop("A"), "matrices.A"),
        (lambda d: d.update(dt="fast"), "dt"),
    ],
)
def test_malformed_dicts_name_the_key(mutate, message):
    d = reference_model().to_dict()
    mutate(d)
    with pytest.raises(ModelFormatError, match=message):
        LinearModel.from_dict(d)


def test_noise_and_trim_are_checked():
    d = reference_model().to_dict()
    d["sensor_noise_std"] = d["sensor_noise_std"][:-1]
    with pytest.raises(DimensionError, match="sensor_noise_std"):
        LinearModel.from_dict(d)
    d = reference_model().to_dict()
    d["trim"]["NoSuchSignal"] = 1.0
    with pytest.raises(UnknownSignalError, match="NoSuchSignal"):
        LinearModel.from_dict(d)
    d = reference_model().to_dict()
    d["matrices"]["A"][0][0] = float("nan")
    with pytest.raises(DimensionError, match="A matrix"):
        LinearModel.from_dict(d)


def test_duplicate_names_refused():
    d = reference_model().to_dict()
    d["signals"]["health"][1]["name"] = d["signals"]["health"][0]["name"]
    with pytest.raises(ValueError, match="duplicate"):
        LinearModel.from_dict(d)


def test_steady_state_gains_equal_the_converged_simulation():
    m = random_model(np.random.default_rng(3))
    Gy, Gz = m.steady_state_gains()
    # Independent: run x[k+1] = A x[k] + L h to convergence for each unit health shift.
    X = np.zeros((m.n_states, m.n_health))
    for _ in range(5000):
        X = m.A @ X + m.L
    np.testing.assert_allclose(Gy, m.C @ X + m.M, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(Gz, m.F @ X + m.N, rtol=1e-9, atol=1e-12)


def test_select_sensors_and_health_take_rows_and_columns_by_name():
    m = reference_model(actuator_bias=True, extra_sensors=3)
    Gy, Gz = m.steady_state_gains()
    sens = ["T48", "Nf", "P50"]
    health = ["hpt_eff", "wf_bias", "fan_flow"]
    sub = m.select_sensors(sens).select_health(health)
    si, hi = m.sensor_index(sens), m.health_index(health)
    Gy_sub, Gz_sub = sub.steady_state_gains()
    np.testing.assert_allclose(Gy_sub, Gy[np.ix_(si, hi)], rtol=1e-12)
    np.testing.assert_allclose(Gz_sub, Gz[:, hi], rtol=1e-12)
    np.testing.assert_array_equal(sub.sensor_noise_std, m.sensor_noise_std[si])
    assert sub.sensor_names == sens and sub.health_names == health
    assert "T24" not in sub.trim and "Nf" in sub.trim  # Nf is also a state
    with pytest.raises(UnknownSignalError, match="Nx"):
        m.select_sensors(["Nx"])


def test_arrays_are_read_only_and_signals_are_values():
    m = reference_model()
    with pytest.raises(ValueError):
        m.A[0, 0] = 2.0
    assert Signal("Nf", "rpm") == m.sensors[0]
    assert m.to_dict()["format"] == MODEL_FORMAT


def test_documented_example_loads():
    import re

    text = (ROOT / "docs" / "model-format.md").read_text()
    block = re.search(r"```json\n(.*?)```", text, re.S).group(1)
    m = LinearModel.from_dict(json.loads(block))
    Gy, Gz = m.steady_state_gains()
    assert Gy.shape == (2, 2) and Gz.shape == (1, 2)
    assert m.sensor_names == ["Nf", "T48"] and m.R[1, 1] == 1.5**2
