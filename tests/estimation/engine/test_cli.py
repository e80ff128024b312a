"""``fleethealth engine trim`` and ``linearize`` through typer's runner."""

import json

import numpy as np
from typer.testing import CliRunner

from app.cli.engine import cli
from estimation.engine.health import health_vector
from estimation.engine.linearize import linearize
from estimation.engine.sensors import AUX_NAMES, SENSOR_NAMES
from estimation.engine.steady import steady_state
from estimation.model import LinearModel

runner = CliRunner()


def test_trim_json_has_every_output_with_units():
    res = runner.invoke(cli, ["trim", "--alt", "35000", "--mach", "0.8", "--power", "85",
                              "--dtamb", "5", "--health", "hpc_eff=-2", "--health",
                              "hpt_flow=1.5", "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    ref = steady_state(np.array([35000.0, 0.8, 5.0]), power=85.0,
                       health=health_vector({"hpc_eff": -2.0, "hpt_flow": 1.5}))
    assert list(out["sensors"]) == list(SENSOR_NAMES)
    assert list(out["aux"]) == list(AUX_NAMES)
    for i, n in enumerate(SENSOR_NAMES):
        assert np.isclose(out["sensors"][n]["value"], ref.sensors[i], rtol=1e-9)
        assert out["sensors"][n]["unit"]
    assert out["sensors"]["T30"]["unit"] == "degR" and out["aux"]["Fn"]["unit"] == "lbf"


def test_trim_outside_envelope_fails_with_message():
    res = runner.invoke(cli, ["trim", "--alt", "60000", "--mach", "0.5", "--power", "50"])
    assert res.exit_code == 2
    assert "envelope" in res.output


def test_trim_unknown_health_name_fails():
    res = runner.invoke(cli, ["trim", "--alt", "0", "--mach", "0", "--power", "50",
                              "--health", "hpc_efficiency=-2"])
    assert res.exit_code != 0 and "hpc_efficiency" in res.output


def test_linearize_writes_the_model_format(tmp_path):
    path = tmp_path / "sub" / "model.json"
    res = runner.invoke(cli, ["linearize", "--alt", "10000", "--mach", "0.4", "--power", "70",
                              "--out", str(path)])
    assert res.exit_code == 0, res.output
    m = LinearModel.from_dict(json.loads(path.read_text()))
    ref = linearize(10000.0, 0.4, 70.0)
    assert np.allclose(m.A, ref.A) and np.allclose(m.M, ref.M)
    assert m.health_names == ref.health_names and m.dt == 0.015
