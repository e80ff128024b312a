"""``calibrate_design``: fit a built-in engine design's model error on simulated fleets and
store it with the design (``designs.calibration``), with progress for the dashboard."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field, model_validator
from sqlalchemy.orm import Session

from app.services.designs import calibration
from app.services.jobs.registry import Progress, registry
from app.services.streams import calibration as stream_calibration
from app.services.streams import store as stream_store


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
    snapshots: bool = Field(True, description=(
        "calibrate the snapshot estimates (the engine and fleet pages); false keeps the stored "
        "snapshot calibration and calibrates the stream estimates alone"))
    streams: bool = Field(True, description=(
        "also calibrate the stream estimates (the recording page) on whole flights of the "
        "closed-loop transient simulator"))
    stream_seed: int = Field(stream_calibration.SEED,
                             description="the simulated fleet of recorded flights")
    stream_aircraft: int = Field(stream_calibration.AIRCRAFT, ge=2, le=128,
                                 description="its aircraft (two engines each, four flights)")
    stream_duration_s: float | None = Field(
        None, ge=300.0, le=2500.0,
        description="seconds of each simulated flight (null: the whole 2500 s flight)")

    @model_validator(mode="after")
    def _something_to_calibrate(self) -> CalibrateDesign:
        if not (self.snapshots or self.streams):
            raise ValueError("nothing to calibrate: snapshots and streams are both false")
        return self


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
    # The snapshots' share of the progress bar.
    share = 0.0 if not parameters.snapshots else 0.6 if stream_est is not None else 1.0

    def snapshots_part(fraction: float, message: str | None = None) -> None:
        progress(share * fraction, message)

    def streams_part(fraction: float, message: str | None = None) -> None:
        progress(share + (1.0 - share) * 0.95 * fraction, message)

    def recordings_part(fraction: float, message: str | None = None) -> None:
        progress(share + (1.0 - share) * (0.95 + 0.05 * fraction), message)

    calib = calibration.run_calibration(
        data, seeds=parameters.seeds, aircraft=parameters.aircraft, flights=parameters.flights,
        progress=snapshots_part,
    ) if parameters.snapshots else None
    stream_calib = (None if stream_est is None else stream_calibration.calibrate(
        stream_est, seed=parameters.stream_seed, aircraft=parameters.stream_aircraft,
        duration_s=parameters.stream_duration_s, design=data.name, progress=streams_part))
    design = calibration.get_design(session, operator_id=operator_id, design_id=data.design_id)
    out: dict[str, Any] = {"design_id": data.design_id}
    if calib is not None:
        stored = calibration.store_calibration(session, design, calib)
        out["observable"] = [
            n for n, o in zip(stored["names"], stored["observable"], strict=True) if o]
        out["source"] = stored["source"]
    if stream_calib is not None:
        streams = stream_calibration.store_calibration(session, design, stream_calib)
        out["streams_observable"] = [
            n for n, o in zip(streams["names"], streams["observable"], strict=True) if o]
        # The design's recordings at another rate than the calibration's were filtered with R
        # per sample; its filter now holds R at the calibration's interval.
        from app.config import get_settings

        out["recordings_estimated_again"] = stream_store.estimate_held(
            session, get_settings().data_dir, design, recordings_part)
    return out
