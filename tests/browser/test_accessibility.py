"""Accessibility basics: badge text readable (WCAG AA contrast), progress bars named, plots with
a text alternative, the upload detail brought into view."""

from __future__ import annotations

import re
from typing import Any

import pytest

from tests.browser.conftest import Console, Server, screenshot, sign_in, traces

pytestmark = pytest.mark.browser
BADGES = ("normal", "watch", "alert", "no_data", "succeeded", "stored", "closed", "ready",
          "acknowledged", "queued", "pending", "open", "failed", "rejected", "running")


def _luminance(rgb: str) -> float:
    """Relative luminance of a CSS ``rgb(r, g, b)`` (WCAG 2.x definition)."""
    channels = [int(v) / 255 for v in re.findall(r"\d+", rgb)[:3]]
    lin = [c / 12.92 if c <= 0.03928 else ((c + 0.055) / 1.055) ** 2.4 for c in channels]
    return 0.2126 * lin[0] + 0.7152 * lin[1] + 0.0722 * lin[2]


def contrast(a: str, b: str) -> float:
    hi, lo = sorted((_luminance(a), _luminance(b)), reverse=True)
    return (hi + 0.05) / (lo + 0.05)


def test_contrast_formula_matches_the_wcag_reference_pairs() -> None:
    assert contrast("rgb(0, 0, 0)", "rgb(255, 255, 255)") == pytest.approx(21.0)
    assert contrast("rgb(118, 118, 118)", "rgb(255, 255, 255)") == pytest.approx(4.54, abs=0.01)


def test_every_badge_has_aa_contrast(page: Any, server: Server, console: Console) -> None:
    sign_in(page, server.seeded.key, "/uploads.html")
    colours = page.evaluate(
        """(kinds) => kinds.map((k) => { const b = document.createElement('span');
            b.className = `badge ${k}`; b.textContent = k; document.body.append(b);
            const s = getComputedStyle(b); return [k, s.color, s.backgroundColor]; })""",
        list(BADGES),
    )
    ratios = {kind: contrast(fg, bg) for kind, fg, bg in colours}
    assert min(ratios.values()) >= 4.5, ratios
    assert console.unexpected() == []


def test_progress_bars_are_named_and_the_upload_detail_comes_into_view(
    page: Any, server: Server, console: Console
) -> None:
    page.set_viewport_size({"width": 1280, "height": 480})
    sign_in(page, server.seeded.key, "/uploads.html")
    bars = page.locator("#jobs [role=progressbar]")
    assert bars.count() > 0
    for i in range(bars.count()):
        bar = bars.nth(i)
        assert re.fullmatch(r"job \d+ [a-z ]+", bar.get_attribute("aria-label") or "")
        assert 0 <= int(bar.get_attribute("aria-valuenow") or "-1") <= 100
        assert (bar.get_attribute("aria-valuetext") or "").startswith(
            f"{bar.get_attribute('aria-valuenow')} %")
    below = page.evaluate("document.querySelector('#upload-detail').getBoundingClientRect().top")
    assert below > 480  # drawn below the fold: it must be scrolled to
    page.locator("#uploads tbody a").first.click()
    page.wait_for_selector("#upload-errors")
    page.wait_for_function("window.scrollY > 0")
    top = page.evaluate("document.querySelector('#upload-errors').getBoundingClientRect().top")
    # Scrolled to its top: at 0, or half a pixel off where the layout's heights are fractional.
    assert -1 < top < 480
    assert page.evaluate("document.activeElement.closest('#upload-errors') !== null")
    screenshot(page, "upload-detail-in-view")
    assert console.unexpected() == []


def test_plots_have_a_text_alternative(page: Any, server: Server, console: Console) -> None:
    engine_id = server.seeded.engine_with_event
    sign_in(page, server.seeded.key, f"/engine.html?id={engine_id}")
    plots = page.locator(".plot")
    assert plots.count() >= 4
    for i in range(plots.count()):
        div = plots.nth(i)
        selector = f"#{div.get_attribute('id')}"
        assert div.get_attribute("role") == "figure"
        assert div.get_attribute("aria-label")
        summary = page.evaluate("(id) => document.getElementById(id).textContent",
                                div.get_attribute("aria-describedby"))
        lines = [t for t in traces(page, selector) if t["role"] == "line"]
        assert lines
        for t in lines:
            values = page.evaluate(
                "([sel, name]) => document.querySelector(sel).data.find((t) => t.name === name)"
                ".y.filter((v) => v !== null).length", [selector, t["label"]])
            assert f"{t['label']}: {values} points" in summary, (t["label"], summary)
    assert console.unexpected() == []
