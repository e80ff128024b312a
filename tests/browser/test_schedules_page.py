"""Schedules in the browser: a bad cron expression is refused naming the field, a cron
schedule of the fleet diagnostic is added with its next run in UTC, "Run now" runs it with
progress, its report names the engines' states and the alerts with links, and the schedule is
disabled, enabled and deleted; other roles are told the page is for administrators."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from typing import Any

import pytest

from tests.browser.conftest import (
    Console,
    Server,
    api_get,
    screenshot,
    sign_in,
    traces,
    unnamed_controls,
)

pytestmark = pytest.mark.browser


def next_six_utc(after: datetime) -> datetime:
    at_six = after.replace(hour=6, minute=0, second=0, microsecond=0)
    return at_six if at_six > after else at_six + timedelta(days=1)


def links(page: Any, selector: str) -> list[str]:
    found: list[str] = page.eval_on_selector_all(
        selector, "els => els.map((e) => e.getAttribute('href'))")
    return found


def test_cron_schedule_run_now_and_the_diagnostic_report(
    page: Any, server: Server, console: Console
) -> None:
    sign_in(page, server.seeded.key, "/schedules.html")
    assert unnamed_controls(page, "#schedule-form") == []
    assert page.input_value("#kind") == "fleet_diagnostics"
    before = api_get(server, "/api/v1/schedules")

    # A minute past 59: refused, the field named, nothing stored.
    page.fill("#cron", "61 6 * * *")
    page.click("#schedule-add")
    error = page.wait_for_selector("#create-result .error").inner_text()
    assert "nothing stored" in error and "422" in error and "cron" in error
    assert api_get(server, "/api/v1/schedules") == before

    page.fill("#cron", "0 6 * * *")
    page.click("#schedule-add")
    created = page.wait_for_selector("#created").inner_text()
    [schedule] = [s for s in api_get(server, "/api/v1/schedules") if s not in before]
    assert f"Schedule #{schedule['id']} added" in created
    assert (schedule["kind"], schedule["cron"], schedule["interval_seconds"]) == (
        "fleet_diagnostics", "0 6 * * *", None)
    next_run = datetime.fromisoformat(schedule["next_run_at"])
    assert next_run == next_six_utc(datetime.fromisoformat(schedule["created_at"]).astimezone(UTC))
    row = page.locator(f"#schedules tr.schedule-{schedule['id']}")
    text = row.inner_text()
    assert "0 6 * * *" in text and f"{next_run:%Y-%m-%d} 06:00 UTC" in text
    assert "not run yet" in text

    # Run now: the job is submitted at once and its progress shown until it ends.
    row.locator("button.run").click()
    page.wait_for_selector(f"#schedules tr.schedule-{schedule['id']} .last-job .badge.succeeded",
                           timeout=90_000)
    last = api_get(server, f"/api/v1/schedules/{schedule['id']}")["last_job"]
    assert last["status"] == "succeeded"
    bar = row.locator(".progress")
    assert bar.get_attribute("aria-valuenow") == "100"
    assert api_get(server, f"/api/v1/schedules/{schedule['id']}")["next_run_at"] == (
        schedule["next_run_at"])  # run now keeps the schedule's times
    screenshot(page, "schedules-run")

    # The report: every engine's state (a first report) and the alerts, linked.
    row.locator("a.report").click()
    page.wait_for_url(f"**/diagnostic.html?job={last['id']}")
    page.wait_for_selector("body[data-ready=true]")
    result = api_get(server, f"/api/v1/jobs/{last['id']}")["result"]
    status = api_get(server, "/api/v1/fleet/status")
    assert {c["engine_id"]: c["to_state"] for c in result["state_changes"]} == {
        e["engine_id"]: e["state"] for e in status["engines"]}
    assert page.inner_text("#n-changes") == str(len(result["state_changes"]))
    assert sorted(links(page, "#changes tr.change td:first-child a")) == sorted(
        f"/engine.html?id={c['engine_id']}" for c in result["state_changes"])
    for change in result["state_changes"]:
        cells = page.locator("#changes tr.change", has_text=change["esn"]).inner_text()
        assert change["to_state"].replace("_", " ") in cells and "first report" in cells
    [bars] = traces(page, "#changes-plot")
    assert bars["type"] == "bar"
    assert sum(page.evaluate("document.querySelector('#changes-plot').data[0].x")) == len(
        result["state_changes"])
    events = api_get(server, "/api/v1/events", limit=200)
    assert server.seeded.event_id is not None
    assert page.inner_text("#n-events") == str(result["n_events_raised"])
    assert result["n_events_raised"] == events["total"]
    assert sorted(links(page, "#events tr.raised td:first-child a")) == sorted(
        f"/events.html?id={e['event_id']}" for e in result["events_raised"])
    assert f"/events.html?id={server.seeded.event_id}" in links(page, "#events a")
    screenshot(page, "diagnostic-report")

    # Disable, enable, delete.
    page.goto("/schedules.html")
    page.wait_for_selector("body[data-ready=true]")
    row = page.locator(f"#schedules tr.schedule-{schedule['id']}")
    row.locator("button.toggle").click()
    page.wait_for_selector(f"#schedules tr.schedule-{schedule['id']}.disabled")
    assert api_get(server, f"/api/v1/schedules/{schedule['id']}")["enabled"] is False
    assert "disabled" in row.inner_text()
    row.locator("button.toggle").click()
    page.wait_for_selector(f"#schedules tr.schedule-{schedule['id']}:not(.disabled)")
    assert api_get(server, f"/api/v1/schedules/{schedule['id']}")["enabled"] is True
    page.once("dialog", lambda dialog: dialog.accept())
    row.locator("button.delete").click()
    page.wait_for_selector(f"#schedules tr.schedule-{schedule['id']}", state="detached")
    assert api_get(server, "/api/v1/schedules") == before
    # The job it ran stays, and its report with it.
    assert api_get(server, f"/api/v1/jobs/{last['id']}")["schedule_id"] is None
    assert console.unexpected("422 (Unprocessable Entity)") == []  # the refused cron


def test_an_interval_schedule_and_the_page_is_for_administrators(
    page: Any, server: Server, console: Console
) -> None:
    sign_in(page, server.seeded.key, "/schedules.html")
    page.check("#timing-interval")
    assert page.is_disabled("#cron")
    page.fill("#interval-hours", "0.5")
    page.select_option("#kind", "purge_finished_jobs")
    page.fill("#parameters", '{"older_than_days": 90}')
    page.click("#schedule-add")
    page.wait_for_selector("#created")
    [schedule] = [s for s in api_get(server, "/api/v1/schedules")
                  if s["kind"] == "purge_finished_jobs"]
    assert (schedule["interval_seconds"], schedule["cron"]) == (1800, None)
    assert schedule["parameters"]["older_than_days"] == 90
    assert "every 30 min" in page.locator(f"#schedules tr.schedule-{schedule['id']}").inner_text()
    page.once("dialog", lambda dialog: dialog.accept())
    page.locator(f"#schedules tr.schedule-{schedule['id']} button.delete").click()
    page.wait_for_selector(f"#schedules tr.schedule-{schedule['id']}", state="detached")

    # A kind that takes a design: the design is chosen from the operator's ready designs.
    assert page.is_hidden("#design-field")
    page.select_option("#kind", "evaluate_design")
    assert page.is_visible("#design-field")
    design_id = server.seeded.design_ids[1]
    page.select_option("#design", str(design_id))
    page.fill("#parameters", "{}")
    page.check("#timing-cron")
    page.fill("#cron", "0 3 * * 0")
    page.click("#schedule-add")
    page.wait_for_selector("#created:has-text('evaluate design')")
    [evaluation] = [s for s in api_get(server, "/api/v1/schedules")
                    if s["kind"] == "evaluate_design"]
    assert evaluation["parameters"]["design_id"] == design_id
    name = api_get(server, f"/api/v1/designs/{design_id}")["name"]
    row = page.locator(f"#schedules tr.schedule-{evaluation['id']}")
    assert name in row.inner_text() and "0 3 * * 0" in row.inner_text()
    page.once("dialog", lambda dialog: dialog.accept())
    row.locator("button.delete").click()
    page.wait_for_selector(f"#schedules tr.schedule-{evaluation['id']}", state="detached")

    page.evaluate("localStorage.clear()")
    sign_in(page, server.seeded.viewer_key, "/schedules.html")
    assert "Only administrators" in page.inner_text("main")
    assert console.unexpected("403") == []
