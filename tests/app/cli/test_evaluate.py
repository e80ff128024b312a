"""``fleethealth evaluate`` on a design result file written like ``fleethealth design``."""

import json

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from app.cli.evaluate import register
from estimation import evaluate as ev
from estimation.design import design_from_result, run_design
from tests.estimation.models import HEALTH_10, reference_model, reference_noise


def _app() -> typer.Typer:
    """The sub-app mounted the way the ``fleethealth`` entry point mounts it."""
    app = typer.Typer()

    @app.command()
    def version() -> None:  # a second command so the app is a group
        pass

    register(app)
    return app


@pytest.fixture(scope="module")
def design_file(tmp_path_factory):
    model = reference_model(actuator_bias=True)
    noise = reference_noise(model.select_health(list(HEALTH_10)))
    spec = {
        "format": "fleethealth.design-spec/1",
        "model": "model.json",
        "health": list(HEALTH_10),
        "method": "optimal",
        "tuners": 6,
        "noise": {
            "Q": np.sqrt(np.diag(noise["Q"])).tolist(),
            "Qh": np.sqrt(np.diag(noise["Qh"])).tolist(),
            "Ph": np.sqrt(np.diag(noise["Ph"])).tolist(),
        },
    }
    result = run_design(spec, model)
    path = tmp_path_factory.mktemp("design") / "design.json"
    path.write_text(json.dumps(result))
    return path


def test_evaluate_writes_monte_carlo_and_confusion(design_file, tmp_path):
    out = tmp_path / "result.json"
    args = ["evaluate", str(design_file), "--monte-carlo", "300", "--seed", "3", "--faults",
            "--fault-duration", "20", "--out", str(out)]
    res = CliRunner().invoke(_app(), args)
    assert res.exit_code == 0, res.output
    data = json.loads(out.read_text())
    mc = data["monte_carlo"]
    assert mc["health"]["names"] == list(HEALTH_10)
    assert len(mc["health"]["squared_error"]) == 10
    assert mc["ssee_health"] == pytest.approx(sum(mc["health"]["squared_error"]))
    # The printed theory is the design file's theory.
    stored = json.loads(design_file.read_text())
    assert mc["ssee_health_theory"] == pytest.approx(stored["theory"]["ssee_health"], rel=1e-9)
    # Same seed through the library gives the same experiment.
    design = design_from_result(stored)
    direct = ev.ssee_monte_carlo(design, 300, rng=np.random.default_rng(3))
    np.testing.assert_allclose(mc["health"]["squared_error"], direct.squared_error, rtol=1e-12)
    for variant in ("wssr_q", "wssr_y", "max_h"):
        conf = data["confusion"][variant]
        assert conf["faults"] == ["Fan", "LPC", "HPC", "HPT", "LPT", "Wf", "VSV", "VBV"]
        np.testing.assert_allclose(np.sum(conf["percent"], axis=1), 100.0)
    assert "overall correct isolation rate" in res.output
    assert "SSEE" in res.output


def test_evaluate_is_repeatable_and_seed_dependent(design_file, tmp_path):
    outs = []
    for seed in (1, 1, 2):
        out = tmp_path / f"r{len(outs)}.json"
        res = CliRunner().invoke(
            _app(), ["evaluate", str(design_file), "--monte-carlo", "20", "--seed", str(seed),
                     "--out", str(out), "--duration", "5", "--window", "2"],
        )
        assert res.exit_code == 0, res.output
        outs.append(json.loads(out.read_text())["monte_carlo"]["ssee_health"])
    assert outs[0] == outs[1] != outs[2]


def _text(output: str) -> str:
    """The message without the error box's borders and line wrapping."""
    return " ".join(output.replace("\u2502", " ").split())


def test_evaluate_rejects_missing_and_bad_files(tmp_path):
    res = CliRunner().invoke(_app(), ["evaluate", str(tmp_path / "nope.json")])
    assert res.exit_code != 0
    assert "does not exist" in _text(res.output)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"format": "something-else"}))
    res = CliRunner().invoke(_app(), ["evaluate", str(bad)])
    assert res.exit_code != 0
    assert "format must be" in _text(res.output)


def test_evaluate_with_progress_bar_forced(design_file, tmp_path):
    """The progress bar path (on by default on a terminal) runs and changes no result."""
    outs = []
    for flag in ("--progress", "--no-progress"):
        out = tmp_path / f"{flag}.json"
        res = CliRunner().invoke(
            _app(), ["evaluate", str(design_file), "--monte-carlo", "10", "--duration", "3",
                     "--window", "1", "--faults", "--fault-duration", "3", flag, "--out", str(out)],
        )
        assert res.exit_code == 0, res.output
        outs.append(json.loads(out.read_text()))
    assert outs[0]["monte_carlo"] == outs[1]["monte_carlo"]
    assert outs[0]["confusion"] == outs[1]["confusion"]
