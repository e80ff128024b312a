"""The engine page keeps its view in the URL: a reload (or the link sent to a colleague) shows
the same engine, design, health view, axis, date range and number of points."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any
from urllib.parse import parse_qs, urlparse

import httpx
import pytest

from app.db import transaction
from app.models import Engine
from app.services.fleet import service as fleet
from app.services.tenancy import service as tenancy
from tests.browser.conftest import Console, Server, screenshot, sign_in

pytestmark = pytest.mark.browser
FIELDS = ("design", "health", "axis", "start", "end", "max_points")
T_INSTALLED = datetime(2026, 1, 1, tzinfo=UTC)


def _view(page: Any) -> dict[str, str]:
    return {f: page.eval_on_selector(f"#{f}", "e => e.value") for f in FIELDS}


def _shown(page: Any) -> dict[str, Any]:
    return page.evaluate("""(() => { const d = document.querySelector('#plot-health');
        const line = d.data.find((t) => t.meta.role === 'line');
        return { axis: d.layout.xaxis.type, n: line.x.filter((x) => x !== null).length,
                 first: line.x[0], info: document.querySelector('#info').textContent }; })()""")


def test_reload_shows_the_same_view(page: Any, server: Server, console: Console) -> None:
    engine_id = server.seeded.engine_with_event
    assert engine_id is not None
    times = httpx.get(f"{server.base_url}/api/v1/engines/{engine_id}/trend",
                      params={"max_points": 200}, headers={"X-API-Key": server.seeded.key}
                      ).json()["time"]
    start, end = times[len(times) // 4][:10], times[len(times) // 2][:10]
    sign_in(page, server.seeded.key, f"/engine.html?id={engine_id}")
    assert set(parse_qs(urlparse(page.url).query)) == {"id"}  # the defaults stay out of the URL
    other_design = str(server.seeded.design_ids[0])  # named, not "the active design"
    page.select_option("#design", other_design)
    page.select_option("#health", "level")
    page.select_option("#max_points", "200")
    page.fill("#start", start)
    page.fill("#end", end)
    page.click("#form button[type=submit]")
    page.wait_for_function(
        "!document.querySelector('#plots section h2').textContent.includes('since baseline')")
    page.select_option("#axis", "cycles")
    page.wait_for_function("document.querySelector('#plot-health').layout.xaxis.type === 'linear'")
    query = parse_qs(urlparse(page.url).query)
    assert query == {"id": [str(engine_id)], "design": [other_design], "health": ["level"],
                     "axis": ["cycles"], "start": [start], "end": [end],
                     "max_points": ["200"]}
    view, shown = _view(page), _shown(page)
    assert "change since baseline" not in page.inner_text("#plots section:first-child h2")

    page.reload()
    page.wait_for_selector("body[data-ready=true]")
    assert _view(page) == view
    assert _shown(page) == shown
    assert "change since baseline" not in page.inner_text("#plots section:first-child h2")
    screenshot(page, "engine-view-from-url")

    # Another engine keeps the view (but not the design, which belongs to its engine type).
    other = next(e for e in server.seeded.engine_ids.values() if e != engine_id)
    page.select_option("#engine", str(other))
    page.wait_for_url(f"**/engine.html?id={other}*")
    page.wait_for_selector("body[data-ready=true]")
    assert {k: v for k, v in _view(page).items() if k != "design"} == {
        k: v for k, v in view.items() if k != "design"}
    assert _view(page)["design"] == ""
    assert console.unexpected() == []


def test_the_engine_list_holds_every_engine_of_a_large_fleet(
    page: Any, server: Server, console: Console
) -> None:
    """An operator with more engines than one page of the API (1,000): the engine page's list
    holds every one, by ESN, with the tail and position it is on now."""
    n = 1003
    with transaction(server.factory) as session:
        op = tenancy.create_operator(session, name="Large Fleet Air")
        _, key = tenancy.issue_api_key(session, operator=op, role="viewer", name="viewer")
        engine_type = fleet.create_engine_type(session, operator_id=op.id, name="TF-2S")
        aircraft = fleet.create_aircraft(session, operator_id=op.id, tail="N1LF")
        session.add_all([Engine(operator_id=op.id, esn=f"LF-{k:04d}", engine_type_id=engine_type.id)
                         for k in range(n)])
        session.flush()
        last = fleet.find_engine(session, operator_id=op.id, esn=f"LF-{n - 1:04d}")
        assert last is not None
        fleet.install(session, operator_id=op.id, engine_id=last.id, aircraft_id=aircraft.id,
                      position=2, installed_at=T_INSTALLED)
        last_id = last.id
    sign_in(page, key, "/engine.html")
    page.wait_for_selector("body[data-ready=true]")
    options = page.eval_on_selector_all("#engine option", "os => os.map((o) => o.textContent)")
    assert options[1:] == [f"LF-{k:04d}" for k in range(n - 1)] + [f"LF-{n - 1:04d} (N1LF #2)"]
    page.select_option("#engine", str(last_id))
    page.wait_for_url(f"**/engine.html?id={last_id}*")
    page.wait_for_selector("body[data-ready=true]")
    assert console.unexpected() == []
