"""Alert handling in the browser: assign an open alert to a person, acknowledge it with a reason
(refused without one), and read who did what in its history."""

from __future__ import annotations

from typing import Any

import pytest

from tests.browser.conftest import Console, Server, api_get, screenshot, sign_in, unnamed_controls

pytestmark = pytest.mark.browser




def test_assign_acknowledge_with_a_reason_and_see_the_history(
    page: Any, server: Server, console: Console
) -> None:
    open_events = api_get(server, "/api/v1/events", status="open", limit=1000)["items"]
    assert open_events, "the demo fleet has open events"
    # Another test acknowledges the seeded event: take a different one when there is one.
    event = next((e for e in open_events if e["id"] != server.seeded.event_id), open_events[0])
    people = api_get(server, "/api/v1/events/assignees")
    person = people[0]
    sign_in(page, server.seeded.key, f"/events.html?id={event['id']}")
    assert page.inner_text("#assigned-to") == "Assigned to: no one"

    page.get_by_label("Assign to").select_option(str(person["key_id"]))
    page.get_by_role("button", name="Assign").click()
    page.wait_for_function(
        "(n) => document.querySelector('#assigned-to').innerText.includes(n)", arg=person["name"]
    )
    # Acknowledging without a reason is refused in the page and stores nothing.
    page.get_by_role("button", name="Acknowledge").click()
    assert "reason" in page.inner_text("#review [role=status]").lower()
    assert api_get(server, f"/api/v1/events/{event['id']}")["status"] == "open"

    page.get_by_label("Reason (required to acknowledge or close)").fill(
        "HPC signature confirmed, wash planned"
    )
    page.get_by_role("button", name="Acknowledge").click()
    page.wait_for_selector("#status .badge.acknowledged")
    steps = page.locator("#history li").all_inner_texts()
    assert len(steps) == 2
    assert f"assigned it to {person['name']}" in steps[0]
    assert "acknowledged" in steps[1] and "Reason: HPC signature confirmed" in steps[1]

    after = api_get(server, f"/api/v1/events/{event['id']}")
    assert after["assignee"]["key_id"] == person["key_id"]
    assert after["acknowledged_reason"] == "HPC signature confirmed, wash planned"
    assert [s["action"] for s in after["history"]] == ["assigned", "acknowledged"]
    assert all(s["actor"] == "admin" for s in after["history"])
    screenshot(page, "event-alert-handling")
    assert unnamed_controls(page, "#review") == []
    assert console.unexpected() == []
