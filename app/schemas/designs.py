"""Request and response models of engine models and estimator designs."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import AwareDatetime, BaseModel, Field, model_validator

from app.schemas.fleet import Row, StrictInput

Name = Field(min_length=1, max_length=100)


class EngineModelImport(StrictInput):
    """An engine model: ``model``, one ``fleethealth.linear-model/1`` or
    ``fleethealth.model-schedule/1`` JSON object; or ``models``, several linear-model files at
    operating points that make one schedule over ``variables`` (docs/model-format.md)."""

    engine_type_id: int
    name: str = Name
    model: dict[str, Any] | None = Field(
        None,
        description="the fleethealth.linear-model/1 document (format, dt, signals, matrices, "
        "trim, sensor_noise_std, operating_condition) or a fleethealth.model-schedule/1 "
        "document (format, variables, models, corrections, design_point)",
    )
    models: list[dict[str, Any]] | None = Field(
        None, min_length=1, max_length=1000,
        description="several fleethealth.linear-model/1 documents, one per operating point, "
        "stored as one model schedule (instead of ``model``)",
    )
    variables: list[str] | None = Field(
        None, description="with ``models``: the scheduling variables, operating-condition "
        "columns (alt_ft, mach, dtamb_k, power_pct) each model's operating_condition gives",
    )
    corrections: dict[str, str] | None = Field(
        None, description="with ``models``: signal name -> correction of its trim (none, "
        "temperature, pressure, thrust, speed, fuel_flow); default from the signal's unit",
    )
    design_point: int = Field(
        0, description="with ``models``: index of the model designs are made on")

    @model_validator(mode="after")
    def _one_form(self) -> EngineModelImport:
        if (self.model is None) == (self.models is None):
            raise ValueError("give either model (one file) or models (several files)")
        if self.models is not None and not self.variables:
            raise ValueError("models needs variables: the operating-condition columns the "
                             "models are scheduled on")
        if self.model is not None and (self.variables is not None
                                       or self.corrections is not None):
            raise ValueError("variables and corrections go with models; a schedule file "
                             "carries its own")
        return self


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
    signals: dict[str, list[dict[str, str]]] = Field(
        description="states, inputs, health, sensors and aux, each {name, unit} as the model "
        "file declares them (of a schedule, its design-point model's)")
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
