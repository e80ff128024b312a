"""Maintenance on the engine page: record a water wash with notes through the form, see it in
the engine's list with the recovery measured across it (the numbers the API measures), and a
viewer cannot record."""

from __future__ import annotations

import time
from datetime import datetime, timedelta
from typing import Any

import pytest

from tests.browser.conftest import Console, Server, api_get, screenshot, sign_in, unnamed_controls

pytestmark = pytest.mark.browser




def _wait_for_jobs(server: Server, timeout_s: float = 120.0) -> None:
    """Until the estimation the wash queued (its records from the wash on, redone) has run."""
    deadline = time.monotonic() + timeout_s
    while api_get(server, "/api/v1/jobs", status=["queued", "running"])["total"]:
        assert time.monotonic() < deadline, "the estimation job did not finish"
        time.sleep(0.5)


def _quiet_engine(server: Server) -> tuple[int, list[str]]:
    """An engine without events (a wash restarts its detection baseline, so other tests' events
    stay as they are) and with the most records, and its record times."""
    with_events = {e["engine_id"] for e in api_get(server, "/api/v1/events", limit=1000)["items"]}
    best: tuple[int, list[str]] | None = None
    for engine_id in server.seeded.engine_ids.values():
        if engine_id in with_events:
            continue
        trend = api_get(server, f"/api/v1/engines/{engine_id}/trend", max_points=0,
                     health="level")
        if best is None or len(trend["time"]) > len(best[1]):
            best = (engine_id, trend["time"])
    assert best is not None, "the seeded fleet has an engine without events"
    return best


def test_record_a_wash_and_see_it_listed_with_its_recovery(
    page: Any, server: Server, console: Console
) -> None:
    engine_id, times = _quiet_engine(server)
    assert len(times) > 200
    middle = datetime.fromisoformat(times[len(times) // 2].replace("Z", "+00:00"))
    at = (middle - timedelta(minutes=1)).replace(second=0, microsecond=0)
    sign_in(page, server.seeded.key, f"/engine.html?id={engine_id}")
    before = api_get(server, "/api/v1/maintenance-actions", engine_id=engine_id)["total"]

    page.get_by_label("Action").select_option("water_wash")
    page.get_by_label("Performed at (UTC)").fill(at.strftime("%Y-%m-%dT%H:%M"))
    page.get_by_label("Notes").fill("on-wing wash, browser test")
    page.get_by_role("button", name="Record action").click()
    page.wait_for_selector("#maintenance [role=status] .notice")

    listed = api_get(server, "/api/v1/maintenance-actions", engine_id=engine_id)
    assert listed["total"] == before + 1
    wash = next(m for m in listed["items"] if m["notes"] == "on-wing wash, browser test")
    assert wash["kind"] == "water_wash"
    assert wash["performed_at"] == at.strftime("%Y-%m-%dT%H:%M:%SZ")
    row = page.locator(f"#mx-rows tr[data-id='{wash['id']}']")
    row.wait_for()
    assert "water wash" in row.inner_text() and "on-wing wash, browser test" in row.inner_text()
    # The wash's estimation job redoes the engine's estimates from the wash on: once it has
    # run, the page (reloaded) and the API read the same estimates.
    _wait_for_jobs(server)
    page.reload()
    page.wait_for_selector("body[data-ready=true]")
    row.locator("ul.recovery").wait_for()

    recovery = api_get(server, f"/api/v1/maintenance-actions/{wash['id']}/recovery")
    assert recovery["note"] is None and recovery["n_before"] == recovery["n_after"] == 20
    egt = next(s for s in recovery["series"] if s["name"] == "egt_margin")
    assert egt["unit"] == "degC"
    shown = row.locator("li[data-series=egt_margin]").inner_text()
    sign = "+" if egt["change"] >= 0 else "−"
    assert shown.startswith(f"EGT margin {sign}{abs(egt['change']):.2f} degC")
    health = [s for s in recovery["series"] if s["group"] == "health"]
    assert health and row.locator("ul.recovery li").count() == len(health) + 1
    for s in health:
        text = row.locator(f"li[data-series={s['name']}]").inner_text()
        assert f"{abs(s['change']):.2f} {s['unit']}" in text
    row.scroll_into_view_if_needed()
    screenshot(page, "engine-maintenance")
    assert unnamed_controls(page, "#maintenance") == []
    assert console.unexpected() == []


def test_a_viewer_sees_the_list_but_cannot_record(
    page: Any, server: Server, console: Console
) -> None:
    engine_id = next(iter(server.seeded.engine_ids.values()))
    sign_in(page, server.seeded.viewer_key, f"/engine.html?id={engine_id}")
    page.wait_for_selector("#mx-rows tr")
    assert page.get_by_role("button", name="Record action").is_disabled()
    assert "viewer key" in page.inner_text("#maintenance")
    assert console.unexpected() == []
