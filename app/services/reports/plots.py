"""The report's plots: plotly figures of the data the pages draw, rendered to PNG.

The figures follow the dashboard's (static/js/plots.js): Okabe & Ito's palette, one colour per
engine module (efficiency solid, flow dashed), the 1-sigma band of each estimate, the engine
type's amber and red limit lines. plotly renders them through kaleido, whose wheel carries its
own headless Chromium: nothing is downloaded and no system browser is needed at run time. Where
that renderer cannot start, the report is refused with a 503 naming what is missing.
"""

from __future__ import annotations

import threading
import warnings
from dataclasses import dataclass

import plotly.graph_objects as go
import plotly.io as pio

from app.errors import ServiceUnavailable
from app.services.reports.content import DeteriorationGroup, Panel, Series, unit_label

PALETTE = ("#0072B2", "#E69F00", "#009E73", "#D55E00", "#56B4E9", "#CC79A7", "#000000",
           "#999999")
MODULES = ("fan", "lpc", "hpc", "hpt", "lpt")
LIMIT_COLOURS = {"amber": "#E69F00", "red": "#D55E00"}
# Lato comes with kaleido: the plots look the same on every machine, with or without fonts.
FONT = {"family": "Lato, DejaVu Sans, Arial, sans-serif", "size": 12, "color": "#1d2733"}
# Pixels of an image; the PDF draws it 17 cm wide (about 150 dpi at scale 1.5).
WIDTH, HEIGHT, SCALE = 1000, 420, 1.5
# One render at a time: kaleido's browser takes one figure at a time anyway, its first use
# starts it, and the warning filters below are process-wide.
_RENDER = threading.Lock()


@dataclass(frozen=True)
class Image:
    """A rendered plot: its title and its PNG bytes (``WIDTH`` x ``HEIGHT`` at ``SCALE``)."""

    title: str
    png: bytes


def style(name: str, index: int) -> tuple[str, str]:
    """(colour, dash) of a series, as the dashboard's ``styleFor``."""
    module = name.split("_")[0].lower()
    if module in MODULES:
        return PALETTE[MODULES.index(module)], "dash" if name.endswith("flow") else "solid"
    dashes = ("solid", "dash", "dot", "dashdot")
    return PALETTE[index % len(PALETTE)], dashes[(index // len(PALETTE)) % len(dashes)]


def _rgba(colour: str, alpha: float) -> str:
    n = int(colour[1:], 16)
    return f"rgba({(n >> 16) & 255},{(n >> 8) & 255},{n & 255},{alpha})"


def _axis_title(label: str, series: tuple[Series, ...]) -> str:
    units = ", ".join(dict.fromkeys(unit_label(s.unit) for s in series))
    return f"{label} [{units}]" if units else label


def _layout(title: str, ytitle: str, xtitle: str = "Date (UTC)") -> go.Layout:
    return go.Layout(
        title={"text": title, "x": 0.01, "font": {"size": 15}},
        font=FONT, paper_bgcolor="#ffffff", plot_bgcolor="#ffffff",
        margin={"l": 75, "r": 20, "t": 60, "b": 55},
        legend={"orientation": "v", "x": 1.01, "y": 1, "font": {"size": 11},
                "traceorder": "normal"},
        xaxis={"title": {"text": xtitle}, "type": "date", "gridcolor": "#e3e8ee",
               "zerolinecolor": "#c5ced8"},
        yaxis={"title": {"text": ytitle}, "gridcolor": "#e3e8ee", "zerolinecolor": "#c5ced8"},
    )


def panel_figure(panel: Panel, time: list[str]) -> go.Figure:
    """One panel of the engine page: each series with its 1-sigma band, and its limit lines."""
    figure = go.Figure(layout=_layout(panel.title, _axis_title(panel.ylabel, panel.series)))
    for i, s in enumerate(panel.series):
        colour, dash = style(s.name, i)
        if s.sigma is not None:
            upper = [None if v is None or e is None else v + e
                     for v, e in zip(s.value, s.sigma, strict=True)]
            lower = [None if v is None or e is None else v - e
                     for v, e in zip(s.value, s.sigma, strict=True)]
            figure.add_trace(go.Scatter(x=time, y=upper, mode="lines", line={"width": 0},
                                        hoverinfo="skip", showlegend=False))
            figure.add_trace(go.Scatter(x=time, y=lower, mode="lines", line={"width": 0},
                                        fill="tonexty", fillcolor=_rgba(colour, 0.18),
                                        hoverinfo="skip", showlegend=False))
        figure.add_trace(go.Scatter(x=time, y=s.value, mode="lines", name=s.name,
                                    line={"color": colour, "dash": dash, "width": 1.6}))
    for limit in panel.limits:
        figure.add_hline(y=limit.value, line={"color": LIMIT_COLOURS.get(limit.level, "#555555"),
                                              "dash": "dash", "width": 1.2},
                         annotation_text=f"{limit.level} {limit.value:g}",
                         annotation_position="top left")
    return figure


def deterioration_figure(groups: tuple[DeteriorationGroup, ...], which: str) -> go.Figure:
    """The fleet page's deterioration plot: fleet mean per bucket, spread over engines as
    error bars; ``which`` is "health" or "aux"."""
    label = ("Fleet-average health level from nominal" if which == "health"
             else "Fleet-average thrust and margins, % of the nominal engine")
    series = tuple(s for g in groups for s in (g.health if which == "health" else g.aux))
    figure = go.Figure(layout=_layout(label, _axis_title(label, series)))
    multi = len(groups) > 1
    for gi, g in enumerate(groups):
        for i, s in enumerate(g.health if which == "health" else g.aux):
            colour, dash = style(s.name, i)
            figure.add_trace(go.Scatter(
                x=g.time, y=s.value, mode="lines+markers",
                name=f"{s.name} ({g.engine_type})" if multi else s.name,
                line={"color": colour, "dash": "dot" if gi else dash, "width": 1.8},
                error_y={"type": "data", "array": s.sigma, "visible": True, "thickness": 1,
                         "width": 3, "color": colour},
            ))
    return figure


def png(figure: go.Figure) -> bytes:
    """The figure as PNG, or a 503 naming what is missing."""
    try:
        with _RENDER, warnings.catch_warnings():
            # plotly announces the end of kaleido 0.x, the one whose wheel ships its browser.
            warnings.simplefilter("ignore", DeprecationWarning)
            return pio.to_image(figure, format="png", width=WIDTH, height=HEIGHT, scale=SCALE)
    except (ValueError, OSError, RuntimeError) as exc:
        raise ServiceUnavailable(
            "report plots cannot be rendered: plotly's image export needs the kaleido package "
            f"(pip install 'kaleido==0.2.1', which ships its own Chromium): {exc}",
            details=[{"location": ["plots"], "reason": str(exc)[:300]}],
        ) from exc


def engine_images(panels: tuple[Panel, ...], time: list[str]) -> list[Image]:
    return [Image(p.title, png(panel_figure(p, time))) for p in panels if time]


def fleet_images(groups: tuple[DeteriorationGroup, ...]) -> list[Image]:
    if not groups:
        return []
    return [Image(title, png(deterioration_figure(groups, which)))
            for which, title in (("health", "Fleet-average health level from nominal"),
                                 ("aux", "Fleet-average thrust and stall-margin change"))]
