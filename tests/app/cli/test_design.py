"""``fleethealth design SPEC.json --out DESIGN.json`` through the Typer app."""

from __future__ import annotations

import json

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from app.cli.design import cli, register
from estimation.design import design_from_result
from estimation.tuners import optimal_tuners
from tests.estimation.models import reference_model

runner = CliRunner()


def _write(tmp_path, spec_over=None):
    model = reference_model()
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "cruise.json").write_text(json.dumps(model.to_dict()))
    spec = {
        "format": "fleethealth.design-spec/1",
        "model": "models/cruise.json",  # relative to the spec, not to the working directory
        "method": "optimal",
        "tuners": 3,
        "noise": {"Q": [0.01, 0.01], "Qh": [0.1] * 10, "Ph": [2.0] * 10},
    }
    spec.update(spec_over or {})
    (tmp_path / "specs").mkdir()
    path = tmp_path / "specs" / "design.json"
    path.write_text(json.dumps(spec))
    return model, path


def test_design_writes_result_and_prints_the_error_table(tmp_path):
    model, spec = _write(tmp_path, {"model": "../models/cruise.json"})
    out = tmp_path / "out" / "design.json"
    result = runner.invoke(cli, [str(spec), "--out", str(out)])
    assert result.exit_code == 0, result.output
    design = json.loads(out.read_text())
    direct = optimal_tuners(model, 3, np.eye(2) * 1e-4, np.eye(10) * 0.01, np.eye(10) * 4.0)
    assert design["theory"]["ssee_health"] == pytest.approx(direct.theory.ssee_health, rel=1e-9)
    assert "SSEE" in result.stdout and "fan_eff" in result.stdout
    assert f"{design['theory']['ssee_health']:.4f}" in result.stdout
    design_from_result(design)  # the written file rebuilds to the same gain


def test_bad_spec_exits_with_a_message_and_writes_nothing(tmp_path):
    _, spec = _write(tmp_path, {"model": "../models/cruise.json", "sensors": ["Nf", "Fake"]})
    out = tmp_path / "design.json"
    result = runner.invoke(cli, [str(spec), "--out", str(out)])
    assert result.exit_code == 2
    assert "Fake" in result.output
    assert not out.exists()


def test_unobservable_design_is_refused(tmp_path):
    _, spec = _write(
        tmp_path, {"model": "../models/cruise.json", "sensors": ["Nf", "Nc"], "tuners": 3}
    )
    result = runner.invoke(cli, [str(spec), "--out", str(tmp_path / "d.json")])
    assert result.exit_code == 2 and "not observable" in result.output


def test_missing_model_file_is_a_usage_error(tmp_path):
    _, spec = _write(tmp_path)  # "models/cruise.json" does not exist next to specs/
    result = runner.invoke(cli, [str(spec), "--out", str(tmp_path / "d.json")])
    assert result.exit_code != 0 and "cannot read model file" in result.output


def test_register_adds_the_design_command_to_another_app(tmp_path):
    _, spec = _write(tmp_path, {"model": "../models/cruise.json"})
    app = typer.Typer()
    app.command("other")(lambda: None)
    register(app)
    out = tmp_path / "d.json"
    result = runner.invoke(app, ["design", str(spec), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert out.exists()
