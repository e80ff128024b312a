"""``calibrate_design``: fit a built-in engine design's model error on simulated fleets and
store it with the design (``designs.calibration``), with progress for the dashboard."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field
from sqlalchemy.orm import Session

from app.services.designs import calibration
from app.services.jobs.registry import Progress, registry


class CalibrateDesign(BaseModel):
    model_config = ConfigDict(extra="forbid")

    design_id: int
    seeds: list[int] = Field(
        default_factory=lambda: list(calibration.CALIBRATION_SEEDS), min_length=1, max_length=16,
        description="one simulated calibration fleet per seed",
    )
    aircraft: int = Field(calibration.CALIBRATION_AIRCRAFT, ge=1, le=50,
                          description="aircraft per calibration fleet (two engines each)")
    flights: int = Field(calibration.CALIBRATION_FLIGHTS, ge=100, le=3000,
                         description="flights per aircraft")


@registry.job(
    calibration.JOB_KIND,
    parameters=CalibrateDesign,
    description="Calibrate a built-in engine design's model error on simulated fleets.",
    role="analyst",
)
def calibrate_design(
    session: Session, parameters: CalibrateDesign, progress: Progress, *, operator_id: int
) -> dict[str, Any]:
    data = calibration.calibration_input(
        session, operator_id=operator_id, design_id=parameters.design_id
    )
    # End the read transaction before the long run (SQLite: see design_evaluation).
    session.commit()
    calib = calibration.run_calibration(
        data, seeds=parameters.seeds, aircraft=parameters.aircraft, flights=parameters.flights,
        progress=progress,
    )
    design = calibration.get_design(session, operator_id=operator_id, design_id=data.design_id)
    stored = calibration.store_calibration(session, design, calib)
    return {"design_id": data.design_id, "observable": [
        n for n, o in zip(stored["names"], stored["observable"], strict=True) if o
    ], "source": stored["source"]}
