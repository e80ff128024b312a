"""Webhook deliveries: a JSON body POSTed with its signature.

Headers: ``X-Fleethealth-Timestamp`` (Unix seconds when sent) and ``X-Fleethealth-Signature``
``sha256=<hex>``, the HMAC-SHA256 under the channel's secret of ``"<timestamp>." + body``. A
receiver recomputes it, compares in constant time, and rejects a timestamp older than a few
minutes, so a captured request cannot be replayed later.
"""

from __future__ import annotations

import hashlib
import hmac
import urllib.error
import urllib.request

from app.services.notifications.outcome import Outcome, timed

TIMEOUT_SECONDS = 10.0
TIMESTAMP_HEADER = "X-Fleethealth-Timestamp"
SIGNATURE_HEADER = "X-Fleethealth-Signature"


def signature(secret: str, timestamp: int, body: bytes) -> str:
    """``sha256=<hex>`` of ``"<timestamp>." + body`` under ``secret``."""
    digest = hmac.new(secret.encode(), f"{timestamp}.".encode() + body, hashlib.sha256)
    return "sha256=" + digest.hexdigest()


def post(url: str, secret: str, body: bytes, timestamp: int) -> Outcome:
    """POST ``body``; success is a 2xx answer. Never raises: failures are the outcome."""
    request = urllib.request.Request(
        url, data=body, method="POST",
        headers={
            "Content-Type": "application/json",
            "User-Agent": "fleethealth-notifications",
            TIMESTAMP_HEADER: str(timestamp),
            SIGNATURE_HEADER: signature(secret, timestamp, body),
        },
    )
    with timed() as clock:
        try:
            with urllib.request.urlopen(request, timeout=TIMEOUT_SECONDS) as response:  # noqa: S310
                code = int(response.status)
            error = None
        except urllib.error.HTTPError as exc:
            code, error = int(exc.code), f"HTTP {exc.code} {exc.reason}"
        except (urllib.error.URLError, OSError, ValueError) as exc:
            reason = getattr(exc, "reason", exc)
            code, error = None, f"{type(exc).__name__}: {reason}"
    ok = code is not None and 200 <= code < 300
    return Outcome(ok=ok, status_code=code, error=error, duration_ms=clock.ms)
