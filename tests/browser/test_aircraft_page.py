"""The aircraft page: reached from a tail on the fleet page; every position's engines on shared
axes, the engine-to-engine difference against the API's numbers, installation history and data
coverage with the seeded recorder gap."""

from __future__ import annotations

from collections import defaultdict
from datetime import datetime
from typing import Any

import pytest

from tests.browser.conftest import (
    Console,
    Server,
    api_get,
    screenshot,
    sign_in,
    traces,
)

pytestmark = pytest.mark.browser
DAY_S = 86400



def _daily(segments: list[dict[str, Any]], position: int, name: str) -> dict[int, float]:
    """Daily mean of one health parameter at one position, from the API's aircraft trend."""
    sums: dict[int, list[float]] = defaultdict(list)
    for seg in segments:
        if seg["position"] != position:
            continue
        series = next((s for g in seg["trend"]["groups"] for s in g["series"] if s["name"] == name),
                      None)
        if series is None:
            continue
        for t, v in zip(seg["trend"]["time"], series["value"], strict=True):
            if v is not None:
                day = int(datetime.fromisoformat(t.replace("Z", "+00:00")).timestamp()) // DAY_S
                sums[day].append(v)
    return {d: sum(v) / len(v) for d, v in sums.items()}


def test_aircraft_page_from_the_fleet_tail_link(
    page: Any, server: Server, console: Console
) -> None:
    sign_in(page, server.seeded.key, "/")
    link = page.locator("#table tbody a.tail").first
    tail = link.inner_text()
    link.click()
    page.wait_for_url("**/aircraft.html?tail=*")
    page.wait_for_selector("body[data-ready=true]")
    assert page.inner_text("#title") == f"Aircraft {tail}"
    aircraft = api_get(server, "/api/v1/aircraft", tail=tail)["items"][0]
    trend = api_get(server, f"/api/v1/aircraft/{aircraft['id']}/trend", max_points=1000)
    positions = sorted({s["position"] for s in trend["segments"]})
    assert len(positions) == 2

    # Side by side: one plot per position, every health parameter of each engine it had, all on
    # the same date range and health scale.
    ranges = []
    for p in positions:
        segs = [s for s in trend["segments"] if s["position"] == p and s["trend"]["groups"]]
        health = next(g for g in segs[0]["trend"]["groups"] if g["key"] == "health")
        # A parameter the design cannot estimate is named, not drawn, and not offered.
        hidden = set(health.get("unobservable") or [])
        shown = [s for s in health["series"] if s["name"] not in hidden]
        lines = [t for t in traces(page, f"#plot-position-{p}") if t["role"] == "line"]
        assert len(lines) == len(segs) * len(shown)
        options = page.eval_on_selector_all("#parameter option", "os => os.map((o) => o.value)")
        assert not hidden & set(options)
        # Every point (a gap in the data adds one null point to break the line).
        assert sorted(t["n"] for t in lines) == pytest.approx(sorted(
            s["trend"]["n_points"] for s in segs for _ in shown), abs=10)
        ranges.append(page.evaluate(
            f"(() => {{ const l = document.querySelector('#plot-position-{p}').layout;"
            " return [l.xaxis.range, l.yaxis.range]; })()"))
    assert ranges[0] == ranges[1]

    # The difference: position 1 minus position 2, day by day where both have data.
    name = page.eval_on_selector("#parameter", "s => s.value")
    first, second = (_daily(trend["segments"], p, name) for p in positions)
    days = sorted(set(first) & set(second))
    delta = [v for v in page.evaluate(
        "document.querySelector('#plot-delta').data.find((t) => t.meta.role === 'line').y")
        if v is not None]
    assert len(delta) == len(days) > 20
    assert delta == pytest.approx([first[d] - second[d] for d in days], abs=1e-9)
    # Another parameter: the overlay and the difference follow, and the URL keeps it.
    page.select_option("#parameter", "hpc_flow")
    page.wait_for_function(
        "document.querySelector('#plot-overlay').layout.yaxis.title.text"
        ".startsWith('HPC flow capacity')")  # the glossary's name of hpc_flow
    assert "parameter=hpc_flow" in page.url

    # Installation history and coverage as the API has them.
    history = api_get(server, f"/api/v1/aircraft/{aircraft['id']}/installations")
    assert page.locator("#installations tbody tr").count() == history["total"]
    assert page.locator("#coverage tbody tr").count() == len(trend["segments"])
    screenshot(page, "aircraft")
    assert console.unexpected() == []


def test_coverage_names_the_recorder_gap(page: Any, server: Server, console: Console) -> None:
    # seed.py: fifteen days without data from position 1 of the first tail.
    aircraft = api_get(server, "/api/v1/aircraft")["items"]
    tails = {a["tail"]: a["id"] for a in aircraft}
    gapped = []
    for tail, aircraft_id in tails.items():
        sign_in(page, server.seeded.key, f"/aircraft.html?id={aircraft_id}")
        text = page.locator("#coverage tbody tr.coverage-1").all_inner_texts()
        if any("days)" in t for t in text):
            gapped.append(tail)
        assert all("days)" not in t for t in
                   page.locator("#coverage tbody tr.coverage-2").all_inner_texts())
    assert len(gapped) == 1
    assert console.unexpected() == []


def test_another_operators_aircraft_is_not_found(
    page: Any, server: Server, console: Console
) -> None:
    aircraft_id = api_get(server, "/api/v1/aircraft")["items"][0]["id"]
    sign_in(page, server.seeded.other_key, f"/aircraft.html?id={aircraft_id}")
    assert "not found" in page.inner_text("#message .error")
    assert console.unexpected("404") == []
