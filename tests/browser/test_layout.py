"""Laptop and wall display: every plot fits inside its card, the text grows on a wall display,
and the trend plots sit three per row on a wall display and one per row on a small laptop."""

from __future__ import annotations

from typing import Any

import pytest

from tests.browser.conftest import Console, Server, screenshot, sign_in

pytestmark = pytest.mark.browser

OVERFLOW = """() => [...document.querySelectorAll('.js-plotly-plot')].filter((p) => {
    const card = p.closest('.card').getBoundingClientRect();
    const svg = p.querySelector('.main-svg').getBoundingClientRect();
    return svg.right > card.right + 1 || svg.width < 200; }).map((p) => p.id)"""
COLUMNS = """() => new Set([...document.querySelectorAll('#plots .card')]
    .map((c) => Math.round(c.getBoundingClientRect().left))).size"""


@pytest.mark.parametrize(
    ("name", "viewport", "columns"),
    [
        ("wall", {"width": 2560, "height": 1440}, 3),
        ("small-laptop", {"width": 1280, "height": 720}, 1),
    ],
)
def test_engine_trend_fits_the_screen(
    browser: Any, server: Server, name: str, viewport: dict[str, int], columns: int
) -> None:
    console = Console()
    context = browser.new_context(viewport=viewport, base_url=server.base_url)
    try:
        page = context.new_page()
        page.on("console", lambda m: console.errors.append(m.text) if m.type == "error" else None)
        page.on("pageerror", lambda e: console.errors.append(str(e)))
        sign_in(page, server.seeded.key, f"/engine.html?id={server.seeded.engine_with_event}")
        assert page.evaluate(OVERFLOW) == []
        assert page.evaluate(COLUMNS) == columns
        font = page.evaluate("parseFloat(getComputedStyle(document.documentElement).fontSize)")
        assert font > 15 if name == "wall" else font == 15
        screenshot(page, f"engine-trend-{name}")
        page.goto("/designs.html")
        page.wait_for_selector("body[data-ready=true]")
        assert page.evaluate(OVERFLOW) == []
        screenshot(page, f"designs-{name}")
        assert console.unexpected() == []
    finally:
        context.close()
