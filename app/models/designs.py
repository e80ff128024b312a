"""Engine types, engine models and estimator designs.

An engine model is a ``fleethealth.linear-model/1`` dict (imported, or built from the built-in
engine), versioned per (engine type, name) and immutable: a change is a new version, and a
model that a design uses can no longer be deleted (``locked_at``). An estimator design is the
``fleethealth.design/1`` result of the estimation core's design step for a spec, stored with its
analytic errors; at most one design per engine type is active (a partial unique index).
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

from sqlalchemy import (
    JSON,
    CheckConstraint,
    ForeignKey,
    Index,
    String,
    Text,
    UniqueConstraint,
    text,
)
from sqlalchemy.dialects.postgresql import JSONB
from sqlalchemy.orm import Mapped, mapped_column, relationship

from app.models.base import Base, UTCDateTime, utcnow

MODEL_SOURCES = ("imported", "builtin")
DESIGN_STATUSES = ("pending", "ready", "failed")

# JSONB on PostgreSQL (compact, indexable), JSON text on SQLite.
JSONDocument = JSON().with_variant(JSONB(), "postgresql")


# Limits of an engine's state, per engine type: name -> (unit, worse direction, amber, red).
# "above": a value above a level is worse (amber < red); "below": a margin, worse below
# (amber > red). A type stores only the levels it overrides (``engine_types.limits``, NULL: all
# defaults). The defaults are the built-in engine's, set where its simulator's mean
# deterioration (estimation.engine.fleet.DETERIORATION_RATES) takes an engine in about 10,000
# cycles (red) and 7,000-8,500 cycles (amber): the largest health parameter change then is
# 7.5 % (5 % at 6,700 cycles) and the take-off EGT 202 K above new (see the redline).
# Thrust deficit and rate of change have no such anchor: 5 % and 10 % of thrust below the
# baseline at the same condition; a health parameter moving 3 % (6 %) in 100 records, which
# gradual wear does not do (0.04 %) and an abrupt fault does.
LIMIT_SPECS: dict[str, tuple[str, str, float, float]] = {
    "health_change": ("%", "above", 5.0, 8.0),
    "egt_margin": ("degC", "below", 25.0, 0.0),
    "thrust_deficit": ("%", "above", 5.0, 10.0),
    "rate_of_change": ("%/100 records", "above", 3.0, 6.0),
}
# EGT redline [degC] of the built-in engine's T48 (its EGT station). Its nominal take-off EGT on
# an ISA+15 K day is 903 degC (schedule); at the simulator's mean deterioration it rises 94 K in
# 5,000 cycles and 202 K in 10,000, so a redline of 1100 degC leaves a new engine ~197 degC of
# margin and none after ~10,000 cycles. (The model's EGT is about twice as sensitive to
# deterioration as a real engine's, hence the large margin.)
DEFAULT_EGT_REDLINE_C = 1100.0


class EngineType(Base):
    __tablename__ = "engine_types"
    __table_args__ = (UniqueConstraint("operator_id", "name"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    operator_id: Mapped[int] = mapped_column(
        ForeignKey("operators.id", ondelete="CASCADE"), index=True
    )
    name: Mapped[str] = mapped_column(String(100))
    description: Mapped[str] = mapped_column(Text, default="")
    created_at: Mapped[datetime] = mapped_column(UTCDateTime(), default=utcnow)
    # Overrides of LIMIT_SPECS' levels ({"egt_margin": {"amber": 20, "red": 5}, ...}) and
    # "egt_redline_c"; NULL: the defaults (migration 0011).
    limits: Mapped[dict[str, Any] | None] = mapped_column(JSONDocument, default=None)

    @property
    def effective_limits(self) -> dict[str, Any]:
        """Every limit with its unit and levels, the stored overrides over the defaults."""
        return effective_limits(self.limits)


def effective_limits(stored: dict[str, Any] | None) -> dict[str, Any]:
    """``LIMIT_SPECS`` with a type's stored overrides: name -> unit, worse, amber, red; and
    egt_redline_c."""
    stored = stored or {}
    out: dict[str, Any] = {}
    for name, (unit, worse, amber, red) in LIMIT_SPECS.items():
        levels = stored.get(name) or {}
        out[name] = {"unit": unit, "worse": worse, "amber": float(levels.get("amber", amber)),
                     "red": float(levels.get("red", red))}
    out["egt_redline_c"] = float(stored.get("egt_redline_c", DEFAULT_EGT_REDLINE_C))
    return out


class EngineModel(Base):
    __tablename__ = "engine_models"
    __table_args__ = (
        UniqueConstraint("engine_type_id", "name", "version"),
        CheckConstraint(
            "source IN (" + ", ".join(f"'{s}'" for s in MODEL_SOURCES) + ")", name="source"
        ),
        CheckConstraint("version >= 1", name="version"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    operator_id: Mapped[int] = mapped_column(
        ForeignKey("operators.id", ondelete="CASCADE"), index=True
    )
    engine_type_id: Mapped[int] = mapped_column(
        ForeignKey("engine_types.id", ondelete="RESTRICT"), index=True
    )
    name: Mapped[str] = mapped_column(String(100))
    version: Mapped[int]
    source: Mapped[str] = mapped_column(String(16))
    format: Mapped[str] = mapped_column(String(64))
    content: Mapped[dict[str, Any]] = mapped_column(JSONDocument)
    checksum: Mapped[str] = mapped_column(String(64))
    dt: Mapped[float]
    n_states: Mapped[int]
    sensor_names: Mapped[list[str]] = mapped_column(JSONDocument)
    health_names: Mapped[list[str]] = mapped_column(JSONDocument)
    aux_names: Mapped[list[str]] = mapped_column(JSONDocument)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime(), default=utcnow)
    # Set when a design first uses the model; from then on it may not be deleted.
    locked_at: Mapped[datetime | None] = mapped_column(UTCDateTime(), default=None)

    engine_type: Mapped[EngineType] = relationship(lazy="joined")

    @property
    def signals(self) -> dict[str, list[dict[str, str]]]:
        """The model's signals by group (states, inputs, health, sensors, aux), each name with
        its unit; of a model schedule, its design-point model's (all its models share them)."""
        content: Any = self.content or {}
        models = content.get("models")
        if isinstance(models, list) and models:
            point = content.get("design_point", 0)
            content = models[point if isinstance(point, int) and 0 <= point < len(models) else 0]
        block = content.get("signals") if isinstance(content, dict) else None
        block = block if isinstance(block, dict) else {}
        return {group: [{"name": str(s.get("name", "")), "unit": str(s.get("unit", ""))}
                        for s in block.get(group) or [] if isinstance(s, dict)]
                for group in ("states", "inputs", "health", "sensors", "aux")}


