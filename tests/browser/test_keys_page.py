"""API keys in the browser: an administrator makes a key (shown once, and it works at once), a
name the API refuses stores nothing and says why, revoking a key makes the API refuse it, and a
viewer's page says keys are for administrators, with nothing it could submit."""

from __future__ import annotations

from typing import Any

import httpx
import pytest

from tests.browser.conftest import Console, Server, screenshot, sign_in

pytestmark = pytest.mark.browser


def _keys(server: Server) -> list[dict[str, Any]]:
    response = httpx.get(f"{server.base_url}/api/v1/keys", params={"limit": 200},
                         headers={"X-API-Key": server.seeded.key})
    assert response.status_code == 200, response.text
    return list(response.json()["items"])


def _me(server: Server, key: str) -> int:
    return httpx.get(f"{server.base_url}/api/v1/me", headers={"X-API-Key": key}).status_code


def test_make_use_and_revoke_a_key(page: Any, server: Server, console: Console) -> None:
    page.on("dialog", lambda dialog: dialog.accept())
    sign_in(page, server.seeded.key, "/keys.html")
    assert page.locator("nav a[aria-current=page]").inner_text() == "API keys"
    page.wait_for_selector("#key-table")
    assert "this browser's" in page.locator("#key-table tr:has-text('admin')").first.inner_text()
    before = len(_keys(server))

    page.fill("#key-name", " " * 3)  # only spaces: the API refuses an empty name
    page.click("#key-add")
    refused = page.wait_for_selector("#key-result .error")
    assert "nothing stored" in refused.inner_text() and "name" in refused.inner_text()
    assert len(_keys(server)) == before

    page.fill("#key-name", "engine-shop feed")
    page.select_option("#key-role", "viewer")
    page.click("#key-add")
    shown = page.wait_for_selector("#new-key-value").inner_text()
    assert "not shown again" in page.locator("#new-key").inner_text()
    row = page.wait_for_selector("#key-table tr:has-text('engine-shop feed')")
    assert "viewer" in row.inner_text() and "active" in row.inner_text()
    assert _me(server, shown) == 200  # the key works at once
    [made] = [k for k in _keys(server) if k["name"] == "engine-shop feed"]
    assert shown.startswith(made["prefix"]) and made["role"] == "viewer"
    screenshot(page, "keys")

    row.query_selector("button.revoke").click()
    page.wait_for_selector("#key-table tr:has-text('engine-shop feed') .badge.failed")
    assert _me(server, shown) == 401
    assert not page.locator("#key-table tr:has-text('engine-shop feed') button.revoke").count()
    page.uncheck("#show-revoked")
    page.wait_for_selector("#key-table tr:has-text('engine-shop feed')", state="detached")
    assert console.unexpected("status of 422") == []  # the refused name's answer only


def test_a_viewer_is_told_keys_are_for_administrators(
    page: Any, server: Server, console: Console
) -> None:
    sign_in(page, server.seeded.viewer_key, "/keys.html")
    note = page.wait_for_selector("#message .notice")
    assert "administrators" in note.inner_text()
    assert page.locator("#key-add").is_disabled()
    assert page.locator("#key-table").count() == 0
