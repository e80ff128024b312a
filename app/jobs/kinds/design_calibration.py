"""``calibrate_design``: fit a built-in engine design's model error on simulated fleets and
store it with the design (``designs.calibration``), with progress for the dashboard."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field
from sqlalchemy.orm import Session

from app.services.designs import calibration
from app.services.jobs.registry import Progress, registry
from app.services.streams import calibration as stream_calibration


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
    streams: bool = Field(True, description=(
        "also calibrate the stream estimates (the recording page) on whole flights of the "
        "closed-loop transient simulator"))
    stream_seed: int = Field(stream_calibration.SEED,
                             description="the simulated fleet of recorded flights")
    stream_aircraft: int = Field(stream_calibration.AIRCRAFT, ge=2, le=64,
                                 description="its aircraft (two engines each, four flights)")
    stream_duration_s: float | None = Field(
        None, ge=300.0, le=2500.0,
        description="seconds of each simulated flight (null: the whole 2500 s flight)")


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
    stream_est = (stream_calibration.calibration_input(
        session, operator_id=operator_id, design_id=parameters.design_id)
        if parameters.streams else None)
    # End the read transaction before the long run (SQLite: see design_evaluation).
    session.commit()
    share = 0.6 if stream_est is not None else 1.0  # of the progress bar: the snapshots'

    def snapshots_part(fraction: float, message: str | None = None) -> None:
        progress(share * fraction, message)

    def streams_part(fraction: float, message: str | None = None) -> None:
        progress(share + (1.0 - share) * fraction, message)

    calib = calibration.run_calibration(
        data, seeds=parameters.seeds, aircraft=parameters.aircraft, flights=parameters.flights,
        progress=snapshots_part,
    )
    stream_calib = (None if stream_est is None else stream_calibration.calibrate(
        stream_est, seed=parameters.stream_seed, aircraft=parameters.stream_aircraft,
        duration_s=parameters.stream_duration_s, design=data.name, progress=streams_part))
    design = calibration.get_design(session, operator_id=operator_id, design_id=data.design_id)
    stored = calibration.store_calibration(session, design, calib)
    out = {"design_id": data.design_id, "observable": [
        n for n, o in zip(stored["names"], stored["observable"], strict=True) if o
    ], "source": stored["source"]}
    if stream_calib is not None:
        streams = stream_calibration.store_calibration(session, design, stream_calib)
        out["streams_observable"] = [
            n for n, o in zip(streams["names"], streams["observable"], strict=True) if o]
    return out
