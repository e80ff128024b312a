"""The fleet page's last data: per tail and per engine how long ago, the overdue engines
flagged, and the overdue age changed in the page."""

from __future__ import annotations

from datetime import datetime
from typing import Any

import pytest

from tests.browser.conftest import Console, Server, api_get, screenshot, sign_in, traces

pytestmark = pytest.mark.browser

DAY_S = 86400.0


def days_ago(iso: str, now: str) -> float:
    return (datetime.fromisoformat(now) - datetime.fromisoformat(iso)).total_seconds() / DAY_S


def overdue_in_table(page: Any) -> set[str]:
    """ESNs the fleet table flags overdue."""
    return set(page.eval_on_selector_all(
        "#table tbody tr:has(.badge.overdue) td:first-child", "els => els.map((e) => e.innerText)"))


def test_last_data_per_tail_and_engine_and_overdue_engines(
    page: Any, server: Server, console: Console
) -> None:
    sign_in(page, server.seeded.key, "/")
    page.wait_for_selector("#coverage-tails table")
    coverage = api_get(server, "/api/v1/fleet/data-coverage")
    assert page.input_value("#overdue-days") == f"{coverage['overdue_days']:g}"
    overdue = {e["esn"] for e in coverage["engines"] if e["overdue"]}
    installed = [e for e in coverage["engines"] if e["tail"]]
    assert overdue, "the seeded records are months old: installed engines are overdue"
    assert page.inner_text("#overdue-count") == (
        f"{len(overdue)} of {len(installed)} installed engines overdue")
    assert overdue_in_table(page) == overdue

    # One row per tail: its newest record and how long ago; its engines with theirs.
    for tail in coverage["tails"]:
        row = page.locator("#coverage-tails tr.coverage-tail", has_text=tail["tail"])
        text = row.inner_text()
        assert tail["last_data"][:10] in text
        assert f"{round(days_ago(tail['last_data'], coverage['now']))} d ago" in text
        on_tail = [e for e in installed if e["aircraft_id"] == tail["aircraft_id"]]
        assert row.locator("li.coverage-engine").count() == len(on_tail)
        assert row.locator("li.coverage-engine.overdue").count() == tail["engines_overdue"]
    # The plot: one bar per engine with data, its length the days since its newest record.
    [bars] = traces(page, "#coverage-plot")
    with_data = [e for e in coverage["engines"] if e["last_data"]]
    assert (bars["type"], bars["n"]) == ("bar", len(with_data))
    plotted = page.evaluate("document.querySelector('#coverage-plot').data[0].x")
    expected = sorted(days_ago(e["last_data"], coverage["now"]) for e in with_data)
    assert sorted(plotted) == pytest.approx(expected, abs=0.01)
    screenshot(page, "fleet-last-data")

    # A longer overdue age than the oldest installed engine's: nothing is overdue any more.
    oldest = max(days_ago(e["last_data"], coverage["now"]) for e in installed if e["last_data"])
    page.fill("#overdue-days", str(round(oldest + 30)))
    page.dispatch_event("#overdue-days", "change")
    page.wait_for_function(
        "document.querySelector('#overdue-count').innerText.startsWith('0 of')")
    assert overdue_in_table(page) == set()
    assert page.locator("#coverage-tails li.coverage-engine.overdue").count() == 0
    # A short one: every installed engine is.
    page.fill("#overdue-days", "1")
    page.dispatch_event("#overdue-days", "change")
    page.wait_for_function(
        "(n) => document.querySelector('#overdue-count').innerText.startsWith(`${n} of`)",
        arg=len(installed))
    assert overdue_in_table(page) == {e["esn"] for e in installed}
    assert console.unexpected() == []
