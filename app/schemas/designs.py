"""Request and response models of engine models and estimator designs."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import AwareDatetime, BaseModel, Field

from app.schemas.fleet import Row, StrictInput

Name = Field(min_length=1, max_length=100)


class EngineModelImport(StrictInput):
    """An engine model file: ``model`` is a ``fleethealth.linear-model/1`` JSON object."""

    engine_type_id: int
    name: str = Name
    model: dict[str, Any] = Field(
        description="the fleethealth.linear-model/1 document (format, dt, signals, matrices, "
        "trim, sensor_noise_std, operating_condition)"
    )


class BuiltinModelCreate(StrictInput):
    """The built-in two-spool engine linearised at one operating condition."""

    engine_type_id: int
    name: str = Name
    alt_ft: float = Field(ge=-2000, le=60000, description="altitude, ft")
    mach: float = Field(ge=0, le=1, description="flight Mach number")
    power_pct: float = Field(gt=0, le=110, description="power setting, % of take-off power")
    dtamb_k: float = Field(0.0, ge=-60, le=60, description="ambient offset from ISA, K")


class EngineModelOut(Row):
    id: int
    engine_type_id: int
    name: str
    version: int
    source: Literal["imported", "builtin"]
    format: str
    checksum: str
    dt: float
    n_states: int
    sensor_names: list[str]
    health_names: list[str]
    aux_names: list[str]
    created_at: AwareDatetime
    locked_at: AwareDatetime | None


class EngineModelContent(BaseModel):
    id: int
    version: int
    model: dict[str, Any]


class DesignCreate(StrictInput):
    """A design spec for the estimation core's design step, on one engine model."""

    engine_model_id: int
    name: str = Name
    spec: dict[str, Any] = Field(description="the design spec (sensor suite, tuner method, noise)")


class DesignOut(Row):
    id: int
    engine_type_id: int
    engine_model_id: int
    name: str
    status: Literal["pending", "ready", "failed"]
    spec: dict[str, Any]
    ssee_health: float | None
    ssee_aux: float | None
    analytic_errors: dict[str, Any] | None
    failure: str | None
    active: bool
    created_at: AwareDatetime
    completed_at: AwareDatetime | None
    activated_at: AwareDatetime | None


class DesignDetail(DesignOut):
    result: dict[str, Any] | None
    job_id: int | None = Field(
        None, description="the create_design job making a design created in the background"
    )
