"""``fit_transient_bias``: fit a design's transient bias model on healthy recordings and store
it with the design (docs/math.md section 7), with progress for the dashboard."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field
from sqlalchemy.orm import Session

from app.services.jobs.registry import Progress, registry
from app.services.streams import bias


class FitTransientBias(BaseModel):
    model_config = ConfigDict(extra="forbid")

    design_id: int = Field(ge=1)
    recording_ids: list[int] = Field(min_length=1, max_length=bias.MAX_RECORDINGS,
                                     description="recordings of healthy engines")
    ti_star: float = Field(1e-3, ge=0.0, le=1.0, description="dead band of the index, 1/s")
    ti_tau_s: float = Field(0.5, ge=0.0, le=60.0, description="low-pass on the index, s")


@registry.job(
    bias.JOB_KIND,
    parameters=FitTransientBias,
    description="Fit a design's transient bias model (seed 004) on healthy recordings.",
    role="analyst",
)
def fit_transient_bias(
    session: Session, parameters: FitTransientBias, progress: Progress, *, operator_id: int
) -> dict[str, Any]:
    from app.config import get_settings

    return bias.fit_and_store(
        session, get_settings().data_dir, operator_id=operator_id,
        design_id=parameters.design_id, recording_ids=parameters.recording_ids,
        ti_star=parameters.ti_star, ti_tau_s=parameters.ti_tau_s, progress=progress,
    )
