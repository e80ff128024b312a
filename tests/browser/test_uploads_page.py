"""Uploads and jobs in the browser: a file sent with upload progress is stored and its
estimation job shows up with progress; a bad file is refused with row-level errors that the
upload history keeps; the history names each file and its source, and an upload's detail is
brought into view when it is clicked."""

from __future__ import annotations

import time
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import httpx
import pytest
from sqlalchemy import select

from app.db import transaction
from app.models import FilterState
from app.services.demo.simulation_files import write_table
from app.services.fleet import service as fleet_service
from tests.app.services.snapshots import test_pipeline as pipeline_case
from tests.app.services.trends.test_trends import add_aircraft, add_engine
from tests.app.services.uploads.test_upload_origin import _csv
from tests.browser.conftest import Console, Server, api_get, screenshot, sign_in

pytestmark = pytest.mark.browser



def _operator_with_one_engine(
    server: Server, tail: str, esn: str, first: datetime
) -> tuple[int, str]:
    """An operator of its own with the pipeline tests' design and one engine on ``tail``,
    installed the day before ``first``: (engine id, its key)."""
    with transaction(server.factory) as session:
        fleet = pipeline_case._fleet_with_design(session)
        aircraft = add_aircraft(session, fleet, tail)
        engine = add_engine(session, fleet, esn)
        fleet_service.install(session, operator_id=fleet.operator_id, engine_id=engine.id,
                              aircraft_id=aircraft.id, position=1,
                              installed_at=first - timedelta(days=1))
        return engine.id, fleet.key


def _send(server: Server, key: str, body: bytes, name: str) -> Any:
    """A CSV upload under file name ``name``; its answer (201)."""
    response = httpx.post(f"{server.base_url}/api/v1/snapshots/file",
                          params={"filename": name}, content=body,
                          headers={"X-API-Key": key, "Content-Type": "text/csv"})
    assert response.status_code == 201, response.text
    return response.json()


def test_upload_with_progress_then_refused_file_with_row_errors(
    page: Any, server: Server, console: Console, tmp_path: Path
) -> None:
    table = server.seeded.next_day
    assert table is not None and table.num_rows > 0
    (good,) = write_table(table, tmp_path / "next-day", ["csv"])
    sign_in(page, server.seeded.key, "/uploads.html")
    # Record the progress bar's values as the XMLHttpRequest reports them.
    page.evaluate(
        """() => { window.progressSeen = [];
        new MutationObserver(() => { const p = document.querySelector('#upload-progress .progress');
          if (p) window.progressSeen.push(Number(p.getAttribute('aria-valuenow'))); })
        .observe(document.querySelector('#upload-progress'), {childList: true, subtree: true}); }"""
    )
    page.set_input_files("#file", str(good))
    page.click("#upload-button")
    ok = page.wait_for_selector("#upload-ok")
    assert f"{table.num_rows} stored" in ok.inner_text()
    assert page.evaluate("window.progressSeen")[-1] == 100
    uploads = api_get(server, "/api/v1/uploads?limit=5")["items"]
    assert uploads[0]["status"] == "stored" and uploads[0]["rows_stored"] == table.num_rows
    assert (uploads[0]["filename"], uploads[0]["source"]) == (good.name, "browser")
    # The history names the file and where it came from (the page, with the key's name).
    row = page.wait_for_selector(f"#uploads tr:has(a:text-is('#{uploads[0]['id']}'))")
    cells = row.inner_text()
    assert good.name in cells and "uploads page" in cells
    assert f"key {uploads[0]['api_key_name']}" in cells
    # The estimation job the upload queued appears and runs to the end (list refreshes itself).
    page.wait_for_selector(
        "#jobs tr.job-estimate_engines :is(.badge.succeeded, .badge.failed)", timeout=90_000
    )
    jobs = api_get(server, "/api/v1/jobs?kind=estimate_engines")["items"]
    assert jobs[0]["status"] == "succeeded", jobs[0]["error"]
    screenshot(page, "uploads-stored")

    # The same rows with a naive timestamp in the second row: refused, row and column named.
    text = good.read_text().splitlines()
    cells = text[2].split(",")
    assert cells[0].endswith('Z"')
    cells[0] = cells[0].replace('Z"', '"')
    text[2] = ",".join(cells)
    bad = tmp_path / "naive-time.csv"
    bad.write_text("\n".join(text) + "\n")
    page.set_input_files("#file", str(bad))
    page.click("#upload-button")
    error = page.wait_for_selector("#upload-result .error")
    message = error.inner_text()
    assert "nothing stored" in message and "422" in message
    assert "row 2" in message and "recorded_at" in message
    page.wait_for_selector("#uploads tr.upload-rejected")
    page.click("#uploads tr.upload-rejected a")
    errors = page.wait_for_selector("#upload-errors").inner_text()
    assert "recorded_at" in errors and bad.name in errors and "uploads page" in errors
    rejected = api_get(server, "/api/v1/uploads?status=rejected")["items"]
    assert len(rejected) == 1 and rejected[0]["rows_stored"] == 0
    screenshot(page, "uploads-rejected")

    # A long history (files from another client, refused: they change no engine's data) in a
    # short window: the newest upload's detail is drawn far below its link, then scrolled to.
    for k in range(15):
        response = httpx.post(
            f"{server.base_url}/api/v1/snapshots/file",
            params={"filename": f"unknown-tail-{k}.csv"},
            content=b"recorded_at,tail,position,phase\n2026-01-01T00:00:00Z,ZZ-NONE,1,cruise\n",
            headers={"X-API-Key": server.seeded.key, "Content-Type": "text/csv"},
        )
        assert response.status_code == 422, response.text
    page.set_viewport_size({"width": 1280, "height": 480})
    page.select_option("#upload-filter", "rejected")
    page.wait_for_selector("#uploads tr:has-text('unknown-tail-14.csv')")
    page.evaluate("window.scrollTo(0, 0)")
    link = page.locator("#uploads tbody tr").first.locator("a")
    assert "unknown-tail-14.csv" in page.locator("#uploads tbody tr").first.inner_text()
    link.scroll_into_view_if_needed()
    gap = page.evaluate("document.querySelector('#upload-detail').getBoundingClientRect().top")
    assert gap > 480  # out of view before the click
    link.click()
    detail = page.wait_for_selector("#upload-errors:has-text('unknown-tail-14.csv')")
    assert "API" in detail.inner_text()
    page.wait_for_function(
        """() => { const r = document.querySelector('#upload-errors').getBoundingClientRect();
          return r.top > -1 && r.top < window.innerHeight; }""", timeout=5_000)  # a fractional
    # layout may leave the scrolled-to top half a pixel above the window
    assert page.evaluate("document.activeElement.closest('#upload-errors') !== null")
    screenshot(page, "uploads-detail-in-view")
    assert console.unexpected("422") == []


