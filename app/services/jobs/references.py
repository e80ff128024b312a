"""Rows a job's parameters name must be the submitting operator's, checked at submission.

Without this a job naming another operator's design was queued and failed later in the
runner; now the request is refused with a 404 (as the row's own route would answer) before
anything is stored.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel
from sqlalchemy.orm import Session

from app.errors import NotFound
from app.models import Engine, EstimatorDesign, StreamRecording, Upload

# Parameter name -> (table, the row's name in messages).
REFERENCES: dict[str, tuple[type[Any], str]] = {
    "design_id": (EstimatorDesign, "design"),
    "recording_id": (StreamRecording, "recording"),
    "engine_id": (Engine, "engine"),
    "upload_id": (Upload, "upload"),
}


def check_references(session: Session, operator_id: int, parameters: BaseModel) -> None:
    """NotFound (404) naming the parameter when a referenced row is missing or another
    operator's."""
    for field, (model, what) in REFERENCES.items():
        value = getattr(parameters, field, None)
        if not isinstance(value, int) or isinstance(value, bool):
            continue
        row = session.get(model, value)
        if row is None or getattr(row, "operator_id", None) != operator_id:
            raise NotFound(
                f"{what} {value} not found",
                details=[{"row": None, "column": f"parameters.{field}",
                          "reason": f"no {what} {value} in your fleet"}],
            )
