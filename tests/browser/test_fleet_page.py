"""Sign-in and the fleet status page in a real browser."""

from __future__ import annotations

from datetime import timedelta
from typing import Any

import httpx
import numpy as np
import pytest

from app.db import transaction
from app.models import EstimatorDesign
from app.services.designs.calibration import BASELINE_SETTLE_RECORDS
from estimation.engine.deltas import STATUS_EGT_MARGIN
from estimation.uncertainty import YEAR_S, Calibration
from tests.app.services.trends.test_trends import (
    LAYOUT,
    T0,
    add_aircraft,
    add_engine,
    add_estimates,
    as_stored,
    make_fleet,
)
from tests.browser.conftest import Console, Server, screenshot, sign_in, traces

pytestmark = [pytest.mark.browser, pytest.mark.long(seconds=20)]


def test_wrong_key_is_refused_with_the_api_message(page: Any, console: Console) -> None:
    page.goto("/")
    page.wait_for_url("**/signin.html**")  # no key yet: the dashboard sends you to sign in
    page.fill("#key", "fh_wrong_key")
    page.click("button[type=submit]")
    error = page.wait_for_selector(".error")
    assert "Sign-in failed" in error.inner_text() and "401" in error.inner_text()
    assert page.evaluate("localStorage.getItem('fleethealth.apiKey')") is None
    screenshot(page, "signin-wrong-key")
    # The browser logs the refused request itself; nothing else may fail.
    assert console.unexpected("401") == []


def test_fleet_status_lists_every_engine_and_plots_deterioration(
    page: Any, server: Server, console: Console
) -> None:
    sign_in(page, server.seeded.key, "/")
    rows = page.locator("#table tbody tr")
    esns = sorted(server.seeded.engine_ids)
    assert rows.count() == len(esns)
    assert sorted(page.locator("#table tbody tr td:first-child").all_inner_texts()) == esns
    # Sorting by ESN puts them in order; filtering by one ESN leaves one row.
    page.click("th[data-key=esn]")
    assert page.locator("#table tbody tr td:first-child").all_inner_texts() == esns
    page.fill("#filter", esns[-1])
    assert page.locator("#table tbody tr").count() == 1
    page.fill("#filter", "")
    # One deterioration trace per health parameter of the design, with units on the y axis.
    plotted = traces(page, "#deterioration")
    names = {t["name"] for t in plotted}
    assert {"fan_eff", "hpc_eff", "hpc_flow", "lpt_flow"} <= names
    assert len(plotted) == 10
    title = page.evaluate("document.querySelector('#deterioration').layout.yaxis.title.text")
    assert "[%]" in title and "health level" in title
    # The fleet-average slope of each health parameter: as the API gives it, a number or why
    # there is none.
    slopes = httpx.get(f"{server.base_url}/api/v1/fleet/deterioration/slopes",
                       headers={"X-API-Key": server.seeded.key}).json()["groups"][0]
    cells = page.locator("#slopes tbody tr td:last-child").all_inner_texts()
    assert len(cells) == len(slopes["health"]) == 10
    for cell, item in zip(cells, slopes["health"], strict=True):
        if item["slope"] is None:
            assert cell.startswith("unobservable" if item["name"] in slopes["unobservable"]
                                   else "no trend yet")
        else:
            assert float(cell.split("±")[0]) == pytest.approx(item["slope"], abs=0.01)
    # Each engine's EGT margin as the status gives it, worst at the top, coloured by level.
    status = httpx.get(f"{server.base_url}/api/v1/fleet/status",
                       headers={"X-API-Key": server.seeded.key}).json()
    margins = {e["esn"]: c for e in status["engines"] for c in e["checks"]
               if c["limit"] == "egt_margin" and c["value"] is not None}
    assert margins, "the seeded fleet's engines have an EGT margin"
    page.wait_for_function("document.querySelector('#egt-plot').data?.length === 1")
    bars = page.evaluate("(() => { const t = document.querySelector('#egt-plot').data[0];"
                         " return {y: t.y, x: t.x, colour: t.marker.color}; })()")
    assert len(bars["y"]) == len(margins)
    assert [label.split(" ")[0] for label in bars["y"]] == sorted(
        margins, key=lambda esn: -margins[esn]["value"])  # the worst drawn at the top
    assert bars["x"] == pytest.approx(sorted((c["value"] for c in margins.values()),
                                             reverse=True))
    colours = {"red": "#D55E00", "amber": "#E69F00", "normal": "#009E73"}
    assert bars["colour"] == [colours[margins[label.split(" ")[0]]["level"]]
                              for label in bars["y"]]
    # The seeded design is not calibrated: no 1-sigma, no error bars.
    assert all(c["sigma"] is None for c in margins.values())
    assert not page.evaluate("document.querySelector('#egt-plot').data[0].error_x.visible")
    screenshot(page, "fleet-status")
    # Every plot exports its data as CSV from the mode bar: one row per plotted point.
    page.hover("#deterioration")
    with page.expect_download() as download_info:
        page.click("#deterioration [data-title='Download data as CSV']")
    lines = download_info.value.path().read_text().splitlines()
    assert lines[0] == "trace,x,y,error"
    assert len(lines) - 1 == sum(t["n"] for t in plotted)
    # Weekly buckets: the same parameters on more points.
    monthly = plotted[0]["n"]
    page.select_option("#bucket", "week")
    page.wait_for_function(
        "(n) => document.querySelector('#deterioration').data[0].x.length > n", arg=monthly
    )
    assert len(traces(page, "#deterioration")) == len(plotted)
    page.select_option("#which", "aux")
    page.wait_for_function(
        "document.querySelector('#deterioration').data.some((t) => t.meta.code === 'Fn')"
    )
    assert console.unexpected() == []


