"""Request and response models of the fleet: engine types, aircraft, engines, installations,
maintenance actions, API keys, and the page envelope of every list."""

from __future__ import annotations

import re
from datetime import datetime
from typing import Annotated, Any, Generic, Literal, TypeVar

from pydantic import (
    AwareDatetime,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    StringConstraints,
    field_validator,
)

MAX_PAGE = 1000
T = TypeVar("T")

Tail = Annotated[
    str, StringConstraints(min_length=1, max_length=32, pattern=r"^[A-Za-z0-9][A-Za-z0-9\-_. ]*$")
]
Esn = Annotated[
    str, StringConstraints(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9][A-Za-z0-9\-_./]*$")
]
Position = Annotated[int, Field(ge=1, le=4, description="engine position on the aircraft, 1..4")]
MaintenanceKind = Literal["water_wash", "module_change", "shop_visit", "borescope_finding"]
Role = Literal["viewer", "analyst", "admin"]


_NUMBER = re.compile(r"\s*[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?\s*")


def _iso_text(value: object) -> object:
    """Refuse a number where a date-time is due: pydantic would read ``0.5`` as seconds
    since 1970, which no client sending ``?at=0.5`` means."""
    if isinstance(value, int | float) and not isinstance(value, bool) or (
        isinstance(value, str) and _NUMBER.fullmatch(value)
    ):
        raise ValueError("expected an ISO 8601 date-time 2026-03-01T12:00:00Z, not a number")
    return value


# Date-times in query parameters: ISO 8601 text only.
IsoDatetime = Annotated[datetime, BeforeValidator(_iso_text)]
IsoAwareDatetime = Annotated[AwareDatetime, BeforeValidator(_iso_text)]


class StrictInput(BaseModel):
    """Request bodies refuse unknown fields, so a misspelt field is named, not ignored."""

    model_config = ConfigDict(extra="forbid", str_strip_whitespace=True)


def refuse_null(*fields: str) -> Any:
    """Validator for update bodies: these fields may be left out, but not set to null."""

    def check(cls: type, value: object) -> object:
        if value is None:
            raise ValueError("may be left out but not set to null")
        return value

    return field_validator(*fields)(check)


class Row(BaseModel):
    model_config = ConfigDict(from_attributes=True)


class PageParams(BaseModel):
    """``limit`` and ``offset`` query parameters of every list."""

    limit: int = Field(100, ge=1, le=MAX_PAGE)
    offset: int = Field(0, ge=0)


class Page(BaseModel, Generic[T]):
    items: list[T]
    total: int
    limit: int
    offset: int

    @classmethod
    def of(cls, items: list[T], total: int, params: PageParams) -> Page[T]:
        return cls(items=items, total=total, limit=params.limit, offset=params.offset)


class Deleted(BaseModel):
    id: int
    deleted: bool = True


# ------------------------------------------------------------------------ engine types


class LimitLevels(StrictInput):
    """Amber and red levels of one limit; ``unit``, when sent, must be the limit's own."""

    amber: float = Field(allow_inf_nan=False)
    red: float = Field(allow_inf_nan=False)
    unit: str | None = None


class EngineTypeLimits(StrictInput):
    """Levels an engine type overrides; a limit left out keeps its current levels.

    health_change [%] and thrust_deficit [%] and rate_of_change [%/100 records]: worse above,
    amber below red. egt_margin [degC]: worse below, amber above red."""

    health_change: LimitLevels | None = None
    egt_margin: LimitLevels | None = None
    thrust_deficit: LimitLevels | None = None
    rate_of_change: LimitLevels | None = None
    egt_redline_c: float | None = Field(None, gt=0, lt=2000, allow_inf_nan=False)


class EngineTypeCreate(StrictInput):
    name: str = Field(min_length=1, max_length=100)
    description: str = Field("", max_length=2000)
    limits: EngineTypeLimits | None = None


class EngineTypeUpdate(StrictInput):
    name: str | None = Field(None, min_length=1, max_length=100)
    description: str | None = Field(None, max_length=2000)
    limits: EngineTypeLimits | None = None

    _no_null = refuse_null("name", "description", "limits")


class EngineTypeOut(Row):
    id: int
    name: str
    description: str
    created_at: AwareDatetime
    limits: dict[str, Any] = Field(
        validation_alias="effective_limits",
        description="every limit with unit, worse direction, amber and red; egt_redline_c",
    )


class SignalOut(BaseModel):
    name: str
    unit: str
    quantity: str = Field(description="what the unit measures (temperature, pressure ...); "
                          "empty for a unit fleethealth does not convert")