def test_an_event_links_the_upload_that_caused_it_and_the_link_opens_its_detail(
    page: Any, server: Server, console: Console
) -> None:
    event_id = server.seeded.event_id
    assert event_id is not None
    causes = api_get(server, f"/api/v1/events/{event_id}/uploads")
    assert causes, "the seeded event's record came from the seeded upload"
    sign_in(page, server.seeded.key, f"/events.html?id={event_id}")
    link = page.wait_for_selector("#caused-by a")
    assert link.inner_text() == f"upload #{causes[0]['id']}"
    link.click()
    page.wait_for_url(f"**/uploads.html?upload={causes[0]['id']}")
    detail = page.wait_for_selector(f"#upload-errors:has-text('Upload #{causes[0]['id']}')")
    linked = detail.eval_on_selector_all(
        "#upload-events a", "els => els.map((e) => e.getAttribute('href'))")
    assert f"/events.html?id={event_id}" in linked
    assert console.unexpected() == []


def test_a_back_dated_upload_is_flagged_in_the_history_and_its_detail(
    page: Any, server: Server, console: Console
) -> None:
    """An operator of its own (the demo fleet's estimates stay as they are): an engine
    estimated to its last record, then sent records between the estimated ones."""
    times, y = pipeline_case._records(seed=31)
    engine_id, key = _operator_with_one_engine(server, "F-LATE", "LATE-1", times[0])

    first = _send(server, key, _csv(times, y, range(0, 120), "F-LATE"), "first.csv")
    assert first["back_dated"] is False
    deadline = time.monotonic() + 90
    while True:  # the upload's estimation job runs in the server
        with transaction(server.factory) as session:
            until = session.scalar(select(FilterState.last_recorded_at)
                                   .where(FilterState.engine_id == engine_id))
        if until == times[119]:
            break
        assert time.monotonic() < deadline, "the estimation job did not finish"
        time.sleep(0.2)
    times_b = [t + timedelta(minutes=5) for t in times]
    late = _send(server, key, _csv(times_b, y, range(40, 60), "F-LATE"), "backfill.csv")
    assert late["back_dated"] is True

    sign_in(page, key, "/uploads.html")
    row = page.wait_for_selector("#uploads tr.upload-back-dated")
    assert "backfill.csv" in row.inner_text() and "back-dated" in row.inner_text()
    assert page.locator("#uploads tr.upload-back-dated").count() == 1
    row.query_selector("a").click()
    warning = page.wait_for_selector("#upload-errors .back-dated-warning").inner_text()
    assert warning.startswith("Back-dated: LATE-1 from") and "estimated to" in warning
    screenshot(page, "uploads-back-dated")
    assert console.unexpected() == []


def test_a_late_upload_carries_the_late_badge_beside_back_dated_and_a_fresh_one_not(
    page: Any, server: Server, console: Console
) -> None:
    """An operator of its own: one upload of records recorded months ago (late), one of
    records from the last hours (not late)."""
    times, y = pipeline_case._records(seed=33)
    now = datetime.now(UTC).replace(microsecond=0)
    fresh_times = [now - timedelta(hours=3) + timedelta(minutes=i) for i in range(len(times))]
    _engine_id, key = _operator_with_one_engine(server, "F-TARDY", "TARDY-1", times[0])

    old = _send(server, key, _csv(times, y, range(0, 30), "F-TARDY"), "march.csv")
    fresh = _send(server, key, _csv(fresh_times, y, range(30, 40), "F-TARDY"), "today.csv")
    assert (old["late"], old["rows_late"], fresh["late"]) == (True, 30, False)

    sign_in(page, key, "/uploads.html")
    late_row = page.wait_for_selector("#uploads tr.upload-late")
    assert page.locator("#uploads tr.upload-late").count() == 1
    assert "march.csv" in late_row.inner_text()
    badge = late_row.query_selector(".badge.late")
    assert badge is not None and badge.inner_text() == "late"
    assert (badge.get_attribute("title") or "").startswith("30 records recorded longer before")
    fresh_row = page.wait_for_selector(f"#uploads tr:has(a:text-is('#{fresh['id']}'))")
    assert "today.csv" in fresh_row.inner_text() and fresh_row.query_selector(".badge.late") is None
    late_row.query_selector("a").click()
    warning = page.wait_for_selector("#upload-errors .late-warning").inner_text()
    assert warning.startswith("Late: 30 of its 30 new records")
    screenshot(page, "uploads-late")
    assert console.unexpected() == []
