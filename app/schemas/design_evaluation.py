"""Response of a design's latest Monte Carlo evaluation."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from pydantic import BaseModel, Field


class DesignEvaluation(BaseModel):
    design_id: int
    job_id: int
    finished_at: datetime | None
    parameters: dict[str, Any]
    result: dict[str, Any] = Field(
        description="fleethealth.evaluation/1: monte_carlo (SSEE per health parameter, theory "
        "and Monte Carlo) and confusion (per isolation variant: faults, percent, correct_rate)"
    )
