"""The fleet: aircraft (tail), engines (ESN), installations, maintenance actions.

Trends belong to the engine serial number; data arrives per tail and position. An
installation says which engine sat at a tail position over ``[installed_at, removed_at)``
(``removed_at`` NULL: still installed). Installations never overlap for one engine nor for
one tail position: the service checks it under a row lock and answers 409, and on
PostgreSQL migration 0002 adds exclusion constraints (btree_gist) that hold for any writer.
"""

from __future__ import annotations

from datetime import datetime

from sqlalchemy import CheckConstraint, ForeignKey, Index, String, Text, UniqueConstraint
from sqlalchemy.orm import Mapped, mapped_column, relationship

from app.models.base import Base, UTCDateTime, utcnow
from app.models.designs import EngineType

MAX_POSITIONS = 4
# Maintenance that restarts the engine's detection baseline; a borescope finding is an
# inspection's record (notes), which changes nothing on the engine.
BASELINE_RESET_KINDS = ("water_wash", "module_change", "shop_visit")
MAINTENANCE_KINDS = (*BASELINE_RESET_KINDS, "borescope_finding")


class Aircraft(Base):
    __tablename__ = "aircraft"
    __table_args__ = (
        UniqueConstraint("operator_id", "tail"),
        CheckConstraint(f"engine_positions BETWEEN 1 AND {MAX_POSITIONS}", name="positions"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    operator_id: Mapped[int] = mapped_column(
        ForeignKey("operators.id", ondelete="CASCADE"), index=True
    )
    tail: Mapped[str] = mapped_column(String(32))
    aircraft_type: Mapped[str | None] = mapped_column(String(64), default=None)
    engine_positions: Mapped[int] = mapped_column(default=2)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime(), default=utcnow)


class Engine(Base):
    __tablename__ = "engines"
    __table_args__ = (UniqueConstraint("operator_id", "esn"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    operator_id: Mapped[int] = mapped_column(
        ForeignKey("operators.id", ondelete="CASCADE"), index=True
    )
    esn: Mapped[str] = mapped_column(String(64))
    engine_type_id: Mapped[int] = mapped_column(
        ForeignKey("engine_types.id", ondelete="RESTRICT"), index=True
    )
    created_at: Mapped[datetime] = mapped_column(UTCDateTime(), default=utcnow)

    engine_type: Mapped[EngineType] = relationship(lazy="joined")


class Installation(Base):
    """Engine ``engine_id`` at ``aircraft_id`` position ``position`` over [installed_at,
    removed_at)."""

    __tablename__ = "installations"
    __table_args__ = (
        CheckConstraint(f"position BETWEEN 1 AND {MAX_POSITIONS}", name="position"),
        CheckConstraint("removed_at IS NULL OR removed_at > installed_at", name="period"),
        Index("ix_installations_aircraft_position", "aircraft_id", "position", "installed_at"),
        Index("ix_installations_engine_installed", "engine_id", "installed_at"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    operator_id: Mapped[int] = mapped_column(
        ForeignKey("operators.id", ondelete="CASCADE"), index=True
    )
    engine_id: Mapped[int] = mapped_column(ForeignKey("engines.id", ondelete="RESTRICT"))
    aircraft_id: Mapped[int] = mapped_column(ForeignKey("aircraft.id", ondelete="RESTRICT"))
    position: Mapped[int]
    installed_at: Mapped[datetime] = mapped_column(UTCDateTime())
    removed_at: Mapped[datetime | None] = mapped_column(UTCDateTime(), default=None)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime(), default=utcnow)

    engine: Mapped[Engine] = relationship(lazy="joined")
    aircraft: Mapped[Aircraft] = relationship(lazy="joined")


class MaintenanceAction(Base):
    """A water wash, module change, shop visit (the detection baseline restarts after these)
    or a borescope finding (notes only)."""

    __tablename__ = "maintenance_actions"
    __table_args__ = (
        CheckConstraint(
            "kind IN (" + ", ".join(f"'{k}'" for k in MAINTENANCE_KINDS) + ")", name="kind"
        ),
        Index("ix_maintenance_actions_engine_performed", "engine_id", "performed_at"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    operator_id: Mapped[int] = mapped_column(
        ForeignKey("operators.id", ondelete="CASCADE"), index=True
    )
    engine_id: Mapped[int] = mapped_column(ForeignKey("engines.id", ondelete="RESTRICT"))
    kind: Mapped[str] = mapped_column(String(32))
    performed_at: Mapped[datetime] = mapped_column(UTCDateTime())
    notes: Mapped[str] = mapped_column(Text, default="")
    created_at: Mapped[datetime] = mapped_column(UTCDateTime(), default=utcnow)
