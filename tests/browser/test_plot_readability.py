"""Readable plots: a distinct colour per trace, legends that fit with every entry shown, ±1σ in
the hovers, marker labels that do not overlap, text with AA contrast, engineers' names from the
glossary, the event window with the engine's maintenance, and a design not in service that says
why it has no estimates."""

from __future__ import annotations

import csv
import io
import itertools
import re
from datetime import datetime, timedelta
from typing import Any

import pytest

from tests.browser.conftest import Console, Server, api_get, screenshot, sign_in, traces
from tests.browser.test_accessibility import contrast

pytestmark = [pytest.mark.browser, pytest.mark.long(seconds=50)]


def _rgb(hex_colour: str) -> str:
    n = int(hex_colour.lstrip("#"), 16)
    return f"rgb({(n >> 16) & 255}, {(n >> 8) & 255}, {n & 255})"


def _lab(hex_colour: str) -> tuple[float, float, float]:
    """CIE L*a*b* (D65) of an sRGB colour."""
    def lin(c: int) -> float:
        v = c / 255
        return v / 12.92 if v <= 0.04045 else ((v + 0.055) / 1.055) ** 2.4
    n = int(hex_colour.lstrip("#"), 16)
    r, g, b = (lin((n >> s) & 255) for s in (16, 8, 0))
    x = (0.4124 * r + 0.3576 * g + 0.1805 * b) / 0.95047
    y = 0.2126 * r + 0.7152 * g + 0.0722 * b
    z = (0.0193 * r + 0.1192 * g + 0.9505 * b) / 1.08883

    def f(t: float) -> float:
        return t ** (1 / 3) if t > 0.008856 else 7.787 * t + 16 / 116
    return 116 * f(y) - 16, 500 * (f(x) - f(y)), 200 * (f(y) - f(z))


def _line_colours(page: Any, selector: str) -> list[str]:
    colours: list[str] = page.evaluate(
        """(sel) => document.querySelector(sel).data
            .filter((t) => t.meta && t.meta.role === 'line').map((t) => t.line.color)""",
        selector,
    )
    return colours


def _ready(page: Any, url: str) -> None:
    page.goto(url)
    page.wait_for_selector("body[data-ready=true]")


def test_the_palette_has_thirteen_distinct_readable_colours_and_each_trace_its_own(
    page: Any, server: Server, console: Console
) -> None:
    sign_in(page, server.seeded.key, f"/engine.html?id={server.seeded.engine_with_event}")
    palette = page.evaluate("import('/js/plots.js').then((m) => m.PALETTE)")
    assert len(set(palette)) == len(palette) >= 13
    # Graphical objects: 3:1 against the white plot (WCAG 1.4.11); told apart from each other.
    assert min(contrast(_rgb(c), "rgb(255, 255, 255)") for c in palette) >= 3.0
    assert min(
        sum((p - q) ** 2 for p, q in zip(_lab(a), _lab(b), strict=True)) ** 0.5
        for a, b in itertools.combinations(palette, 2)
    ) >= 30
    # Every plot of the page: as many colours as lines (the health plot has ten).
    plots = page.eval_on_selector_all(".plot", "ds => ds.map((d) => d.id)")
    assert "plot-health" in plots
    for plot_id in plots:
        colours = _line_colours(page, f"#{plot_id}")
        assert len(set(colours)) == len(colours), (plot_id, colours)
    assert len(_line_colours(page, "#plot-health")) == 10
    assert console.unexpected() == []


def _legend_check(page: Any, selector: str) -> dict[str, Any]:
    result: dict[str, Any] = page.evaluate(
        """(sel) => {
            const div = document.querySelector(sel);
            const box = div.getBoundingClientRect();
            const legend = div.querySelector('.legend');
            if (!legend) return { entries: 0, shown: 0, inside: true, scroll: 0 };
            const bg = legend.querySelector('.bg').getBoundingClientRect();
            const entries = [...legend.querySelectorAll('.traces')]
                .map((t) => t.getBoundingClientRect());
            const within = (r, o) => r.left >= o.left - 1 && r.right <= o.right + 1
                && r.top >= o.top - 1 && r.bottom <= o.bottom + 1;
            const bar = legend.querySelector('.scrollbar');
            return {
                entries: entries.length,
                shown: entries.filter((r) => within(r, bg)).length,
                inside: within(bg, box),
                scroll: bar ? bar.getBoundingClientRect().height : 0,
                expected: div.data.filter((t) => t.showlegend !== false).length,
            };
        }""",
        selector,
    )
    return result