class ParameterSetOut(BaseModel):
    """The columns an engine type's snapshots carry, read from its models."""

    engine_type_id: int
    engine_type: str
    from_models: bool = Field(
        description="false: no model of the type declares a signal yet, and the built-in "
        "engine's catalogue stands in")
    signals: list[SignalOut] = Field(description="inputs and sensors, in the model files' "
                                     "names and units")
    scheduled_on: list[str] = Field(description="operating-condition columns every row needs")
    phase_required: bool


# ---------------------------------------------------------------------------- aircraft


class AircraftCreate(StrictInput):
    tail: Tail
    aircraft_type: str | None = Field(None, max_length=64)
    engine_positions: int = Field(2, ge=1, le=4)


class AircraftUpdate(StrictInput):
    tail: Tail | None = None
    aircraft_type: str | None = Field(None, max_length=64)
    engine_positions: int | None = Field(None, ge=1, le=4)

    _no_null = refuse_null("tail", "engine_positions")


class AircraftOut(Row):
    id: int
    tail: str
    aircraft_type: str | None
    engine_positions: int
    created_at: AwareDatetime


# ----------------------------------------------------------------------------- engines


class EngineCreate(StrictInput):
    esn: Esn
    engine_type_id: int


class EngineUpdate(StrictInput):
    esn: Esn | None = None
    engine_type_id: int | None = None

    _no_null = refuse_null("esn", "engine_type_id")


class EngineOut(Row):
    id: int
    esn: str
    engine_type_id: int
    created_at: AwareDatetime
    tail: str | None = Field(None, description="the tail it is installed on now (null: none)")
    position: int | None = Field(None, description="its position on that tail")


# ----------------------------------------------------------------------- installations


class InstallationCreate(StrictInput):
    engine_id: int
    aircraft_id: int
    position: Position
    installed_at: AwareDatetime
    removed_at: AwareDatetime | None = None


class InstallationUpdate(StrictInput):
    """Fields sent are changed; ``removed_at: null`` re-opens an installation."""

    position: Position | None = None
    installed_at: AwareDatetime | None = None
    removed_at: AwareDatetime | None = None

    _no_null = refuse_null("installed_at", "position")


class InstallationOut(Row):
    id: int
    engine_id: int
    esn: str
    aircraft_id: int
    tail: str
    position: int
    installed_at: AwareDatetime
    removed_at: AwareDatetime | None

    @classmethod
    def of(cls, row: Any) -> InstallationOut:
        """From an installation row with its engine and aircraft."""
        return cls(
            id=row.id,
            engine_id=row.engine_id,
            esn=row.engine.esn,
            aircraft_id=row.aircraft_id,
            tail=row.aircraft.tail,
            position=row.position,
            installed_at=row.installed_at,
            removed_at=row.removed_at,
        )


class PositionEngine(BaseModel):
    """Which engine sat at one position of a tail at a time (null: none installed)."""

    position: int
    engine: EngineOut | None
    installation_id: int | None


# ----------------------------------------------------------------- maintenance actions


class MaintenanceCreate(StrictInput):
    engine_id: int
    kind: MaintenanceKind
    performed_at: AwareDatetime
    notes: str = Field("", max_length=10_000)


class MaintenanceUpdate(StrictInput):
    kind: MaintenanceKind | None = None
    performed_at: AwareDatetime | None = None
    notes: str | None = Field(None, max_length=10_000)

    _no_null = refuse_null("kind", "performed_at", "notes")


class MaintenanceOut(Row):
    id: int
    engine_id: int
    kind: str
    performed_at: AwareDatetime
    notes: str
    created_at: AwareDatetime


# ---------------------------------------------------------------------------- API keys


class ApiKeyCreate(StrictInput):
    name: str = Field(min_length=1, max_length=200)
    role: Role


class ApiKeyOut(Row):
    id: int
    name: str
    prefix: str
    role: str
    created_at: AwareDatetime
    revoked_at: AwareDatetime | None


class ApiKeyCreated(ApiKeyOut):
    key: str = Field(description="the key itself; shown only in this response")


# ---------------------------------------------------------------------------- maintenance recovery


class SeriesRecoveryOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    group: Literal["health", "performance"]
    name: str
    unit: str
    before: float = Field(description="mean of the records before the action")
    after: float = Field(description="mean of the settled records after the action")
    change: float = Field(description="after - before: positive is a recovery")
    standard_error: float | None = Field(description="of the change, from the records' scatter")


class MaintenanceRecoveryOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    maintenance_action_id: int
    engine_id: int
    kind: str
    performed_at: AwareDatetime
    design_id: int | None
    n_before: int = Field(description="records averaged before the action")
    n_after: int = Field(description="records averaged after it")
    series: list[SeriesRecoveryOut]
    note: str | None = Field(description="why nothing is measured, when so")
