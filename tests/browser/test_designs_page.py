"""Estimator designs in the browser: stacked squared bias and variance with Monte Carlo beside
them, confusion and misclassification heatmaps, two designs side by side, and a design created
from the page with its evaluation job watched to the end."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from app.db import transaction
from app.models.jobs import Job
from tests.browser.conftest import (
    Console,
    Server,
    api_get,
    screenshot,
    sign_in,
    traces,
)

pytestmark = [pytest.mark.browser, pytest.mark.long(seconds=30)]



def _data(page: Any, selector: str) -> list[dict[str, Any]]:
    result: list[dict[str, Any]] = page.evaluate(f"document.querySelector('{selector}').data")
    return result


def test_two_designs_side_by_side(page: Any, server: Server, console: Console) -> None:
    a, b = server.seeded.design_ids
    sign_in(page, server.seeded.key, f"/designs.html?a={a}&b={b}")
    design = api_get(server, f"/api/v1/designs/{a}")
    evaluation = api_get(server, f"/api/v1/designs/{a}/evaluation")
    health = _data(page, "#health-a")
    assert [t["name"] for t in health] == [
        "squared bias (theory)", "variance (theory)", "Monte Carlo squared error"
    ]
    theory = design["analytic_errors"]["health"]
    assert health[0]["y"] == pytest.approx(theory["bias2"])
    assert health[1]["y"] == pytest.approx(theory["variance"])
    assert health[1]["base"] == pytest.approx(theory["bias2"])  # stacked on the bias
    monte_carlo = evaluation["result"]["monte_carlo"]["health"]
    assert health[2]["y"] == pytest.approx(monte_carlo["squared_error"])
    aux = _data(page, "#aux-a")
    assert aux[0]["x"] == design["analytic_errors"]["aux"]["names"] and len(aux) == 2
    confusion = _data(page, "#confusion-a")[0]
    wssr_q = evaluation["result"]["confusion"]["wssr_q"]
    assert confusion["type"] == "heatmap"
    np.testing.assert_allclose(confusion["z"], wssr_q["percent"])
    assert confusion["x"] == wssr_q["faults"]
    cells = page.evaluate("document.querySelector('#confusion-a').layout.annotations.length")
    assert cells == len(wssr_q["faults"]) ** 2  # percentages written in the cells
    pmc = _data(page, "#pmc-a")[0]
    np.testing.assert_allclose(pmc["z"], design["result"]["faults"]["pmc"])
    # The run on the built-in nonlinear engine beside the linear one.
    engine = evaluation["result"]["nonlinear_engine"]
    assert engine is not None, evaluation["result"].get("nonlinear_engine_note")
    heat = _data(page, "#engine-confusion-a")[0]
    assert heat["type"] == "heatmap" and heat["x"] == engine["faults"]
    np.testing.assert_allclose(heat["z"], engine["confusion_percent"])
    bars = _data(page, "#engine-health-a")
    assert bars[0]["y"] == pytest.approx(engine["health"]["rms"])
    assert bars[1]["y"] == pytest.approx([100 * c for c in engine["health"]["coverage_95"]])
    assert bars[2]["y"] == pytest.approx(engine["health"]["floor"])  # the sensors' floor
    card = page.inner_text("#design-a")
    assert f"correct {engine['percent_correct']:.1f} %" in card
    assert engine["visibility"]["not_visible"]  # VBV on this engine
    for fault in engine["visibility"]["not_visible"]:
        assert fault in page.inner_text("#design-a .engine-invisible")
    ceiling = engine["visibility"]["ceiling_percent_correct"]
    assert f"more than {ceiling:.1f} % of all" in page.inner_text("#design-a .engine-invisible")
    # How the events' confidence was tempered on the run's second fleet.
    tempering = engine["posterior"]
    text = page.inner_text("#design-a .engine-tempering")
    assert f"tempered on {tempering['events']} other faulted engines" in text
    assert f"{tempering['wssr_scale']:.2f}" in text
    # Design B has no evaluation yet: theory only, and a button to run one.
    assert [t["name"] for t in traces(page, "#health-b")] == [
        "squared bias (theory)", "variance (theory)"
    ]
    assert "Run evaluation" in page.inner_text("#design-b")
    title = page.evaluate("document.querySelector('#health-a').layout.yaxis.title.text")
    assert "%²" in title
    screenshot(page, "designs-compare")
    # The placeholder's button runs the evaluation of design B in place.
    page.click("#design-b .run-evaluation")
    page.wait_for_selector("#confusion-b .main-svg", timeout=60_000)
    evaluated = api_get(server, f"/api/v1/designs/{b}/evaluation")
    assert evaluated["result"]["monte_carlo"]["n_cases"] == 200  # the job's seed 002 defaults
    page.select_option("#variant", "max_h")
    page.wait_for_function(
        "document.querySelector('#design-a').innerText.includes('largest health change')"
    )
    page.wait_for_selector("#confusion-a .main-svg")
    np.testing.assert_allclose(
        _data(page, "#confusion-a")[0]["z"], evaluation["result"]["confusion"]["max_h"]["percent"]
    )
    # An evaluation stored before the confidence's tempering says to run it again.
    with transaction(server.factory) as session:
        job = session.get(Job, evaluation["job_id"])
        assert job is not None and job.result is not None
        engine_run = {k: v for k, v in job.result["nonlinear_engine"].items() if k != "posterior"}
        job.result = {**job.result, "nonlinear_engine": engine_run}
    page.reload()
    page.wait_for_selector("#design-a .engine-tempering")
    assert "predates the tempering" in page.inner_text("#design-a .engine-tempering")
    assert console.unexpected() == []


def test_create_a_design_and_watch_its_evaluation(
    page: Any, server: Server, console: Console
) -> None:
    sign_in(page, server.seeded.key, "/designs.html")
    page.evaluate(
        """() => { window.jobText = [];
        new MutationObserver(() => window.jobText.push(document.querySelector('#job').innerText))
        .observe(document.querySelector('#job'), {childList: true, subtree: true}); }"""
    )
    page.fill("#name", "browser SVD m = 5")
    page.select_option("#method", "svd")
    page.fill("#tuners", "5")
    page.click("#create-button")
    page.wait_for_selector("#job .progress", timeout=60_000)
    # The design step's badge turns "succeeded" first; the evaluation's job follows in the
    # same box: wait for that one (on a slow machine the design step's alone was seen).
    page.wait_for_function(
        "document.querySelector('#job').innerText.includes('Monte Carlo evaluation of design')"
        " && document.querySelector('#job .badge.succeeded') !== null", timeout=150_000)
    page.wait_for_selector("#design-b #confusion-b .main-svg", timeout=30_000)
    created = [d for d in api_get(server, "/api/v1/designs?limit=200")["items"]
               if d["name"] == "browser SVD m = 5"]
    assert len(created) == 1 and created[0]["spec"]["tuners"] == 5
    assert page.input_value("#b") == str(created[0]["id"])
    # Both jobs were watched on the page: the design step, then the Monte Carlo evaluation.
    seen = " ".join(page.evaluate("window.jobText"))
    assert f"Design step of design {created[0]['id']}" in seen
    assert f"Monte Carlo evaluation of design {created[0]['id']}" in seen
    design_jobs = api_get(server, "/api/v1/jobs?kind=create_design")["items"]
    mine = [j for j in design_jobs if j["parameters"]["design_id"] == created[0]["id"]]
    assert [j["status"] for j in mine] == ["succeeded"]
    evaluation = api_get(server, f"/api/v1/designs/{created[0]['id']}/evaluation")
    assert evaluation is not None
    assert [t["name"] for t in traces(page, "#health-b")][-1] == "Monte Carlo squared error"
    screenshot(page, "designs-created")
    # A bad spec (more tuners than health parameters) is refused with the API's reason.
    page.fill("#name", "too many tuners")
    page.fill("#tuners", "40")
    page.click("#create-button")
    error = page.wait_for_selector("#create-message .error")
    assert "tuners" in error.inner_text() and "422" in error.inner_text()
    assert console.unexpected("422") == []


def test_calibration_state_and_the_button_that_runs_it(
    page: Any, server: Server, console: Console
) -> None:
    """A built-in engine design's card says whether it is calibrated against the simulator
    (and whether before the engine page's other bands were) and runs the calibration job from
    its button."""
    from app.models import EstimatorDesign
    from estimation.uncertainty import Calibration

    design_id = server.seeded.design_ids[0]

    def state() -> str:
        page.goto(f"/designs.html?a={design_id}")
        page.wait_for_selector("#design-a .calibration-state")
        text: str = page.inner_text("#design-a .calibration-state")
        return text

    sign_in(page, server.seeded.key, f"/designs.html?a={design_id}")
    assert state().startswith("not calibrated")
    assert page.inner_text("#design-a .run-calibration") == "Calibrate against the simulator"
    one = {"names": ("fan_eff",), "level_std": np.zeros(1), "change_std": np.zeros(1),
           "slope_error": np.zeros(1), "bias2": np.zeros(1), "drift": np.zeros(1),
           "observable": np.ones(1, bool)}
    with transaction(server.factory) as session:
        design = session.get(EstimatorDesign, design_id)
        assert design is not None
        before = design.result
        old = Calibration(**one, source={"seeds": [1, 2], "engines": 38, "records": 9000})
        design.result = {**(before or {}), "uncertainty": old.to_dict()}
    try:
        text = state()
        assert text.startswith("calibrated on 2 simulated fleets, 38 engines, 9000 records before")
        assert "calibrate again" in text
        with transaction(server.factory) as session:
            design = session.get(EstimatorDesign, design_id)
            assert design is not None
            kw = dict(source={"seeds": [1, 2], "engines": 38, "records": 9000},
                      tuner_names=("q1",), tuner_std=np.ones(1), delta_names=("dEGT",),
                      delta_std=np.ones(1), aux_names=("Fn",), aux_std=np.ones(1))
            # Before the calibrated aux outputs and the rate of change's sigma: again.
            design.result = {**(before or {}),
                             "uncertainty": Calibration(**one, **kw).to_dict()}
        assert "calibrate again" in state()
        with transaction(server.factory) as session:
            design = session.get(EstimatorDesign, design_id)
            assert design is not None
            full = Calibration(**one, **kw, aux_correction=np.zeros((1, 3)),
                               rate_std=np.zeros(1))
            design.result = {**(before or {}), "uncertainty": full.to_dict()}
        assert "every band of the engine page" in state()
        streams = page.inner_text("#design-a .stream-calibration-state")
        assert streams.startswith("stream estimates not calibrated"), streams
        with transaction(server.factory) as session:
            design = session.get(EstimatorDesign, design_id)
            assert design is not None
            stream = Calibration(**one, source={"flights": 256, "windows": 600000})
            design.result = {**design.result, "stream_uncertainty": stream.to_dict()}
        state()
        streams = page.inner_text("#design-a .stream-calibration-state")
        # Made before the calibration carried an engine's tuners from flight to flight.
        assert streams.startswith("stream estimates calibrated on 256 simulated flights"), streams
        assert "calibrate again" in streams, streams
        with transaction(server.factory) as session:
            design = session.get(EstimatorDesign, design_id)
            assert design is not None
            stream = Calibration(**one, source={"flights": 256, "windows": 600000,
                                                "carried": True})
            design.result = {**design.result, "stream_uncertainty": stream.to_dict()}
        state()
        streams = page.inner_text("#design-a .stream-calibration-state")
        assert streams.startswith("stream estimates calibrated on 256 simulated flights"), streams
        assert "again" not in streams and "shown Fan efficiency" in streams, streams
        # The button queues the calibration job, watched with its progress (cancelled here: a
        # real calibration takes minutes).
        page.click("#design-a .run-calibration")
        page.wait_for_selector("#job progress, #job .progress")
        with transaction(server.factory) as session:
            job = session.query(Job).filter(Job.kind == "calibrate_design").order_by(
                Job.id.desc()).first()
            assert job is not None and job.parameters["design_id"] == design_id
            job_id = job.id
        api_post = page.request.post(f"/api/v1/jobs/{job_id}/cancel",
                                     headers={"X-API-Key": server.seeded.key})
        assert api_post.ok
        page.wait_for_function("document.querySelector('#job').innerText.includes('cancel')")
        # A calibration someone else started (the demo's first start queues one): the card
        # names it instead of offering a second, the job box follows it, and its end shows
        # what it stored.
        with transaction(server.factory) as session:
            design = session.get(EstimatorDesign, design_id)
            assert design is not None
            running = Job(operator_id=design.operator_id, kind="calibrate_design",
                          parameters={"design_id": design_id, "snapshots": False},
                          checksum="browser-test", status="running", progress=0.4,
                          message="simulating recorded flights")
            session.add(running)
            session.flush()
            running_id = running.id
        state()
        page.wait_for_selector("#design-a .calibration-running")
        text = page.inner_text("#design-a .calibration-running")
        assert f"#{running_id} running (40 %)" in text, text
        assert page.query_selector("#design-a .run-calibration") is None
        page.wait_for_function(
            "document.querySelector('#job').innerText.includes('simulating recorded flights')")
        with transaction(server.factory) as session:
            job = session.get(Job, running_id)
            assert job is not None
            job.status, job.progress = "succeeded", 1.0
        page.wait_for_selector("#design-a .run-calibration")
        assert page.query_selector("#design-a .calibration-running") is None
    finally:
        with transaction(server.factory) as session:
            design = session.get(EstimatorDesign, design_id)
            assert design is not None
            design.result = before
            for job in session.query(Job).filter(Job.checksum == "browser-test"):
                session.delete(job)