def test_legends_fit_inside_the_figure_with_no_entry_hidden(
    page: Any, server: Server, console: Console
) -> None:
    seeded = server.seeded
    sign_in(page, seeded.key, f"/engine.html?id={seeded.engine_with_event}")
    checked = {}
    for plot_id in page.eval_on_selector_all(".plot", "ds => ds.map((d) => d.id)"):
        checked[plot_id] = _legend_check(page, f"#{plot_id}")
    _ready(page, f"/events.html?id={seeded.event_id}")
    page.wait_for_selector("#around .legend")
    checked["around"] = _legend_check(page, "#around")
    for plot_id, c in checked.items():
        assert c["scroll"] == 0, (plot_id, c)  # no scroll bar
        assert c["inside"], (plot_id, c)
        assert c["shown"] == c["entries"], (plot_id, c)
    assert checked["plot-health"]["entries"] == checked["plot-health"]["expected"] >= 10
    assert checked["around"]["entries"] >= 10
    screenshot(page, "event-window-legend")
    assert console.unexpected() == []


def test_hovers_carry_the_estimates_sigma(page: Any, server: Server, console: Console) -> None:
    engine_id = server.seeded.engine_with_event
    sign_in(page, server.seeded.key, f"/engine.html?id={engine_id}")
    trend = api_get(server, f"/api/v1/engines/{engine_id}/trend", max_points=1000,
                    health="change")  # the page's defaults
    with_sigma = {g["key"]: {s["name"] for s in g["series"] if s["sigma"]} for g in trend["groups"]}
    assert with_sigma["health"] and with_sigma["tuners"]
    for key in ("health", "tuners"):
        lines = page.evaluate(
            """(sel) => document.querySelector(sel).data
                .filter((t) => t.meta && t.meta.role === 'line')
                .map((t) => [t.meta.code, t.hovertemplate,
                             t.customdata ? t.customdata.length : 0, t.y.length])""",
            f"#plot-{key}",
        )
        for code, template, n_sigma, n in lines:
            if code in with_sigma[key]:
                assert "± %{customdata" in template and "σ" in template, (code, template)
                assert n_sigma == n
    # The hover box as drawn: value ± sigma of every health parameter.
    box = page.locator("#plot-health .nsewdrag").first.bounding_box()
    page.mouse.move(box["x"] + box["width"] * 0.6, box["y"] + box["height"] / 2)
    page.wait_for_selector("#plot-health .hoverlayer text")
    text = page.evaluate(
        "[...document.querySelectorAll('#plot-health .hoverlayer text')]"
        ".map((t) => t.textContent).join('\\n')")
    assert len(re.findall(r"-?\d+\.\d{3} ± \d+\.\d{3} % \(1σ\)", text)) >= 5, text
    screenshot(page, "engine-hover-sigma")
    # The plot's CSV (mode bar) names the series as the API does and gives each value its sigma.
    exported = page.evaluate(
        "import('/js/plots.js').then((m) => m.plotCsv(document.querySelector('#plot-health')))")
    rows = list(csv.DictReader(io.StringIO(exported)))
    health = next(g for g in trend["groups"] if g["key"] == "health")
    fan = [r for r in rows if r["trace"] == "fan_eff" and r["y"]]
    sigma = [v for v in next(s for s in health["series"] if s["name"] == "fan_eff")["sigma"]
             if v is not None]
    assert [float(r["error"]) for r in fan] == pytest.approx(sigma)
    assert console.unexpected() == []


def _crowded_trend(route: Any, at: list[str]) -> None:
    """The engine's real trend with maintenance actions added at the times ``at``: labels that
    would print over one another if laid out naively."""
    response = route.fetch()
    trend = response.json()
    trend["maintenance"] = trend["maintenance"] + [
        {"id": 10_000 + i, "kind": kind, "performed_at": t,
         "notes": f"added for the layout check {i}"}
        for i, (t, kind) in enumerate(zip(at, itertools.cycle(
            ["borescope_finding", "water_wash", "module_change"]), strict=False))
    ]
    route.fulfill(response=response, json=trend)


