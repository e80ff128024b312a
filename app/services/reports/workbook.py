"""Reports as Excel workbooks (openpyxl): one sheet per table, numbers as numbers, the data of
every plot, and a sheet with the plots as images."""

from __future__ import annotations

import io
from collections.abc import Iterable, Sequence
from datetime import UTC, datetime
from typing import Any

from openpyxl import Workbook
from openpyxl.drawing.image import Image as SheetImage
from openpyxl.styles import Font, PatternFill
from openpyxl.utils import get_column_letter
from openpyxl.worksheet.worksheet import Worksheet

from app.services.reports.content import (
    EngineReport,
    EventLine,
    FleetReport,
    label,
    unit_label,
)
from app.services.reports.plots import HEIGHT, WIDTH, Image

HEADER = Font(bold=True)
HEADER_FILL = PatternFill("solid", fgColor="EEF2F6")
# Rows an image takes on the plots sheet (default row height 15 points = 20 pixels) at the
# size it is shown.
SHOWN_WIDTH = 900
IMAGE_ROWS = int(SHOWN_WIDTH * HEIGHT / WIDTH / 20) + 3


def _utc(value: datetime) -> datetime:
    """Excel has no time zones: times are written as naive UTC (the headers say so)."""
    return value.astimezone(UTC).replace(tzinfo=None)


def _cell(value: Any) -> Any:
    return _utc(value) if isinstance(value, datetime) else value


def _sheet(book: Workbook, title: str, header: Sequence[str],
           rows: Iterable[Sequence[Any]]) -> Worksheet:
    sheet = book.create_sheet(title)
    sheet.append(list(header))
    for cell in sheet[1]:
        cell.font, cell.fill = HEADER, HEADER_FILL
    for row in rows:
        sheet.append([_cell(v) for v in row])
    for j, name in enumerate(header, start=1):
        sheet.column_dimensions[get_column_letter(j)].width = max(10, min(40, len(name) + 2))
    sheet.freeze_panes = "A2"
    return sheet


def _events(book: Workbook, title: str, events: tuple[EventLine, ...]) -> None:
    _sheet(book, title,
           ["event", "esn", "tail", "detected_at (UTC)", "kind", "status", "fault", "magnitude",
            "isolated", "probability", "ambiguity_group", "assignee"],
           [[e.id, e.esn, e.tail, e.detected_at, e.kind, e.status, e.fault, e.magnitude,
             e.isolated, e.probability, ", ".join(e.ambiguity_group), e.assignee]
            for e in events])


def _plots(book: Workbook, images: list[Image]) -> None:
    sheet = book.create_sheet("Plots")
    row = 1
    for image in images:
        sheet.cell(row=row, column=1, value=image.title).font = HEADER
        picture = SheetImage(io.BytesIO(image.png))
        picture.width, picture.height = SHOWN_WIDTH, int(SHOWN_WIDTH * HEIGHT / WIDTH)
        sheet.add_image(picture, f"A{row + 1}")
        row += IMAGE_ROWS
    if not images:
        sheet.cell(row=1, column=1, value="No estimates to plot.")


def _save(book: Workbook) -> bytes:
    sink = io.BytesIO()
    book.save(sink)
    return sink.getvalue()


def engine_workbook(report: EngineReport, images: list[Image]) -> bytes:
    book = Workbook()
    summary = book.active
    assert summary is not None
    summary.title = "Engine"
    for key, value in (
        ("Report", f"Engine report {report.esn}"), ("Operator", report.operator),
        ("Generated (UTC)", report.generated_at), ("ESN", report.esn),
        ("Engine type", report.engine_type), ("Tail", report.tail),
        ("Position", report.position), ("Design", report.design_name),
        ("State", report.state), ("Severity", report.severity),
        ("Reason", report.reason or "within limits"), ("Records", report.n_records),
        ("Last data (UTC)", report.last_data),
        ("Engineering figures", report.performance_note or "in the Figures and Trend sheets"),
    ):
        summary.append([key, _cell(value)])
        summary.cell(row=summary.max_row, column=1).font = HEADER
    summary.column_dimensions["A"].width = 18
    summary.column_dimensions["B"].width = 40
    _sheet(book, "Limit checks", ["limit", "value", "unit", "amber", "red", "level"],
           [[c.limit, c.value, unit_label(c.unit), c.amber, c.red, c.level]
            for c in report.checks])
    _sheet(book, "Figures", ["group", "name", "figure", "value", "sigma", "unit"],
           [[f.group, f.name, label(f.name), f.value, f.sigma, unit_label(f.unit)]
            for f in report.figures])
    _events(book, "Active events", report.events)
    _sheet(book, "Maintenance", ["performed_at (UTC)", "kind", "notes"],
           [[m.performed_at, m.kind, m.notes] for m in report.maintenance])
    # The plotted data: one row per record, each series with its 1-sigma.
    columns: list[tuple[str, list[float | None]]] = []
    for panel in report.panels:
        for s in panel.series:
            columns.append((f"{s.name} [{unit_label(s.unit)}]", s.value))
            if s.sigma is not None:
                columns.append((f"{s.name} sigma [{unit_label(s.unit)}]", s.sigma))
    _sheet(book, "Trend", ["time (UTC)", *(name for name, _v in columns)],
           [[_utc(datetime.fromisoformat(t.replace("Z", "+00:00"))),
             *(v[i] for _n, v in columns)] for i, t in enumerate(report.time)])
    _plots(book, images)
    return _save(book)


def fleet_workbook(report: FleetReport, images: list[Image]) -> bytes:
    book = Workbook()
    summary = book.active
    assert summary is not None
    summary.title = "Fleet"
    for key, value in (
        ("Report", f"Fleet report {report.operator}"), ("Operator", report.operator),
        ("Generated (UTC)", report.generated_at), ("Engines", report.n_engines),
        ("Active events", report.n_open_events),
        *((f"State {state}", count) for state, count in report.states.items()),
    ):
        summary.append([key, _cell(value)])
        summary.cell(row=summary.max_row, column=1).font = HEADER
    summary.column_dimensions["A"].width = 18
    summary.column_dimensions["B"].width = 40
    _sheet(book, "Status",
           ["rank", "esn", "engine_type", "tail", "position", "state", "severity", "reason",
            "worst_health", "worst_health_value [%]", "worst_health_sigma [%]",
            "thrust_deficit [%]", "last_data (UTC)", "n_records", "open_events"],
           [[e.rank, e.esn, e.engine_type, e.tail, e.position, e.state, e.severity, e.reason,
             e.worst_health, e.worst_health_value, e.worst_health_sigma, e.thrust_deficit,
             e.last_data, e.n_records, e.open_events] for e in report.engines])
    _events(book, "Active alerts", report.alerts)
    rows = []
    for g in report.deterioration:
        for s in (*g.health, *g.aux):
            for i, t in enumerate(g.time):
                rows.append([g.engine_type, _utc(datetime.fromisoformat(t.replace("Z", "+00:00"))),
                             g.n_engines[i], s.name, s.unit, s.value[i],
                             None if s.sigma is None else s.sigma[i]])
    _sheet(book, "Deterioration",
           ["engine_type", f"{report.bucket} (UTC)", "n_engines", "series", "unit", "mean",
            "spread (1 sd)"], rows)
    _plots(book, images)
    return _save(book)
