"""WCAG 2.0 and 2.1, levels A and AA, checked by axe-core (the ``axe-playwright-python`` test
extra's pinned axe.min.js) on every dashboard page in the states worth checking: no violation.
And the check itself: a page with an unlabelled field or grey-on-grey text fails it."""

from __future__ import annotations

import time
from collections.abc import Callable
from datetime import datetime, timedelta
from typing import Any

import httpx
import pytest

from tests.browser.conftest import (
    Console,
    Server,
    api_get,
    axe_report,
    axe_violations,
    cruise_stream_csv,
    screenshot,
    sign_in,
)

pytestmark = [pytest.mark.browser, pytest.mark.long(seconds=35)]


def _ready(page: Any, url: str) -> None:
    page.goto(url)
    page.wait_for_selector("body[data-ready=true]")
    # Some plots draw after the page is ready: checked once the requests have settled.
    page.wait_for_load_state("networkidle")
    page.wait_for_timeout(300)


def _hover_plot(page: Any, selector: str) -> None:
    box = page.locator(f"{selector} .nsewdrag").first.bounding_box()
    page.mouse.move(box["x"] + box["width"] * 0.6, box["y"] + box["height"] / 2)
    page.wait_for_selector(f"{selector} .hoverlayer text")


def _recording(server: Server) -> int:
    """A minute's stream recording on the seeded event's engine two days before the event (clear
    of the recording page's own test at the event), estimated."""
    event = api_get(server, f"/api/v1/events/{server.seeded.event_id}")
    started = datetime.fromisoformat(event["detected_at"]) - timedelta(days=2)
    body, _ = cruise_stream_csv(seed=33, n=1200, dt=0.05)
    response = httpx.post(
        f"{server.base_url}/api/v1/streams", content=body,
        headers={"X-API-Key": server.seeded.key, "Content-Type": "text/csv"},
        params={"tail": event["tail"], "position": event["position"],
                "started_at": started.isoformat()},
    )
    assert response.status_code == 201, response.text[:400]
    rid: int = response.json()["recording"]["id"]
    deadline = time.monotonic() + 120
    while api_get(server, f"/api/v1/streams/{rid}/estimates")["n_samples_estimated"] < 1200:
        assert time.monotonic() < deadline, "the recording was not estimated in time"
        time.sleep(0.5)
    return rid


def test_every_page_has_no_wcag_aa_violation(
    page: Any, server: Server, console: Console
) -> None:
    seeded = server.seeded
    inactive = next(d for d in api_get(server, "/api/v1/designs")["items"] if not d["active"])
    event = api_get(server, f"/api/v1/events/{seeded.event_id}")
    rid = _recording(server)
    found: dict[str, list[dict[str, Any]]] = {}

    def check(name: str, *steps: Callable[[], Any]) -> None:
        for step in steps:
            step()
        found[name] = axe_violations(page)

    # Signed out.
    check("signin", lambda: page.goto("/signin.html"))
    check("signin, wrong key", lambda: page.fill("#key", "fh_wrong"),
          lambda: page.click("button[type=submit]"), lambda: page.wait_for_selector(".error"))
    check("not-found", lambda: page.goto("/no-such-page"))
    sign_in(page, seeded.key, "/")
    check("fleet", lambda: _ready(page, "/"))
    check("fleet, thrust and margins", lambda: page.select_option("#which", "aux"),
          lambda: page.wait_for_timeout(500))
    check("engine", lambda: _ready(page, f"/engine.html?id={seeded.engine_with_event}"))
    check("engine, hover", lambda: _hover_plot(page, "#plot-health"))
    check("engine, cycles and levels", lambda: _ready(
        page, f"/engine.html?id={seeded.engine_with_event}&axis=cycles&health=level"))
    check("engine, design not in service", lambda: _ready(
        page, f"/engine.html?id={seeded.engine_with_event}&design={inactive['id']}"),
        lambda: page.wait_for_selector("#no-estimates"))
    check("engine, none chosen", lambda: _ready(page, "/engine.html"))
    check("aircraft", lambda: _ready(page, f"/aircraft.html?tail={event['tail']}"))
    check("aircraft, none chosen", lambda: _ready(page, "/aircraft.html"))
    check("events", lambda: _ready(page, "/events.html"))
    check("event", lambda: _ready(page, f"/events.html?id={seeded.event_id}"))
    check("event, reason missing", lambda: page.click("#close"),
          lambda: page.wait_for_selector("#review .error"))
    check("designs", lambda: _ready(page, "/designs.html"))
    check("designs, refused spec", lambda: page.fill("#name", "a11y check"),
          lambda: page.fill("#tuners", "99"), lambda: page.click("#create-button"),
          lambda: page.wait_for_selector("#create-message .error"))
    check("uploads", lambda: _ready(page, "/uploads.html"))
    check("uploads, upload detail", lambda: page.locator("#uploads tbody a").first.click(),
          lambda: page.wait_for_selector("#upload-errors"))
    check("settings", lambda: _ready(page, "/settings.html"))
    check("recording", lambda: _ready(page, f"/recording.html?id={rid}"))
    check("recording, none chosen", lambda: _ready(page, "/recording.html"))
    check("glossary", lambda: _ready(page, "/glossary.html"))
    check("schedules", lambda: _ready(page, "/schedules.html"))
    check("diagnostic report, none chosen", lambda: _ready(page, "/diagnostic.html"))
    check("keys", lambda: _ready(page, "/keys.html"))
    sign_in(page, seeded.viewer_key, "/")
    check("event, viewer", lambda: _ready(page, f"/events.html?id={seeded.event_id}"))
    check("settings, viewer", lambda: _ready(page, "/settings.html"))
    check("keys, viewer", lambda: _ready(page, "/keys.html"))
    screenshot(page, "axe-last-page")
    failed = {name: axe_report(v) for name, v in found.items() if v}
    assert failed == {}, "\n".join(f"{k}:\n{v}" for k, v in failed.items())
    assert len(found) == 29
    assert console.unexpected("401", "422", "Failed to load resource") == []


def test_the_check_fails_on_a_violation(page: Any, server: Server) -> None:
    """Brought into a clean page: an input with no label, grey text on grey, an image without
    alternative text. axe names each, with the element."""
    page.goto("/signin.html")
    assert axe_violations(page) == []
    page.evaluate("""() => {
        const form = document.querySelector('#signin');
        const field = Object.assign(document.createElement('input'), { id: 'unlabelled' });
        form.append(field);
        const p = Object.assign(document.createElement('p'), { id: 'faint', textContent: 'faint' });
        p.style.cssText = 'color: #999; background: #bbb';
        form.append(p);
        const img = Object.assign(document.createElement('img'), { id: 'bare' });
        img.src = '/favicon.svg';
        form.append(img);
    }""")
    found = {v["id"]: [n["target"] for n in v["nodes"]] for v in axe_violations(page)}
    assert found == {"label": ["#unlabelled"], "color-contrast": ["#faint"],
                     "image-alt": ["#bare"]}
