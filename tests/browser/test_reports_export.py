"""The report buttons of the fleet and engine pages: each downloads its file, made by the API
with the signed-in key, and the file opens with a real parser."""

from __future__ import annotations

import io
import time
from typing import Any

import pypdf
import pytest
from openpyxl import load_workbook

from tests.browser.conftest import Console, Server, api_get, screenshot, sign_in

pytestmark = pytest.mark.browser


def _export(page: Any, button: str) -> tuple[str, bytes, float]:
    """Click ``button``; the download's file name, its bytes and the seconds it took."""
    started = time.monotonic()
    with page.expect_download(timeout=60_000) as info:
        page.click(button)
    download = info.value
    body = download.path().read_bytes()
    took = time.monotonic() - started
    # The button is usable again once the file is saved.
    page.wait_for_selector(f"{button}:not([disabled])")
    return download.suggested_filename, body, took


def _pdf_text(body: bytes) -> tuple[str, int]:
    reader = pypdf.PdfReader(io.BytesIO(body))
    return ("\n".join(p.extract_text() for p in reader.pages),
            sum(len(p.images) for p in reader.pages))


def test_fleet_page_exports_pdf_and_excel(page: Any, server: Server, console: Console) -> None:
    sign_in(page, server.seeded.key, "/")
    status = api_get(server, "/api/v1/fleet/status")
    ranked = [e["esn"] for e in status["engines"]]
    assert page.locator("#export-pdf").inner_text() == "Export PDF"
    assert page.locator("#export-xlsx").inner_text() == "Export Excel"
    screenshot(page, "fleet-report-buttons")

    name, body, took_pdf = _export(page, "#export-pdf")
    assert name == "fleet-report-Browser_Air.pdf" and body.startswith(b"%PDF-")
    text, images = _pdf_text(body)
    assert "Fleet report · Browser Air" in text and images == 2
    places = [text.index(esn) for esn in ranked]
    assert places == sorted(places)

    name, body, took_xlsx = _export(page, "#export-xlsx")
    assert name == "fleet-report-Browser_Air.xlsx"
    book = load_workbook(io.BytesIO(body))
    rows = list(book["Status"].iter_rows(min_row=2, values_only=True))
    assert [r[1] for r in rows] == ranked
    assert len(book["Plots"]._images) == 2
    print(f"fleet report from the browser: PDF {took_pdf:.2f} s, Excel {took_xlsx:.2f} s")
    assert console.unexpected() == []


def test_engine_page_exports_pdf_and_excel(page: Any, server: Server, console: Console) -> None:
    engine_id = server.seeded.engine_with_event
    engine = api_get(server, f"/api/v1/engines/{engine_id}")
    sign_in(page, server.seeded.key, f"/engine.html?id={engine_id}")

    name, body, took_pdf = _export(page, "#export-pdf")
    assert name == f"engine-report-{engine['esn']}.pdf" and body.startswith(b"%PDF-")
    text, images = _pdf_text(body)
    assert f"Engine report · {engine['esn']}" in text and images >= 2
    assert "EGT margin" in text and "thrust_deficit" in text

    name, body, took_xlsx = _export(page, "#export-xlsx")
    assert name == f"engine-report-{engine['esn']}.xlsx"
    book = load_workbook(io.BytesIO(body))
    summary = {r[0]: r[1] for r in book["Engine"].iter_rows(values_only=True)}
    assert summary["ESN"] == engine["esn"]
    trend = api_get(server, f"/api/v1/engines/{engine_id}/trend", health="change", max_points=0)
    assert book["Trend"].max_row - 1 == trend["n_records"]
    assert len(book["Plots"]._images) == images
    print(f"engine report from the browser: PDF {took_pdf:.2f} s, Excel {took_xlsx:.2f} s")
    assert console.unexpected() == []


def test_a_failed_report_is_shown_with_the_api_message(
    page: Any, server: Server, console: Console
) -> None:
    # Another operator's engine: the page names the refusal and offers no file.
    sign_in(page, server.seeded.key, f"/engine.html?id={server.seeded.other_engine_id}")
    assert page.locator("#export-pdf").count() == 0
    page.goto("/")
    page.wait_for_selector("body[data-ready=true]")
    # The key is revoked in another tab: the export answers 401 and sends the user to sign in.
    page.evaluate("localStorage.setItem('fleethealth.apiKey', 'fh_not_a_key')")
    page.click("#export-xlsx")
    page.wait_for_url("**/signin.html**")
    assert console.unexpected("401", "404") == []