def test_a_key_revoked_mid_session_sends_the_user_back_to_sign_in(
    page: Any, server: Server, console: Console
) -> None:
    admin = {"X-API-Key": server.seeded.key}
    created = httpx.post(
        f"{server.base_url}/api/v1/keys", json={"name": "night shift", "role": "viewer"},
        headers=admin,
    ).json()
    sign_in(page, created["key"], "/events.html")
    revoked = httpx.delete(f"{server.base_url}/api/v1/keys/{created['id']}", headers=admin)
    assert revoked.status_code == 200
    page.select_option("#status", "closed")  # the next API call answers 401
    page.wait_for_url("**/signin.html**")
    assert "sign in again" in page.inner_text("#message")
    assert page.evaluate("localStorage.getItem('fleethealth.apiKey')") is None
    screenshot(page, "signin-after-revocation")
    assert console.unexpected("401") == []


def test_fleet_slopes_show_the_sigma_with_units_and_ask_to_recalibrate(
    page: Any, server: Server, console: Console
) -> None:
    """An operator of its own with a year of trends and a calibrated design: each shown slope
    reads "slope ± sigma %/year" as the API gives them, the unobservable one says so; with a
    calibration stored before the gain's standard error was, the slope stays and the cell asks
    to recalibrate instead of showing a sigma."""
    with transaction(server.factory) as session:
        fleet = make_fleet(session, "Slope Page Air")
        aircraft = add_aircraft(session, fleet, "F-SLOPE")
        rng = np.random.default_rng(3)
        h = LAYOUT.slices()["h"]
        days = np.arange(365)
        for i, rate in enumerate(([-1.0, -0.8, 0.4], [-1.2, -0.6, 0.5])):
            engine = add_engine(session, fleet, f"SLOPE-{i}")
            v = rng.normal(size=(len(days), LAYOUT.width)) * 0.01
            v[:, h] = np.outer(days * 86400.0 / YEAR_S, rate)
            add_estimates(session, fleet, engine, aircraft, v,
                          [T0 + timedelta(days=int(d)) for d in days])
        calib = Calibration(
            names=("fan_eff", "hpc_eff", "hpc_flow"), level_std=np.zeros(3),
            change_std=np.zeros(3), slope_error=np.zeros(3), bias2=np.zeros(3),
            drift=np.zeros(3), observable=np.array([False, True, True]),
            slope_gain=np.array([1.0, 1.1, 0.9]), slope_noise=np.full(3, 0.02),
            slope_common=np.full(3, 0.001), slope_gain_std=np.array([0.1, 0.05, 0.04]),
        )
        design = session.get(EstimatorDesign, fleet.design.id)
        assert design is not None
        design.result = {"uncertainty": calib.to_dict()}
        key, design_id = fleet.key, design.id

    def api_slopes() -> dict[str, Any]:
        return httpx.get(f"{server.base_url}/api/v1/fleet/deterioration/slopes",
                         headers={"X-API-Key": key}).json()["groups"][0]

    def cells() -> list[str]:
        return page.locator("#slopes tbody tr td:last-child").all_inner_texts()

    sign_in(page, key, "/")
    slopes = api_slopes()
    assert slopes["uncertainty"] == "calibrated" and slopes["unit"] == "%/year"
    header = page.locator("#slopes thead th").all_inner_texts()[-1]
    assert header == "Slope ± 1σ [%/year]"
    shown = 0
    for cell, item in zip(cells(), slopes["health"], strict=True):
        if item["name"] in slopes["unobservable"]:
            assert cell == "unobservable"
            continue
        assert item["sigma"] is not None and item["sigma"] > 0.0
        assert cell == f"{item['slope']:.2f} ± {item['sigma']:.2f} %/year"
        shown += 1
    assert shown == 2
    screenshot(page, "fleet-slopes")
    with transaction(server.factory) as session:
        design = session.get(EstimatorDesign, design_id)
        assert design is not None
        stale = {k: v for k, v in calib.to_dict().items() if k != "slope_gain_std"}
        design.result = {"uncertainty": stale}
    page.reload()
    page.wait_for_selector("body[data-ready=true]")
    page.wait_for_function("document.querySelector('#slopes tbody') !== null")
    before = api_slopes()
    assert before["uncertainty"] == "recalibrate"
    for cell, item in zip(cells(), before["health"], strict=True):
        if item["name"] not in before["unobservable"]:
            assert item["sigma"] is None
            assert cell == f"{item['slope']:.2f} %/year (1σ: recalibrate the design)"
    assert "recalibrate the design for a σ" in page.locator("#slopes .legend-note").inner_text()
    assert console.unexpected() == []


