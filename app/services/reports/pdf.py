"""Reports as PDF (reportlab): the tables first, then each plot as an image."""

from __future__ import annotations

import io
from collections.abc import Iterable, Sequence
from html import escape

from reportlab.lib import colors
from reportlab.lib.pagesizes import A4, landscape
from reportlab.lib.styles import ParagraphStyle, getSampleStyleSheet
from reportlab.lib.units import cm
from reportlab.platypus import (
    Flowable,
    KeepTogether,
    Paragraph,
    SimpleDocTemplate,
    Spacer,
    Table,
    TableStyle,
)
from reportlab.platypus import Image as PdfImage

from app.services.reports.content import (
    EngineReport,
    EventLine,
    FleetReport,
    label,
    number,
    stamp,
    unit_label,
)
from app.services.reports.plots import HEIGHT, WIDTH, Image

STYLES = getSampleStyleSheet()
SMALL = ParagraphStyle("small", parent=STYLES["BodyText"], fontSize=8, leading=10)
STATE_COLOURS = {"alert": "#D55E00", "watch": "#E69F00", "normal": "#009E73",
                 "no_data": "#999999"}
MARGIN = 1.5 * cm
# The fleet's tables are wide: its report is landscape.
FLEET_PAGE = landscape(A4)


def _table(header: Sequence[str], rows: Iterable[Sequence[str]],
           widths: Sequence[float] | None = None) -> Flowable:
    body = [[Paragraph(escape(str(c), quote=False), SMALL) for c in row] for row in rows]
    data = [[Paragraph(f"<b>{h}</b>", SMALL) for h in header], *body]
    table = Table(data, colWidths=widths, repeatRows=1, hAlign="LEFT")
    table.setStyle(TableStyle([
        ("GRID", (0, 0), (-1, -1), 0.25, colors.HexColor("#c5ced8")),
        ("BACKGROUND", (0, 0), (-1, 0), colors.HexColor("#eef2f6")),
        ("VALIGN", (0, 0), (-1, -1), "TOP"),
    ]))
    return table


def _none(text: str) -> Flowable:
    return Paragraph(f"<i>{text}</i>", STYLES["BodyText"])


def _images(images: list[Image], page: tuple[float, float] = A4) -> list[Flowable]:
    out: list[Flowable] = []
    width = min(page[0] - 2 * MARGIN, 24 * cm)
    for image in images:
        picture = PdfImage(io.BytesIO(image.png), width=width, height=width * HEIGHT / WIDTH)
        out.append(KeepTogether([picture, Spacer(1, 0.3 * cm)]))
    return out


def _events(events: tuple[EventLine, ...], with_engine: bool) -> Flowable:
    widths = ([1.2, 2.4, 1.8] if with_engine else [1.2]) + [2.4, 2.2, 2.0, 1.5, 1.8, 2.8, 3.2,
                                                            2.5]
    if not events:
        return _none("No active events.")
    header = ["Event", *(["ESN", "Tail"] if with_engine else []), "Detected", "Kind", "Status",
              "Fault", "Magnitude", "Isolated (probability)", "Ambiguity group", "Assignee"]
    rows = [[
        str(e.id), *([e.esn, e.tail or "–"] if with_engine else []), stamp(e.detected_at),
        e.kind, e.status, e.fault or "–", number(e.magnitude),
        "–" if e.isolated is None else f"{e.isolated} ({number(e.probability)})",
        ", ".join(e.ambiguity_group) or "–", e.assignee or "–",
    ] for e in events]
    return _table(header, rows, [w * cm for w in widths] if with_engine else None)


def _state(state: str, severity: str | None) -> str:
    colour = STATE_COLOURS.get(state, "#1d2733")
    return f'<font color="{colour}"><b>{escape(state)}</b></font> (severity {severity or "–"})'


def _build(story: list[Flowable], title: str, page: tuple[float, float] = A4) -> bytes:
    sink = io.BytesIO()
    document = SimpleDocTemplate(sink, pagesize=page, title=title, author="fleethealth",
                                 leftMargin=MARGIN, rightMargin=MARGIN,
                                 topMargin=MARGIN, bottomMargin=MARGIN)
    document.build(story)
    return sink.getvalue()


