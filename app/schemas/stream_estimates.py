"""Stream estimates as served: decimated q_hat, h_hat, z_hat with 1-sigma and residuals."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field


class StreamEstimatesOut(BaseModel):
    """Series aligned with ``t_s`` (seconds from the recording's start, first sample of each
    point's window); every value is a window mean, in percent (of trim, or health deviation)."""

    recording_id: int
    engine_id: int
    design_id: int | None = Field(description="design the series were estimated with")
    window_s: float = Field(description="recording time each point averages")
    n_samples: int = Field(description="samples received")
    n_samples_estimated: int = Field(description="samples the filter has run over")
    names: dict[str, list[str]] = Field(description="tuners, health, aux, sensors")
    t_s: list[float]
    q_hat: dict[str, list[float | None]]
    q_sigma: dict[str, list[float | None]]
    h_hat: dict[str, list[float | None]]
    h_sigma: dict[str, list[float | None]]
    z_hat: dict[str, list[float | None]]
    z_sigma: dict[str, list[float | None]]
    residual: dict[str, list[float | None]] = Field(description="innovation per sensor, % of trim")
    uncertainty: str = Field(
        "uncalibrated",
        description=(
            "what q_sigma and h_sigma are. calibrated: the design's stream calibration on the "
            "built-in engine's simulated flights (h_hat and q_hat are then the calibrated "
            "level and tuners, and the sigma the honest one: filter and model error); "
            "uncalibrated: the stream filter's own 1-sigma (sensor noise alone, much narrower "
            "than the real error); sensors: calibrated without this recording's sensor set, "
            "so the filter's own 1-sigma"
        ),
    )
    unobservable: list[str] = Field(
        default_factory=list,
        description="health parameters the calibration finds unobservable: their values are null")
    tuners_unobservable: list[str] = Field(
        default_factory=list,
        description="tuners the calibration finds unobservable: their values are null")


class TransientBiasFit(BaseModel):
    """Fit a design's transient bias model (seed 004) on recordings of healthy engines."""

    model_config = ConfigDict(extra="forbid")

    recording_ids: list[int] = Field(min_length=1, max_length=200,
                                     description="stream recordings of healthy engines")
    ti_star: float = Field(1e-3, ge=0.0, le=1.0,
                           description="dead band of the transient index, 1/s")
    ti_tau_s: float = Field(0.5, ge=0.0, le=60.0,
                            description="time constant of the low-pass on the index, s")


class TransientBiasOut(BaseModel):
    """A design's stored bias model (``fleethealth.transient-bias/1``)."""

    design_id: int
    model: dict[str, Any] | None = Field(description="null while no model is fitted")