def test_engine_page_draws_the_calibrated_level_the_api_gives(
    page: Any, server: Server, console: Console
) -> None:
    """A design calibrated with a level correction: the engine page's health plot draws the
    corrected change the API gives (not the stored estimate's), says that the estimate is
    calibrated, and names the unobservable parameter."""
    with transaction(server.factory) as session:
        fleet = make_fleet(session, "Calibrated Level Air")
        aircraft = add_aircraft(session, fleet, "F-CALIB")
        engine = add_engine(session, fleet, "CALIB-1")
        rng = np.random.default_rng(4)
        v = rng.normal(size=(200, LAYOUT.width)) * 0.05
        v[:, LAYOUT.slices()["h"]] += np.linspace(0.0, -2.0, 200)[:, None]
        add_estimates(session, fleet, engine, aircraft, v,
                      [T0 + timedelta(hours=12 * i) for i in range(200)])
        calib = Calibration(
            names=("hpc_eff", "hpc_flow", "fan_eff"), level_std=np.full(3, 0.1),
            change_std=np.full(3, 0.05), slope_error=np.zeros(3), bias2=np.zeros(3),
            drift=np.zeros(3), observable=np.array([True, True, False]),
            level_correction=np.array([[0.1, 0.5, 0.0, 0.0], [0.0, 0.0, -0.5, 0.0],
                                       [0.0, 0.0, 0.0, 0.0]]),
            # Fn calibrated (0.3 off its estimate), SmHPC not.
            aux_names=("Fn", "SmHPC"), aux_std=np.full(2, 0.1),
            aux_correction=np.array([[0.3] + [0.0] * 9, [0.0] * 10]),
            # q1 calibrated (0.2 off its estimate), q2 unobservable.
            tuner_names=("q1", "q2"), tuner_std=np.full(2, 0.1),
            tuner_correction=np.array([[0.2] + [0.0] * 9, [0.0] * 10]),
            tuner_observable=np.array([True, False]),
        )
        design = session.get(EstimatorDesign, fleet.design.id)
        assert design is not None
        design.result = {"uncertainty": calib.to_dict()}
        key, engine_id = fleet.key, engine.id
    sign_in(page, key, f"/engine.html?id={engine_id}")
    page.wait_for_function("document.querySelector('#plot-health') !== null "
                           "&& (document.querySelector('#plot-health').data || []).length > 0")
    api = httpx.get(f"{server.base_url}/api/v1/engines/{engine_id}/trend",
                    params={"max_points": 1000, "health": "change"},
                    headers={"X-API-Key": key}).json()
    health = next(g for g in api["groups"] if g["key"] == "health")
    assert health["uncertainty"] == "calibrated" and health["unobservable"] == ["fan_eff"]
    drawn = page.evaluate(
        "document.querySelector('#plot-health').data"
        ".filter((t) => t.meta && t.meta.role === 'line')"
        ".map((t) => ({code: t.meta.code, y: t.y}))")
    by_code = {t["code"]: t["y"] for t in drawn}
    for series in health["series"]:
        if series["name"] == "fan_eff":
            assert "fan_eff" not in by_code
            continue
        api_y = [y for y in series["value"] if y is not None]
        plot_y = [y for y in by_code[series["name"]] if y is not None]
        np.testing.assert_allclose(plot_y, api_y, atol=1e-9)
    # hpc_eff's error is half its estimate (its row of the correction): the change shown is
    # half the stored one, from the baseline record on.
    hpc = next(s for s in health["series"] if s["name"] == "hpc_eff")["value"]
    base = BASELINE_SETTLE_RECORDS
    stored = v[:, LAYOUT.slices()["h"]][:, 0]
    assert hpc[base - 1] is None
    assert hpc[-1] == pytest.approx(0.5 * (stored[-1] - stored[base]), abs=1e-3)
    notes = page.locator("#plots").inner_text() if page.locator("#plots").count() else \
        page.inner_text("body")
    assert "Calibrated on the built-in engine's simulator" in notes
    assert "Not observable with this design" in notes
    # The aux outputs: the API names the calibrated ones, the plot draws their calibrated
    # values, and its card says so.
    aux = next(g for g in api["groups"] if g["key"] == "aux")
    assert aux["calibrated_series"] == ["Fn"]
    fn = next(s for s in aux["series"] if s["name"] == "Fn")["value"]
    assert fn[-1] == pytest.approx(float(as_stored(v)[-1, LAYOUT.slices()["z"]][0]) - 0.3,
                                   abs=1e-3)
    card = page.locator("#plot-aux").locator("xpath=..").inner_text()
    assert "the estimate corrected for how this design reads the engine" in card
    # The tuners: the calibrated one drawn at its calibrated value, the unobservable one
    # named on the card and not drawn.
    tuners = next(g for g in api["groups"] if g["key"] == "tuners")
    assert tuners["calibrated_series"] == ["q1"] and tuners["unobservable"] == ["q2"]
    q1 = next(s for s in tuners["series"] if s["name"] == "q1")["value"]
    assert q1[-1] == pytest.approx(float(as_stored(v)[-1, LAYOUT.slices()["q"]][0]) - 0.2,
                                   abs=1e-3)
    drawn_tuners = page.evaluate(
        "document.querySelector('#plot-tuners').data"
        ".filter((t) => t.meta && t.meta.role === 'line').map((t) => t.meta.code)")
    assert drawn_tuners == ["q1"], drawn_tuners
    card = page.locator("#plot-tuners").locator("xpath=..").inner_text()
    assert "Not observable with this design" in card
    assert "the tuners of the calibrated health above" in card
    assert console.unexpected() == []


