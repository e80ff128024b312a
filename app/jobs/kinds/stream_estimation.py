"""Stream estimation kind: run the steady-state reduced-order filter over a recording's new
samples (queued after a whole-flight upload and after each live chunk)."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field
from sqlalchemy.orm import Session

from app.services.jobs.registry import Progress, registry
from app.services.streams import store as stream_store


class EstimateRecording(BaseModel):
    """``through_sample`` (the recording's sample count when queued) tells the jobs of
    successive live chunks apart; each job estimates whatever has arrived when it runs."""

    model_config = ConfigDict(extra="forbid")

    recording_id: int = Field(ge=1)
    through_sample: int = Field(default=0, ge=0)


@registry.job(
    "estimate_recording",
    parameters=EstimateRecording,
    description="Run the stream filter over a recording's new samples and store its trend.",
    role="analyst",
    submittable=False,
)
def estimate_recording(
    session: Session, parameters: EstimateRecording, progress: Progress, *, operator_id: int
) -> dict[str, Any]:
    from app.config import get_settings

    return stream_store.estimate_recording(
        session,
        operator_id=operator_id,
        recording_id=parameters.recording_id,
        data_dir=get_settings().data_dir,
        progress=progress,
    )
