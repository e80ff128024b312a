"""Notification settings in the browser: an administrator adds a webhook (its signing secret
shown once), a wrong URL is refused with the reason and nothing stored, a test message reaches
a local HTTP server with a valid signature and the delivery log shows the attempt; a failing
endpoint's attempt is logged with its status, and deleting the channel ends its retries."""

from __future__ import annotations

import hashlib
import hmac
from typing import Any

import httpx
import pytest

from tests.browser.conftest import Console, Server, screenshot, sign_in
from tests.support.receivers import webhook_receiver

pytestmark = pytest.mark.browser


def _channels(server: Server) -> list[dict[str, Any]]:
    response = httpx.get(f"{server.base_url}/api/v1/notifications/channels",
                         headers={"X-API-Key": server.seeded.key})
    assert response.status_code == 200, response.text
    return list(response.json())


def _add_webhook(page: Any, name: str, url: str) -> None:
    page.fill("#webhook-name", name)
    page.fill("#webhook-url", url)
    page.click("#webhook-add")


def test_configure_a_webhook_and_read_the_delivery_log(
    page: Any, server: Server, console: Console
) -> None:
    page.on("dialog", lambda dialog: dialog.accept())
    sign_in(page, server.seeded.key, "/settings.html")
    assert page.locator("nav a[aria-current=page]").inner_text() == "Notifications"
    before = len(_channels(server))

    _add_webhook(page, "refused", "ftp://example.org/hook")
    refused = page.wait_for_selector("#webhook-result .error")
    assert "nothing stored" in refused.inner_text() and "http" in refused.inner_text()
    assert len(_channels(server)) == before

    with webhook_receiver() as good, webhook_receiver(codes=[500]) as bad:
        _add_webhook(page, "operations desk", good.url)
        secret = page.wait_for_selector("#webhook-secret code").inner_text()
        assert secret.startswith("whsec_")
        row = page.wait_for_selector("#channel-table tr:has-text('operations desk')")
        assert good.url in row.inner_text()
        assert all("secret" not in c for c in _channels(server))

        row.query_selector("button.test").click()
        sent = page.wait_for_selector("#delivery-table tr.delivery-sent", timeout=30_000)
        assert "operations desk" in sent.inner_text()
        assert "200" in sent.query_selector("ol.attempts").inner_text()
        [request] = good.requests
        timestamp = request.headers["X-Fleethealth-Timestamp"]
        digest = hmac.new(secret.encode(), f"{timestamp}.".encode() + request.body,
                          hashlib.sha256).hexdigest()
        assert request.headers["X-Fleethealth-Signature"] == f"sha256={digest}"

        _add_webhook(page, "broken receiver", bad.url)
        page.wait_for_selector("#channel-table tr:has-text('broken receiver')").query_selector(
            "button.test").click()
        failing = page.wait_for_selector(
            "#delivery-table tr.delivery-pending:has-text('broken receiver')", timeout=30_000)
        page.wait_for_function(
            "() => /500/.test(document.querySelector('#delivery-table tr.delivery-pending')"
            "?.innerText || '')", timeout=30_000)
        assert "next try" in page.locator("#delivery-table tr.delivery-pending").inner_text()
        screenshot(page, "settings-delivery-log")
        assert failing is not None and len(bad.requests) == 1
        # Deleting the channel drops its pending delivery: the sending job stops retrying.
        page.locator("#channel-table tr:has-text('broken receiver') button.delete").click()
        page.wait_for_selector("#channel-table tr:has-text('broken receiver')", state="detached")
        page.wait_for_selector("#delivery-table tr.delivery-pending", state="detached")
        # The server is shared by later tests: leave no channel pointing at a closed receiver.
        page.locator("#channel-table tr:has-text('operations desk') button.delete").click()
        page.wait_for_selector("#channel-table tr:has-text('operations desk')", state="detached")
    assert len(_channels(server)) == before
    assert console.unexpected("422") == []
