"""Event review in the browser: the list, the detected shift, WSSR bars of every fault
hypothesis, acknowledge with a reason, comment; a viewer cannot write."""

from __future__ import annotations

from typing import Any

import httpx
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



def test_event_list_shows_every_event(page: Any, server: Server, console: Console) -> None:
    sign_in(page, server.seeded.key, "/events.html?status=")
    api = api_get(server, "/api/v1/events")
    assert api["total"] >= 1
    ids = page.locator("table.data tbody tr td:first-child").all_inner_texts()
    assert sorted(ids) == sorted(f"#{e['id']}" for e in api["items"])
    screenshot(page, "events-list")
    assert console.unexpected() == []


def test_event_review_plots_shift_and_wssr_and_acknowledges(
    page: Any, server: Server, console: Console
) -> None:
    event_id = server.seeded.event_id
    assert event_id is not None
    sign_in(page, server.seeded.key, f"/events.html?id={event_id}")
    event = api_get(server, f"/api/v1/events/{event_id}")
    wssr = page.evaluate("document.querySelector('#wssr').data[0]")
    assert wssr["type"] == "bar" and wssr["x"] == list(event["wssr"])
    assert wssr["y"] == pytest.approx(list(event["wssr"].values()))
    confidence = event["confidence"]
    assert confidence is not None and sum(confidence["posterior"]) == pytest.approx(1.0)
    posterior = page.evaluate("document.querySelector('#posterior').data[0]")
    assert posterior["x"] == confidence["faults"]
    assert posterior["y"] == pytest.approx([100 * p for p in confidence["posterior"]])
    assert confidence["label"] in page.inner_text("#confidence h2")
    if confidence["confusion_row"] is not None:
        row = page.evaluate("document.querySelector('#confusion-row').data[0]")
        assert row["y"] == pytest.approx(confidence["confusion_row"]["percent"])
    shift = traces(page, "#shift")
    assert shift[0]["name"] == "detected health shift"
    assert shift[0]["n"] == len(event["health_shift"])
    assert len(shift) == (2 if event["fault"] and event["fault_shift"] else 1)
    around = [t["name"] for t in traces(page, "#around") if t["role"] == "line"]
    assert around == list(event["health_shift"])
    # Each line is referred to its mean over the 20 records before the detection.
    baselines = page.evaluate(
        """(t) => document.querySelector('#around').data.filter((d) => d.meta.role === 'line')
        .map((d) => { const y = d.y.filter((_, i) => Date.parse(d.x[i]) < Date.parse(t))
          .slice(-20).filter((v) => v !== null);
          return y.reduce((a, b) => a + b, 0) / Math.max(1, y.length); })""",
        event["detected_at"],
    )
    assert baselines == pytest.approx([0.0] * len(around), abs=1e-9)
    assert "[%]" in page.evaluate("document.querySelector('#shift').layout.yaxis.title.text")
    screenshot(page, "event-review")

    if event["status"] == "open":
        page.fill("#reason", "borescope booked for the next night stop")
        page.click("#ack")
        page.wait_for_selector("#status .badge.acknowledged")
        assert "borescope booked" in page.inner_text("#history")
        after = api_get(server, f"/api/v1/events/{event_id}")
        assert after["status"] == "acknowledged"
        assert after["acknowledged_reason"] == "borescope booked for the next night stop"
    page.fill("#comment", "second look: shift confirmed")
    page.click("#add-comment")
    page.wait_for_selector("#comments")
    page.wait_for_function(
        "document.querySelector('#comments').innerText.includes('second look')"
    )
    screenshot(page, "event-acknowledged")
    assert console.unexpected() == []


def test_a_viewer_cannot_acknowledge(page: Any, server: Server, console: Console) -> None:
    sign_in(page, server.seeded.viewer_key, f"/events.html?id={server.seeded.event_id}")
    assert page.locator("#ack").is_disabled() and page.locator("#add-comment").is_disabled()
    assert page.locator("#assign").is_disabled()
    assert "viewer key" in page.inner_text("main")
    assert console.unexpected() == []


def test_a_wear_event_ranks_module_faults_and_says_what_fits_better(
    page: Any, server: Server, console: Console
) -> None:
    """A wear event whose change an actuator bias (Wf) fits better than any module fault: the
    confidence names the event's own fault, and the page says which faults it did not rank and
    that Wf fits the change better."""
    from app.db import transaction
    from app.models import Event
    from app.models.base import utcnow
    from tests.app.services.trends.test_trends import add_engine, make_fleet

    with transaction(server.factory) as session:
        fleet = make_fleet(session, "Wear Page Air")
        fleet.design.result = {"vstar": [[1.0]] * 5}
        engine = add_engine(session, fleet, "WEAR-1")
        event = Event(
            operator_id=fleet.operator_id, engine_id=engine.id, design_id=fleet.design.id,
            seq=300, detected_at=utcnow(), kind="wear", fault="LPT", magnitude=1.01,
            statistic=8.7, wssr={"Fan": 16.1, "HPC": 15.6, "LPT": 11.9, "Wf": 2.3},
            shift={"tuners": {"q1": 0.1}, "health": {"lpt_eff": -1.0, "lpt_flow": 3.4},
                   "fault": {"lpt_eff": -2.0, "lpt_flow": 2.0},
                   "wear": {"alert": "directional", "statistic": 8.7, "threshold": 7.4,
                            "baseline_seq": 20, "hypotheses": ["Fan", "HPC", "LPT"]}},
        )
        session.add(event)
        session.flush()
        key, event_id = fleet.key, event.id
    sign_in(page, key, f"/events.html?id={event_id}")
    page.wait_for_selector("#left-out")
    confidence = httpx.get(f"{server.base_url}/api/v1/events/{event_id}",
                           headers={"X-API-Key": key}).json()["confidence"]
    assert confidence["isolated"] == "LPT" and confidence["left_out"] == ["Wf"]
    assert "LPT" in page.inner_text("#confidence h2")
    # LPT's part of the change: 1 - 11.9 / (1.0^2 + 3.4^2) = 5 %.
    assert page.inner_text("#explained").startswith("LPT explains 5 % of the change")
    note = page.inner_text("#left-out")
    assert "not ranked: Wf" in note and "Wf fits this change better" in note
    assert page.evaluate("document.querySelector('#posterior').data[0].x") == ["Fan", "HPC",
                                                                               "LPT"]
    screenshot(page, "event-wear-left-out")
    assert console.unexpected() == []
