"""The engine trend page: every trend group plotted with its bands and units, markers on the time
axis, cycles axis, zoom shared by the plots, CSV export of the shown data, tenant rule."""

from __future__ import annotations

import csv
import io
from datetime import datetime, timedelta
from typing import Any

import httpx
import pytest

from tests.browser.conftest import Console, Server, screenshot, sign_in, traces

pytestmark = pytest.mark.browser


def _api_trend(server: Server, engine_id: int, **query: Any) -> Any:
    # The page's defaults: 1000 points, the health group as the change since the baseline.
    response = httpx.get(
        f"{server.base_url}/api/v1/engines/{engine_id}/trend",
        params={"max_points": 1000, "health": "change", **query},
        headers={"X-API-Key": server.seeded.key},
    )
    assert response.status_code == 200, response.text
    return response.json() if query.get("format") != "csv" else response.text


def test_trend_plots_every_group_with_bands_markers_and_units(
    page: Any, server: Server, console: Console
) -> None:
    engine_id = server.seeded.engine_with_event
    assert engine_id is not None, "the seeded fleet must have an event"
    sign_in(page, server.seeded.key, f"/engine.html?id={engine_id}")
    api = _api_trend(server, engine_id)
    performance = next(g for g in api["groups"] if g["key"] == "performance")
    # The performance group in engineering units is drawn as one panel per quantity, with the
    # type's limit lines as dashed amber and red shapes.
    drawn = []
    for panel in ("perf-egt", "perf-degt", "perf-deltas", "perf-thrust", "perf-rated",
                  "perf-deficit", "perf-margins", "perf-margin-change", "perf-t40", "perf-bpr"):
        drawn += [t["name"] for t in traces(page, f"#plot-{panel}") if t["role"] == "line"]
    # Thrust, thrust in % of rated and the bypass ratio: one line per flight phase (take-off
    # and cruise thrust differ fourfold); the rest one line per series.
    phases = sorted({p for p in api["phase"] if p})
    by_phase = ("Fn", "Fn_rated", "BPR")
    expected = [f"{s['name']} ({p})" if s["name"] in by_phase else s["name"]
                for s in performance["series"]
                for p in (phases if s["name"] in by_phase else [None])]
    assert sorted(drawn) == sorted(expected)
    thrust = [t for t in traces(page, "#plot-perf-thrust") if t["role"] == "line"]
    assert sum(t["n"] for t in thrust) <= api["n_points"]
    egt_title = page.evaluate("document.querySelector('#plot-perf-egt').layout.yaxis.title.text")
    assert egt_title == "EGT margin [°C]"
    limit_values = page.evaluate(
        "document.querySelector('#plot-perf-egt').layout.shapes"
        ".filter((s) => s.xref === 'paper').map((s) => s.y0)"
    )
    assert sorted(limit_values) == sorted(
        line["value"] for line in performance["limits"] if line["series"] == "egt_margin"
    )
    # Every auxiliary output is on a performance panel in its unit (T40 as its change from the
    # nominal engine, in degrees): the design's percent-of-nominal view of them is not drawn.
    assert page.locator("#plot-aux").count() == 0
    assert "ΔT40 [°C]" == page.evaluate(
        "document.querySelector('#plot-perf-t40').layout.yaxis.title.text")
    for group in api["groups"]:
        if group["key"] in ("performance", "aux"):
            continue
        plotted = traces(page, f"#plot-{group['key']}")
        lines = [t for t in plotted if t["role"] == "line"]
        bands = [t for t in plotted if t["role"] == "band"]
        assert [t["name"] for t in lines] == [s["name"] for s in group["series"]]
        # Every record is plotted (a long gap in the data adds one null point to break the line).
        assert all(api["n_points"] <= t["n"] <= api["n_points"] + 10 for t in lines)
        banded = [s for s in group["series"] if s["sigma"] is not None or s["max"] is not None]
        assert len(bands) == len(banded)
        assert [t["name"] for t in plotted if t["name"] == "events"] == ["events"]
        title = page.evaluate(
            f"document.querySelector('#plot-{group['key']}').layout.yaxis.title.text"
        )
        assert f"[{group['series'][0]['unit']}]" in title or "dimensionless" in title
    # The seeded design is not calibrated: the tuners' card says its band is the filter's,
    # and so does each performance panel (whose measured figures have none).
    states = {g["key"]: g.get("uncertainty") for g in api["groups"]}
    assert states["tuners"] == states["performance"] == "uncalibrated"
    note = "Band: the filter's own 1-sigma (the design has no calibrated model error)"
    assert note in page.locator("#plot-tuners").locator("xpath=..").inner_text()
    assert note in page.locator("#plot-perf-egt").locator("xpath=..").inner_text()
    health = next(g for g in api["groups"] if g["key"] == "health")
    assert health["view"] == "change"
    assert "change since baseline" in page.inner_text("#plots section:first-child h2")
    # One solid line per event at its detection time: vermilion for a shift, pink for wear.
    shapes = page.evaluate("document.querySelector('#plot-health').layout.shapes")
    for colour, wear in (("#D55E00", False), ("#CC79A7", True)):
        lines_of = [s["x0"] for s in shapes if s["line"]["color"] == colour]
        assert sorted(lines_of) == sorted(
            e["detected_at"] for e in api["events"] if (e["kind"] == "wear") == wear)
    screenshot(page, "engine-trend")

    # Decimated to 200 buckets: residuals and WSSR (no sigma) get their bucket min-max band.
    page.select_option("#max_points", "200")
    page.click("#form button[type=submit]")
    page.wait_for_function(
        "document.querySelector('#plot-residuals').data.some((t) => t.name.endsWith('min–max'))"
    )
    decimated = _api_trend(server, engine_id, max_points=200)
    assert decimated["decimated"] and decimated["n_points"] <= 200
    residuals = next(g for g in decimated["groups"] if g["key"] == "residuals")
    envelope = [t for t in traces(page, "#plot-residuals") if t["role"] == "band"]
    # Each band names its series (meta.code) and says what it is (the shown name).
    assert [t["name"] for t in envelope] == [s["name"] for s in residuals["series"]]
    assert all(t["label"].endswith(" min–max") for t in envelope)
    page.select_option("#max_points", "1000")
    page.click("#form button[type=submit]")
    page.wait_for_function(
        "!document.querySelector('#plot-residuals').data.some((t) => t.name.endsWith('min–max'))"
    )

    # Cycles axis: the record numbers.
    page.select_option("#axis", "cycles")
    page.wait_for_function("document.querySelector('#plot-health').layout.xaxis.type === 'linear'")
    x = page.evaluate(
        "document.querySelector('#plot-health').data.find((t) => t.meta.role === 'line').x"
    )
    seqs = set(api["seq"])
    assert [v for v in x if v in seqs] == api["seq"]
    event_x = page.evaluate(
        "document.querySelector('#plot-health').data.find((t) => t.meta.code === 'events').x"
    )
    assert event_x == [e["seq"] for e in api["events"]]
    page.select_option("#axis", "date")
    page.wait_for_function("document.querySelector('#plot-health').layout.xaxis.type === 'date'")

    # Zooming the health plot zooms the others; the export holds the zoomed records only.
    first, last = api["time"][0], api["time"][len(api["time"]) // 3]
    page.evaluate(
        "([a, b]) => Plotly.relayout(document.querySelector('#plot-health'), "
        "{'xaxis.range': [a, b]})", [first, last],
    )
    page.wait_for_function(
        "(a) => String(document.querySelector('#plot-wssr').layout.xaxis.range[0]).startsWith(a)",
        arg=first[:10],
    )
    with page.expect_download() as download_info:
        page.click("#export")
    exported = download_info.value.path().read_text()
    rows = list(csv.DictReader(io.StringIO(exported)))
    full = list(csv.DictReader(io.StringIO(_api_trend(server, engine_id, format="csv"))))
    assert list(rows[0]) == list(full[0])  # the API's own CSV columns
    assert 0 < len(rows) < len(full)
    assert all(first[:10] <= r["recorded_at"][:10] <= last[:10] for r in rows)
    assert console.unexpected() == []


def test_maintenance_and_installation_changes_are_marked(
    page: Any, server: Server, console: Console
) -> None:
    engine_id = min(server.seeded.engine_ids.values())  # the engine with the water wash
    sign_in(page, server.seeded.key, f"/engine.html?id={engine_id}")
    api = _api_trend(server, engine_id)
    shapes = page.evaluate("document.querySelector('#plot-tuners').layout.shapes")
    washes = [s for s in shapes if s["line"]["color"] == "#009E73"]
    assert [s["x0"] for s in washes] == [
        m["performed_at"] for m in api["maintenance"]
        if api["time"][0] <= m["performed_at"] <= api["time"][-1]
    ]
    assert washes, "the seeded water wash lies inside the trend"
    assert console.unexpected() == []


def test_another_operators_engine_is_not_found(
    page: Any, server: Server, console: Console
) -> None:
    sign_in(page, server.seeded.key, "/engine.html")
    page.goto(f"/engine.html?id={server.seeded.other_engine_id}")
    error = page.wait_for_selector(".error")
    assert "not found" in error.inner_text() and "404" in error.inner_text()
    assert page.locator(".js-plotly-plot").count() == 0
    screenshot(page, "engine-other-operator")
    assert console.unexpected("404") == []


def test_a_long_gap_in_the_data_breaks_the_lines(
    page: Any, server: Server, console: Console
) -> None:
    # The seeded fleet lost fifteen days of one engine's data. A gap is a step longer than
    # 3 days and 20 typical (median) steps.
    engine_id = server.seeded.engine_ids[min(server.seeded.engine_ids)]
    api = _api_trend(server, engine_id)
    times = [datetime.fromisoformat(t.replace("Z", "+00:00")) for t in api["time"]]
    steps = sorted(b - a for a, b in zip(times, times[1:], strict=False))
    limit = max(timedelta(days=3), 20 * steps[len(steps) // 2])
    gaps = [i - 1 for i in range(1, len(times)) if times[i] - times[i - 1] > limit]
    assert len(gaps) == 1
    sign_in(page, server.seeded.key, f"/engine.html?id={engine_id}")
    # The tuners (the health change is null before its baseline settles).
    line = page.evaluate(
        "document.querySelector('#plot-tuners').data.find((t) => t.meta.role === 'line')"
    )
    assert len(line["x"]) == len(api["time"]) + len(gaps)
    nulls = [i for i, v in enumerate(line["y"]) if v is None]
    assert nulls == [g + 1 + k for k, g in enumerate(gaps)]
    screenshot(page, "engine-trend-gap")
    assert console.unexpected() == []