def engine_pdf(report: EngineReport, images: list[Image]) -> bytes:
    h1, h2, body = STYLES["Title"], STYLES["Heading2"], STYLES["BodyText"]
    where = ("not installed" if report.tail is None
             else f"{report.tail} position {report.position}")
    story: list[Flowable] = [
        Paragraph(f"Engine report · {escape(report.esn)}", h1),
        Paragraph(f"{escape(report.operator)} · generated {stamp(report.generated_at)}", body),
        Spacer(1, 0.3 * cm),
        _table(["ESN", "Engine type", "Installed on", "Design", "Records", "Last data"],
               [[report.esn, report.engine_type, where, report.design_name or "none",
                 str(report.n_records), stamp(report.last_data)]]),
        Spacer(1, 0.3 * cm),
        Paragraph(f"State: {_state(report.state, report.severity)}", body),
        Paragraph(f"Reason: {escape(report.reason or 'within limits')}", body),
    ]
    if report.checks:
        story.append(_table(
            ["Limit", "Value", "Amber", "Red", "Level"],
            [[c.limit, f"{number(c.value)} {unit_label(c.unit)}", number(c.amber),
              number(c.red), c.level] for c in report.checks]))
    story.append(Paragraph("Current figures (latest record, ± 1 sigma where estimated)", h2))
    if report.figures:
        story.append(_table(
            ["Figure", "Name", "Value", "1-sigma", "Unit"],
            [[label(f.name), f.name, number(f.value), number(f.sigma), unit_label(f.unit)]
             for f in report.figures],
            widths=[5.5 * cm, 3.5 * cm, 2.5 * cm, 2.5 * cm, 3.0 * cm]))
    else:
        story.append(_none("No estimates for this engine."))
    if report.performance_note:
        story.append(_none(escape(report.performance_note)))
    story += [Paragraph("Active events and their isolation", h2),
              _events(report.events, with_engine=False),
              Paragraph("Maintenance actions", h2)]
    story.append(_table(["Performed", "Kind", "Notes"],
                        [[stamp(m.performed_at), m.kind.replace("_", " "), m.notes or ""]
                         for m in report.maintenance])
                 if report.maintenance else _none("No maintenance actions."))
    story.append(Paragraph("Trends", h2))
    story += _images(images) or [_none("No estimates to plot.")]
    return _build(story, f"Engine report {report.esn}")


def fleet_pdf(report: FleetReport, images: list[Image]) -> bytes:
    h1, h2, body = STYLES["Title"], STYLES["Heading2"], STYLES["BodyText"]
    states = report.states
    story: list[Flowable] = [
        Paragraph(f"Fleet report · {escape(report.operator)}", h1),
        Paragraph(f"generated {stamp(report.generated_at)}", body),
        Spacer(1, 0.3 * cm),
        _table(["Engines", "Active events", "Alert (red)", "Watch (amber)", "Normal", "No data"],
               [[str(report.n_engines), str(report.n_open_events), str(states.get("alert", 0)),
                 str(states.get("watch", 0)), str(states.get("normal", 0)),
                 str(states.get("no_data", 0))]]),
        Paragraph("Fleet status, worst first", h2),
    ]
    story.append(_table(
        ["#", "ESN", "Tail", "Type", "State", "Reason", "Largest health level from nominal [%]",
         "Thrust deficit [%]", "Last data", "Active events"],
        [[str(e.rank), e.esn, "–" if e.tail is None else f"{e.tail} #{e.position}",
          e.engine_type, e.state, e.reason or "within limits",
          "–" if e.worst_health is None
          else f"{e.worst_health} {number(e.worst_health_value)} ± "
               f"{number(e.worst_health_sigma)}",
          number(e.thrust_deficit), stamp(e.last_data), str(e.open_events)]
         for e in report.engines],
        [w * cm for w in (0.8, 2.6, 2.0, 3.2, 1.5, 6.0, 3.4, 1.7, 2.6, 1.6)],
    ) if report.engines else _none("No engines."))
    story += [Paragraph("Active alerts", h2), _events(report.alerts, with_engine=True),
              Paragraph(f"Fleet-average deterioration per {report.bucket}", h2),
              Paragraph("Mean over the engines with data in each bucket; error bars: spread "
                        "over engines (± 1 standard deviation).", body)]
    story += _images(images, FLEET_PAGE) or [_none("No estimates yet.")]
    return _build(story, f"Fleet report {report.operator}", FLEET_PAGE)