def test_egt_margins_carry_the_calibrated_sigma(page: Any, server: Server,
                                                console: Console) -> None:
    """With the active design calibrated, each EGT margin bar has its 1-sigma error bar and
    says it in its hover, as the status gives it (the calibration's fit of the status's EGT
    margin against the simulator's truth)."""
    design_id = server.seeded.design_ids[0]
    with transaction(server.factory) as session:
        design = session.get(EstimatorDesign, design_id)
        assert design is not None
        before = design.result
        design.result = {**(before or {}), "uncertainty": Calibration(
            names=("fan_eff",), level_std=np.zeros(1), change_std=np.zeros(1),
            slope_error=np.zeros(1), bias2=np.zeros(1), drift=np.zeros(1),
            observable=np.ones(1, bool), delta_names=(STATUS_EGT_MARGIN,),
            delta_std=np.array([3.25]), aux_names=("Fn",), aux_std=np.array([0.4])).to_dict()}
    try:
        sign_in(page, server.seeded.key, "/")
        page.wait_for_function("document.querySelector('#egt-plot').data?.length === 1")
        status = httpx.get(f"{server.base_url}/api/v1/fleet/status",
                           headers={"X-API-Key": server.seeded.key}).json()
        margins = [c for e in status["engines"] for c in e["checks"]
                   if c["limit"] == "egt_margin"]
        assert margins and all(c["sigma"] == 3.25 for c in margins)
        bars = page.evaluate("(() => { const t = document.querySelector('#egt-plot').data[0];"
                             " return {error: t.error_x, hover: t.customdata}; })()")
        assert bars["error"]["visible"] and bars["error"]["array"] == [3.25] * len(margins)
        assert all(text.endswith("(±3.2 °C, 1σ)") or text.endswith("(±3.3 °C, 1σ)")
                   for text in bars["hover"])
        # The table's thrust deficit with its 1-sigma, and every check with its own in the
        # reason's tooltip, as the status gives them.
        by_esn = {e["esn"]: e for e in status["engines"]}
        thrusts = 0
        for row in page.locator("#table tbody tr").all():
            cells = row.locator("td").all_inner_texts()
            engine = by_esn[cells[0]]
            checks = {c["limit"]: c for c in engine["checks"]}
            thrust = checks.get("thrust_deficit")
            if thrust is not None:
                thrusts += 1
                assert thrust["sigma"] is not None and thrust["sigma"] >= 0.4
                value, sigma = (float(x) for x in cells[8].split("±"))
                assert value == pytest.approx(engine["health"]["thrust_deficit"], abs=0.006)
                assert sigma == pytest.approx(thrust["sigma"], abs=0.006)
            tip = row.locator("td:nth-child(7) span").first.get_attribute("title") or ""
            assert len(tip.splitlines()) == len(checks)
            if "egt_margin" in checks:
                assert "± 3.25 °C" in tip
        assert thrusts, "the seeded engines have a thrust deficit"
        screenshot(page, "fleet-egt-margin-sigma")
    finally:
        with transaction(server.factory) as session:
            design = session.get(EstimatorDesign, design_id)
            assert design is not None
            design.result = before
    assert console.unexpected() == []