def _annotation_boxes(page: Any, selector: str) -> list[dict[str, float]]:
    boxes: list[dict[str, float]] = page.evaluate(
        """(sel) => [...document.querySelectorAll(`${sel} .infolayer .annotation`)]
            .map((a) => a.querySelector('.annotation-text-g') || a)
            .map((a) => { const r = a.getBoundingClientRect();
                return { left: r.left, right: r.right, top: r.top, bottom: r.bottom,
                         text: a.textContent }; })""",
        selector,
    )
    return boxes


def _overlaps(boxes: list[dict[str, float]]) -> list[tuple[str, str]]:
    return [
        (a["text"], b["text"]) for a, b in itertools.combinations(boxes, 2)
        if a["left"] < b["right"] - 0.5 and b["left"] < a["right"] - 0.5
        and a["top"] < b["bottom"] - 0.5 and b["top"] < a["bottom"] - 0.5
    ]


def test_marker_labels_do_not_overlap(page: Any, server: Server, console: Console) -> None:
    engine_id = server.seeded.engine_with_event
    trend = api_get(server, f"/api/v1/engines/{engine_id}/trend", max_points=1000)
    start = datetime.fromisoformat(trend["time"][len(trend["time"]) // 2].replace("Z", "+00:00"))
    # Eight actions three days apart: on the two-month trend some 25 pixels apart, each label
    # about 100 pixels wide.
    at = [(start + timedelta(days=3 * i)).strftime("%Y-%m-%dT%H:%M:%SZ") for i in range(8)]
    page.route(f"**/api/v1/engines/{engine_id}/trend*", lambda route: _crowded_trend(route, at))
    sign_in(page, server.seeded.key, f"/engine.html?id={engine_id}")
    boxes = _annotation_boxes(page, "#plot-health")
    page.locator("#plot-health").scroll_into_view_if_needed()
    page.locator("#plot-health").screenshot(path=str(screenshot(page, "marker-labels")))
    assert len(boxes) >= 4, boxes  # several labels placed, the rest as "+" where there is room
    assert _overlaps(boxes) == [], boxes
    # Each label stays above the plot, inside the figure.
    plot_top = page.locator("#plot-health .nsewdrag").first.bounding_box()["y"]
    figure = page.locator("#plot-health").bounding_box()
    assert all(figure["y"] <= b["top"] and b["bottom"] <= plot_top + 1 for b in boxes), boxes
    # Every marker has its full description in its hover text.
    hovers = page.evaluate(
        "document.querySelector('#plot-health').layout.annotations"
        ".map((a) => a.hovertext).join('<br>')")
    placed = sum("added for the layout check" in h for h in hovers.split("<br>"))
    assert placed == len(boxes)
    page.unroute(f"**/api/v1/engines/{engine_id}/trend*")
    assert console.unexpected() == []


def _text_contrasts(page: Any, selector: str) -> list[tuple[str, float]]:
    """Every SVG text of the plots in ``selector`` (hover boxes aside) with its fill colour."""
    fills: list[list[str]] = page.evaluate(
        """(sel) => [...document.querySelectorAll(`${sel} .main-svg text`)]
            .filter((t) => !t.closest('.hoverlayer') && t.textContent.trim()
                && getComputedStyle(t).fill.startsWith('rgb'))
            .map((t) => [t.textContent, getComputedStyle(t).fill])""",
        selector,
    )
    return [(text, contrast(fill, "rgb(255, 255, 255)")) for text, fill in fills]


def test_plot_text_has_aa_contrast(page: Any, server: Server, console: Console) -> None:
    """axe-core cannot judge text drawn in SVG over the plot (it reports it as incomplete): the
    text of the plots is checked here against the white plot, 4.5:1 (WCAG 1.4.3)."""
    washed = min(server.seeded.engine_ids.values())  # seed.py: the engine with the water wash
    sign_in(page, server.seeded.key, f"/engine.html?id={washed}")
    texts = _text_contrasts(page, "#plots")
    assert any("water wash" in t for t, _ in texts)  # the maintenance label is drawn
    assert any(" amber " in t for t, _ in texts)  # and the limit lines' labels
    low = [(t, round(c, 2)) for t, c in texts if c < 4.5]
    assert low == []
    _ready(page, f"/events.html?id={server.seeded.event_id}")
    page.wait_for_selector("#around .main-svg")
    low = [(t, round(c, 2)) for t, c in _text_contrasts(page, "#content") if c < 4.5]
    assert low == []
    assert console.unexpected() == []


def _glossary_names(page: Any) -> set[str]:
    _ready(page, "/glossary.html")
    names: list[str] = page.eval_on_selector_all(
        "#glossary tbody th[scope=row]", "ths => ths.map((t) => t.textContent)")
    return set(names)


def _shown_names(page: Any, selector: str, what: str = ".legend .legendtext") -> list[str]:
    """The texts ``what`` (legend entries; or category tick labels) of every plot in
    ``selector``."""
    names: list[str] = page.evaluate(
        """([sel, what]) => [...document.querySelectorAll(`${sel} .js-plotly-plot`)].flatMap((d) =>
            [...d.querySelectorAll(what)].map((t) => t.textContent))""",
        [selector, what],
    )
    return names


TICKS = ".xaxislayer-above .xtick text"


JARGON = re.compile(r"^(q\d+|h_hat|SM_\w+|\w+_(eff|flow|bias|change)|dEGT|dN[12]|dWf|Fn\w*)$")


def test_every_name_shown_is_an_engineers_name_from_the_glossary(
    page: Any, server: Server, console: Console
) -> None:
    seeded = server.seeded
    sign_in(page, seeded.key, "/")
    glossary = _glossary_names(page)
    assert {"Fan efficiency", "Tuner 1", "LPC stall margin", "ΔEGT", "EGT margin"} <= glossary
    assert page.locator("nav a[href='/glossary.html']").count() == 1
    shown: dict[str, list[str]] = {}
    _ready(page, f"/engine.html?id={seeded.engine_with_event}")
    shown["engine"] = _shown_names(page, "#plots")
    # WSSR lines are fault hypotheses, named as faults (not as the actuator Wf, VSV, VBV).
    wssr = page.eval_on_selector_all(
        "#plot-wssr .legend .legendtext", "ts => ts.map((t) => t.textContent)")
    assert "Fuel-flow bias fault" in wssr and "HPT fault" in wssr, wssr
    _ready(page, f"/events.html?id={seeded.event_id}")
    page.wait_for_selector("#around .legend")
    shown["event"] = _shown_names(page, "#content") + _shown_names(page, "#content", TICKS)
    a, b = seeded.design_ids
    _ready(page, f"/designs.html?a={a}&b={b}")
    shown["designs"] = _shown_names(page, "#compare") + _shown_names(page, "#compare", TICKS)
    for where, names in shown.items():
        jargon = [n for n in names if JARGON.match(n)]
        assert jargon == [], (where, jargon)
    # Every trace of the engine page is named from the glossary (a phase in brackets aside).
    legend = {re.sub(r" \((takeoff|climb|cruise)\)$", "", n) for n in shown["engine"]}
    assert legend - glossary == set(), legend - glossary
    health = {n for n in shown["designs"] if n in glossary}
    assert {"Fan efficiency", "HPT flow capacity"} <= health
    assert console.unexpected() == []


def _with_maintenance(route: Any, at: str) -> None:
    """The event window's real trend with a borescope finding three days after the detection."""
    response = route.fetch()
    trend = response.json()
    trend["maintenance"] = trend["maintenance"] + [
        {"id": 20_000, "kind": "borescope_finding", "performed_at": at,
         "notes": "HPT blade tip erosion"}]
    route.fulfill(response=response, json=trend)


def test_the_event_window_marks_the_engines_maintenance_and_installations(
    page: Any, server: Server, console: Console
) -> None:
    seeded = server.seeded
    event = api_get(server, f"/api/v1/events/{seeded.event_id}")
    detected = datetime.fromisoformat(event["detected_at"].replace("Z", "+00:00"))
    at = (detected + timedelta(days=3)).strftime("%Y-%m-%dT%H:%M:%SZ")
    page.route(f"**/api/v1/engines/{event['engine_id']}/trend*",
               lambda route: _with_maintenance(route, at))
    sign_in(page, seeded.key, f"/events.html?id={seeded.event_id}")
    page.wait_for_selector("#around .main-svg")
    shapes = page.evaluate("document.querySelector('#around').layout.shapes")
    maintenance = [s for s in shapes if s["line"]["color"] == "#009E73"]
    assert [s["x0"] for s in maintenance] == [at]
    this = [s["x0"] for s in shapes if s["line"]["color"] == "#D55E00" and s["line"]["width"] == 3]
    assert this == [event["detected_at"]]
    labels = page.evaluate(
        "document.querySelector('#around').layout.annotations.map((a) => a.text)")
    assert "borescope finding" in labels and f"event #{event['id']}" in labels
    assert _overlaps(_annotation_boxes(page, "#around")) == []
    page.unroute(f"**/api/v1/engines/{event['engine_id']}/trend*")
    screenshot(page, "event-window-markers")
    assert console.unexpected() == []


def test_a_design_not_in_service_says_why_it_has_no_estimates(
    page: Any, server: Server, console: Console
) -> None:
    seeded = server.seeded
    inactive = next(d for d in api_get(server, "/api/v1/designs")["items"] if not d["active"])
    url = f"/engine.html?id={seeded.engine_with_event}&design={inactive['id']}"
    sign_in(page, seeded.key, "/")
    _ready(page, url)
    notice = page.inner_text("#no-estimates")
    assert f"Design {inactive['name']} has no estimates" in notice
    assert "active design" in notice
    button = page.locator("#activate-design")
    assert button.is_enabled() and inactive["name"] in button.inner_text()
    assert page.locator(f"#no-estimates a[href='/designs.html?a={inactive['id']}']").count() == 1
    screenshot(page, "engine-design-not-in-service")
    # The active design, chosen by name, has its estimates.
    _ready(page, f"/engine.html?id={seeded.engine_with_event}")
    assert page.locator("#no-estimates").count() == 0
    assert traces(page, "#plot-health")
    # A viewer sees why, and that activating needs an analyst key.
    sign_in(page, seeded.viewer_key, "/")
    _ready(page, url)
    assert page.locator("#activate-design").is_disabled()
    assert "analyst key" in page.inner_text("#no-estimates")
    assert console.unexpected() == []


def _scale_colour(scale: list[list[Any]], f: float) -> str:
    """A plotly colour scale's colour at ``f`` in [0, 1] as CSS rgb(), linear between stops."""
    stops = [(float(s), [float(v) for v in re.findall(r"[\d.]+", c)[:3]]) for s, c in scale]
    f = min(1.0, max(0.0, f))
    k = next(i for i, (s, _) in enumerate(stops) if s >= f) or 1
    (a, ca), (b, cb) = stops[k - 1], stops[k]
    t = (f - a) / (b - a) if b > a else 0.0
    r, g, bl = (round(x + t * (y - x)) for x, y in zip(ca, cb, strict=True))
    return f"rgb({r}, {g}, {bl})"


def test_numbers_in_heatmap_cells_have_aa_contrast(
    page: Any, server: Server, console: Console
) -> None:
    """The confusion and misclassification matrices write their values in the cells: each in
    black or white against that cell's colour of plotly's own colour scale, 4.5:1 or better."""
    a, b = server.seeded.design_ids
    sign_in(page, server.seeded.key, f"/designs.html?a={a}&b={b}")
    heatmaps = page.eval_on_selector_all(
        ".js-plotly-plot", "ds => ds.filter((d) => d.data[0].type === 'heatmap').map((d) => d.id)")
    assert len(heatmaps) >= 3
    ratios = []
    for plot_id in heatmaps:
        cells = page.evaluate(
            """(id) => { const d = document.getElementById(id); const t = d._fullData[0];
                return { scale: t.colorscale, zmin: t.zmin, zmax: t.zmax, z: t.z, x: t.x, y: t.y,
                    notes: d.layout.annotations.filter((n) => n.text)
                        .map((n) => [n.x, n.y, n.font.color]) }; }""",
            plot_id,
        )
        span = (cells["zmax"] - cells["zmin"]) or 1
        for x, y, colour in cells["notes"]:
            v = cells["z"][cells["y"].index(y)][cells["x"].index(x)]
            cell = _scale_colour(cells["scale"], (v - cells["zmin"]) / span)
            ratios.append((plot_id, x, y, v, contrast(_rgb(colour), cell)))
    assert ratios
    low = [r for r in ratios if r[-1] < 4.5]
    assert low == []
    assert console.unexpected() == []
