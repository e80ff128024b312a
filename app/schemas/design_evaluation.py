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
        "and Monte Carlo), confusion (per isolation variant: faults, percent, correct_rate) "
        "and nonlinear_engine (the design on the built-in engine's faulted fleet: "
        "confusion_percent, percent_correct, visibility, ambiguity_groups, health rms and "
        "coverage_95; null with nonlinear_engine_note saying why)"
    )
