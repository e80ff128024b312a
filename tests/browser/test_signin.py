"""Signing in once per browser: a second tab opens without asking, and signing out in one tab
signs out every tab."""

from __future__ import annotations

from typing import Any

import pytest

from tests.browser.conftest import Console, Server, screenshot, sign_in

pytestmark = pytest.mark.browser


def test_second_tab_is_signed_in_and_sign_out_reaches_every_tab(
    page: Any, context: Any, server: Server, console: Console
) -> None:
    sign_in(page, server.seeded.key, "/")
    second = context.new_page()
    try:
        second.goto("/events.html")
        second.wait_for_selector("body[data-ready=true]")  # no sign-in asked
        assert second.url.endswith("/events.html")
        assert "Browser Air" in second.inner_text("nav .who")
        second.click("nav button:text('Sign out')")
        second.wait_for_url("**/signin.html**")
        # The first tab follows without a click, to sign-in with the reason.
        page.wait_for_url("**/signin.html**")
        assert "signed out in another tab" in page.inner_text("#message")
        assert page.evaluate("localStorage.getItem('fleethealth.apiKey')") is None
        screenshot(page, "signed-out-in-another-tab")
        # Signing in again in one tab is enough for a new one.
        sign_in(second, server.seeded.viewer_key, "/")
        third = context.new_page()
        try:
            third.goto("/uploads.html")
            third.wait_for_selector("body[data-ready=true]")
            assert "viewer" in third.inner_text("nav .who")
        finally:
            third.close()
    finally:
        second.close()
    assert console.unexpected() == []
