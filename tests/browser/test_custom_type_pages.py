"""Pages of an engine of a second type, defined through the API from a model file whose names
appear nowhere in fleethealth's code (N1, N2, EGT in degC, PS3, FF; health fan_loss ...
hpt_area; aux THR, SMC; ``tests.support.custom_type``): the engine page's trend, its type's
signals and the design studio show that type's own names and units, none of the built-in
engine's, and say plainly that the built-in engine's engineering-unit figures do not exist for
it. The type lives in an operator of its own, so the seeded fleet's pages are unchanged."""

from __future__ import annotations

import time
from typing import Any

import httpx
import pytest

from tests.app.test_type_names import builtin_names_in
from tests.browser.conftest import Console, Server, screenshot, sign_in, traces
from tests.support import custom_type as own

pytestmark = pytest.mark.browser
N_RECORDS = 60


@pytest.fixture(scope="module")
def custom(server: Server) -> tuple[own.CustomFleet, str]:
    with server.factory() as session:
        _operator, key = own.make_operator(session)
    headers = {"X-API-Key": key}

    post = own.poster(httpx.post, headers, server.base_url)

    def upload(body: bytes) -> None:
        response = httpx.post(f"{server.base_url}/api/v1/snapshots/file", content=body,
                              headers={**headers, "Content-Type": "text/csv"})
        assert response.status_code in (200, 201, 202), response.text

    fleet = own.setup(post, upload, n=N_RECORDS)
    # The server's job runner estimates the upload in the background.
    deadline = time.monotonic() + 120
    while True:
        trend = httpx.get(f"{server.base_url}/api/v1/engines/{fleet.engine_id}/trend",
                          headers=headers).json()
        if trend["n_records"] == N_RECORDS:
            break
        assert time.monotonic() < deadline, "the upload was not estimated within 120 s"
        time.sleep(0.5)
    return fleet, key


def test_the_engine_page_shows_the_types_own_names_and_units(
    page: Any, custom: tuple[own.CustomFleet, str], console: Console
) -> None:
    fleet, key = custom
    sign_in(page, key, f"/engine.html?id={fleet.engine_id}")
    page.wait_for_selector("#parameters li")
    shown = page.locator("#parameters li").all_inner_texts()
    assert shown == ["FF [kg/h]", "IGV [deg]", "N1 [%]", "N2 [%]", "EGT [degC]", "PS3 [kPa]",
                     "FF_meas [kg/h]"]
    assert page.locator("#parameters h2").inner_text() == "Signals of Made-up 2-spool"
    lines = [t["name"] for t in traces(page, "#plot-health") if t["role"] == "line"]
    assert lines == list(own.HEALTH)
    assert [t["name"] for t in traces(page, "#plot-residuals") if t["role"] == "line"] == [
        "N1", "N2", "EGT", "PS3"]
    assert [t["label"] for t in traces(page, "#plot-wssr") if t["role"] == "line"] == [
        f["name"] for f in own.LIBRARY]
    aux_title = page.locator("#plot-aux").locator("xpath=..").locator("h2").inner_text()
    assert aux_title == "Estimated auxiliary outputs: THR, SMC"
    y_title = page.evaluate("document.querySelector('#plot-health').layout.yaxis.title.text")
    assert y_title.endswith("[%]")
    # The built-in engine's EGT margin, thrust and stall margins do not exist for this type.
    note = page.locator("#performance-note").inner_text()
    assert "built-in engine's nonlinear model" in note
    assert page.locator("[id^=plot-perf-]").count() == 0
    assert builtin_names_in(page.locator("main").inner_text()) == []
    screenshot(page, "custom-type-engine")
    assert console.unexpected() == []


def test_the_design_studio_shows_the_types_own_names_and_units(
    page: Any, custom: tuple[own.CustomFleet, str], console: Console
) -> None:
    fleet, key = custom
    sign_in(page, key, f"/designs.html?a={fleet.design_id}")
    page.wait_for_selector("#health-a .main-svg")
    assert page.locator("#model option").all_inner_texts() == ["Made-up 2-spool: cruise v1"]
    checks = {" ".join(page.locator(f"[data-sensor='{n}']").inner_text().split()):
              page.locator(f"[data-sensor='{n}'] input").is_checked()
              for n in ("N1", "N2", "EGT", "PS3", "FF_meas")}
    assert checks == {"N1 [%]": True, "N2 [%]": True, "EGT [degC]": True, "PS3 [kPa]": True,
                      "FF_meas [kg/h]": True}
    health = page.evaluate("document.querySelector('#health-a').data[0].x")
    assert health == list(own.HEALTH)
    aux = page.evaluate("document.querySelector('#aux-a').data[0].x")
    assert aux == ["THR", "SMC"]
    heading = page.locator("#design-a h3", has_text="Auxiliary outputs").inner_text()
    assert heading == "Auxiliary outputs (THR, SMC): squared bias + variance"
    assert "N1, N2, EGT, PS3" in page.locator("#design-a dl").inner_text()
    assert builtin_names_in(page.locator("main").inner_text()) == []
    screenshot(page, "custom-type-designs")
    assert console.unexpected() == []
