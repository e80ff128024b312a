"""The recording page: a whole-flight stream uploaded on the engine and at the time of a seeded
event shows its samples, the tuners and health parameters with their 1-sigma bands and the
event; the transient index and bias correction are drawn when the estimates carry them; the
engine page and the uploads page link to it."""

from __future__ import annotations

import json
import time
from datetime import datetime, timedelta
from typing import Any

import httpx
import numpy as np
import pytest

from app.db import transaction
from app.models import EstimatorDesign
from app.services.streams.estimator import CALIBRATION_KEY
from estimation.uncertainty import Calibration, correction_width
from tests.browser.conftest import (
    Console,
    Server,
    api_get,
    cruise_stream_csv,
    screenshot,
    sign_in,
    traces,
)

pytestmark = pytest.mark.browser

N = 1200  # one minute at 20 Hz
DT = 0.05



def _cruise_csv(seed: int) -> tuple[bytes, list[str]]:
    return cruise_stream_csv(seed, N, DT)


def test_recording_page_samples_estimates_events_and_links(
    page: Any, server: Server, console: Console
) -> None:
    seeded = server.seeded
    assert seeded.event_id is not None
    event = api_get(server, f"/api/v1/events/{seeded.event_id}")
    started = datetime.fromisoformat(event["detected_at"]) - timedelta(seconds=30)
    body, sensors = _cruise_csv(seed=21)
    response = httpx.post(
        f"{server.base_url}/api/v1/streams", content=body,
        headers={"X-API-Key": seeded.key, "Content-Type": "text/csv"},
        params={"tail": event["tail"], "position": event["position"],
                "started_at": started.isoformat()},
    )
    assert response.status_code == 201, response.text[:400]
    rid = response.json()["recording"]["id"]
    assert response.json()["recording"]["engine_id"] == event["engine_id"]
    deadline = time.monotonic() + 120
    while True:  # the upload queued the estimation job; the server's runner runs it
        est = api_get(server, f"/api/v1/streams/{rid}/estimates")
        if est["n_samples_estimated"] == N:
            break
        failed = api_get(server, "/api/v1/jobs?kind=estimate_recording&status=failed")["items"]
        assert failed == [], failed[0]["error"]
        assert time.monotonic() < deadline, "the recording was not estimated in time"
        time.sleep(0.5)

    sign_in(page, seeded.key, f"/recording.html?id={rid}")
    samples = traces(page, "#samples-plot")
    design_sensors = set(est["names"]["sensors"])
    assert design_sensors <= {t["name"] for t in samples} <= set(sensors)
    assert all(t["n"] == N for t in samples)  # a minute is drawn whole
    tuners = traces(page, "#tuners-plot")
    m = len(est["names"]["tuners"])
    assert [t["role"] for t in tuners] == ["band", "line"] * m
    assert [t["name"] for t in tuners if t["role"] == "line"] == est["names"]["tuners"]
    assert all(t["n"] == N * DT for t in tuners if t["role"] == "line")  # one-second windows
    # A band is the polygon value +- sigma: twice the windows' points.
    assert all(t["n"] == 2 * N * DT for t in tuners if t["role"] == "band")
    health = [t["name"] for t in traces(page, "#health-plot") if t["role"] == "line"]
    assert health == est["names"]["health"]
    # The seeded event falls in the recording: listed, and marked on the plots.
    assert page.locator(f"#events a[href='/events.html?id={seeded.event_id}']").count() == 1
    shapes = page.evaluate("document.querySelector('#tuners-plot').layout.shapes.length")
    assert shapes == 1
    # These estimates have neither a transient index nor a bias correction: said so.
    assert page.locator("#transient-absent").is_visible()
    assert page.locator("#bias-absent").is_visible()
    # The seeded design has no stream calibration: the note says the bands are the filter's.
    note = page.locator("#estimates-note")
    assert note.get_attribute("data-uncertainty") == "uncalibrated"
    assert "stream filter's own 1σ" in note.inner_text()
    screenshot(page, "recording")

    # With a stream calibration (synthetic here: one health parameter and one tuner
    # unobservable), the page draws the calibrated estimates, names what it hides and says
    # what the bands are.
    names, tuner_names = est["names"]["health"], est["names"]["tuners"]
    p, m = len(names), len(tuner_names)
    calib = Calibration(
        names=tuple(names), level_std=np.full(p, 0.3), change_std=np.zeros(p),
        slope_error=np.zeros(p), bias2=np.zeros(p), drift=np.zeros(p),
        observable=np.arange(p) > 0, tuner_names=tuple(tuner_names), tuner_std=np.full(m, 0.2),
        tuner_correction=np.zeros((m, correction_width(p))), tuner_observable=np.arange(m) > 0,
        source={"sensors": est["names"]["sensors"]})
    with transaction(server.factory) as session:
        design = session.get(EstimatorDesign, est["design_id"])
        assert design is not None
        before = design.result
        design.result = {**before, CALIBRATION_KEY: calib.to_dict()}
    try:
        page.reload()
        page.wait_for_selector("body[data-ready=true]")
        assert note.get_attribute("data-uncertainty") == "calibrated"
        text = note.inner_text()
        assert "Calibrated on the built-in engine's simulated flights" in text
        assert "Not observable with this design" in text
        drawn = [t["name"] for t in traces(page, "#health-plot") if t["role"] == "line"]
        assert drawn == names[1:]
        drawn = [t["name"] for t in traces(page, "#tuners-plot") if t["role"] == "line"]
        assert drawn == tuner_names[1:]
    finally:
        with transaction(server.factory) as session:
            design = session.get(EstimatorDesign, est["design_id"])
            assert design is not None
            design.result = before
        page.reload()
        page.wait_for_selector("body[data-ready=true]")

    # Estimates that carry them (seed 004's bias compensation) are drawn.
    def with_bias(route: Any) -> None:
        got = route.fetch()
        data = got.json()
        windows = len(data["t_s"])
        data["transient_index"] = [0.1 * k for k in range(windows)]
        data["bias_correction"] = {s: [0.5] * windows for s in data["names"]["sensors"][:2]}
        route.fulfill(response=got, body=json.dumps(data))

    page.route("**/api/v1/streams/*/estimates*", with_bias)
    page.reload()
    page.wait_for_selector("body[data-ready=true]")
    assert [t["n"] for t in traces(page, "#transient-plot")] == [N * DT]
    assert [t["name"] for t in traces(page, "#bias-plot")] == est["names"]["sensors"][:2]
    page.unroute("**/api/v1/streams/*/estimates*")

    # Linked from the engine page and from the uploads page.
    page.goto(f"/engine.html?id={event['engine_id']}")
    page.wait_for_selector("body[data-ready=true]")
    page.click(f"#recordings a[href='/recording.html?id={rid}']")
    page.wait_for_url(f"**/recording.html?id={rid}")
    page.wait_for_selector("body[data-ready=true]")
    page.goto("/uploads.html")
    page.wait_for_selector("body[data-ready=true]")
    page.click(f"#recordings a[href='/recording.html?id={rid}']")
    page.wait_for_url(f"**/recording.html?id={rid}")
    page.wait_for_selector("body[data-ready=true]")
    assert console.unexpected() == []
