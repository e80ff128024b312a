"""A report file: its content read through the services, its plots rendered, written as PDF
or as an Excel workbook. Nothing is stored: the file goes straight to the caller."""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Literal

from sqlalchemy.orm import Session

from app.services.reports import content, pdf, plots, workbook

ReportFormat = Literal["pdf", "xlsx"]
MEDIA_TYPES: dict[str, str] = {
    "pdf": "application/pdf",
    "xlsx": "application/vnd.openxmlformats-officedocument.spreadsheetml.sheet",
}


@dataclass(frozen=True)
class ReportFile:
    body: bytes
    media_type: str
    filename: str


def _safe(name: str) -> str:
    """A file-name part of ``name``: letters, digits, dot, dash and underscore."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("_") or "report"


def engine_report(
    session: Session, operator_id: int, engine_id: int, fmt: ReportFormat
) -> ReportFile:
    report = content.engine_report(session, operator_id, engine_id)
    images = plots.engine_images(report.panels, report.time)
    body = (pdf.engine_pdf(report, images) if fmt == "pdf"
            else workbook.engine_workbook(report, images))
    return ReportFile(body, MEDIA_TYPES[fmt], f"engine-report-{_safe(report.esn)}.{fmt}")


def fleet_report(session: Session, operator_id: int, fmt: ReportFormat) -> ReportFile:
    report = content.fleet_report(session, operator_id)
    images = plots.fleet_images(report.deterioration)
    body = (pdf.fleet_pdf(report, images) if fmt == "pdf"
            else workbook.fleet_workbook(report, images))
    return ReportFile(body, MEDIA_TYPES[fmt], f"fleet-report-{_safe(report.operator)}.{fmt}")
