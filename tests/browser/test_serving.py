"""What Chromium receives: plotly.js compressed, and a page (not JSON) for an unknown address."""

from __future__ import annotations

from typing import Any

import pytest

from tests.browser.conftest import LAPTOP, Server, screenshot

pytestmark = pytest.mark.browser


def test_plotly_arrives_gzipped_and_unknown_pages_are_html(
    browser: Any, server: Server
) -> None:
    # A fresh context: nothing cached, so the bundle really comes over the wire.
    ctx = browser.new_context(viewport=LAPTOP, base_url=server.base_url)
    try:
        page = ctx.new_page()
        with page.expect_response("**/vendor/plotly.min.js") as info:
            page.goto("/signin.html?next=/")
            page.goto("/")
        response = info.value
        assert response.status == 200
        assert response.header_value("content-encoding") == "gzip"
        missing = page.goto("/nosuchpage")
        assert missing is not None and missing.status == 404
        assert page.inner_text("h1") == "Page not found"
        page.click("text=Fleet status")
        page.wait_for_url("**/signin.html**")  # the fleet page, which asks for a key first
        page.goto("/nosuchpage")
        screenshot(page, "not-found")
        api = page.goto("/api/v1/nosuch")
        assert api is not None and api.status == 404
        assert api.header_value("content-type") == "application/json"
    finally:
        ctx.close()