class EstimatorDesign(Base):
    __tablename__ = "estimator_designs"
    __table_args__ = (
        CheckConstraint(
            "status IN (" + ", ".join(f"'{s}'" for s in DESIGN_STATUSES) + ")", name="status"
        ),
        CheckConstraint("NOT active OR status = 'ready'", name="active_ready"),
        # One active design per engine type, on both backends.
        Index(
            "uq_estimator_designs_active_engine_type",
            "engine_type_id",
            unique=True,
            sqlite_where=text("active"),
            postgresql_where=text("active"),
        ),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    operator_id: Mapped[int] = mapped_column(
        ForeignKey("operators.id", ondelete="CASCADE"), index=True
    )
    engine_type_id: Mapped[int] = mapped_column(
        ForeignKey("engine_types.id", ondelete="RESTRICT"), index=True
    )
    engine_model_id: Mapped[int] = mapped_column(
        ForeignKey("engine_models.id", ondelete="RESTRICT"), index=True
    )
    name: Mapped[str] = mapped_column(String(100))
    spec: Mapped[dict[str, Any]] = mapped_column(JSONDocument)
    status: Mapped[str] = mapped_column(String(16), default="pending")
    # The fleethealth.design/1 dict and its analytic errors (docs/math.md section 3), when ready.
    result: Mapped[dict[str, Any] | None] = mapped_column(JSONDocument, default=None)
    analytic_errors: Mapped[dict[str, Any] | None] = mapped_column(JSONDocument, default=None)
    ssee_health: Mapped[float | None] = mapped_column(default=None)
    ssee_aux: Mapped[float | None] = mapped_column(default=None)
    failure: Mapped[str | None] = mapped_column(Text, default=None)
    active: Mapped[bool] = mapped_column(default=False)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime(), default=utcnow)
    completed_at: Mapped[datetime | None] = mapped_column(UTCDateTime(), default=None)
    activated_at: Mapped[datetime | None] = mapped_column(UTCDateTime(), default=None)

    engine_type: Mapped[EngineType] = relationship(lazy="joined")
    engine_model: Mapped[EngineModel] = relationship(lazy="raise")
