"""Estimates, filter states and events: what the estimation pipeline derives from snapshots.

Storage of estimates. A trend query reads thousands of rows of one engine and design, so each
row keeps its numbers in one packed little-endian float32 blob (``packed``) and the names that
say which number is which live once per (engine, design) on ``filter_states.layout`` (they come
from the design). Decoding 10,000 rows is then one ``b"".join`` and one ``numpy.frombuffer``
with no per-value parsing, on SQLite and PostgreSQL alike; the same query over JSON arrays parses
every number as text. float32 keeps 7 significant digits, far below the 1-sigma bands it carries,
and the pipeline is deterministic, so a re-run writes byte-identical blobs.

Rows are derived data: they are deleted and rewritten when a late record re-runs an engine, so
every table here cascades from the design it was computed under (``estimates`` keeps only that
foreign key; the snapshot, engine and operator are the pipeline's to get right, see migration
0007).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import datetime
from typing import Any

import numpy as np
from sqlalchemy import (
    CheckConstraint,
    Float,
    ForeignKey,
    Index,
    Integer,
    LargeBinary,
    String,
    Text,
    UniqueConstraint,
)
from sqlalchemy.orm import Mapped, mapped_column, relationship

from app.models.base import Base, UTCDateTime, utcnow
from app.models.designs import JSONDocument

EVENT_KINDS = ("shift", "isolated_fault", "wear")
EVENT_STATUSES = ("open", "acknowledged", "closed")
# What an event's history records: who assigned, acknowledged, commented on or closed it.
EVENT_ACTIONS = ("assigned", "unassigned", "acknowledged", "commented", "closed")
# The severity an open event gives its engine (kinds not named: amber).
EVENT_LEVEL = {"isolated_fault": "red", "shift": "amber"}


class Estimate(Base):
    """One snapshot's estimate under one design.

    ``packed`` holds, in the order of ``filter_states.layout["blocks"]``: tuners q_hat and their
    1-sigma, health parameters h_hat and 1-sigma (percent), auxiliary outputs z_hat and 1-sigma
    (thrust deficit, stall margins), sensor residuals (percent of trim) and WSSR per library fault.
    ``seq`` numbers the engine's records under the design in time order (0, 1, ...): the
    "cycles" axis of a trend, and the place a re-run starts from.
    """

    __tablename__ = "estimates"

    # Derived rows written by COPY, one per snapshot: the key (engine, design, seq) is the only
    # index and there is no foreign key (migration 0008: each costs a lookup per COPYed row).
    # operator_id and engine_id are copied by the pipeline from the snapshots it estimates;
    # snapshots (hence their engines and operators) are never deleted while they have rows, and
    # a design with estimates is never deleted. The snapshot is (engine_id, recorded_at).
    engine_id: Mapped[int] = mapped_column(Integer, primary_key=True)
    design_id: Mapped[int] = mapped_column(Integer, primary_key=True)
    seq: Mapped[int] = mapped_column(Integer, primary_key=True)
    operator_id: Mapped[int] = mapped_column(Integer)
    recorded_at: Mapped[datetime] = mapped_column(UTCDateTime())
    phase: Mapped[str] = mapped_column(String(16))
    packed: Mapped[bytes] = mapped_column(LargeBinary)


class FilterState(Base):
    """The pipeline's state for one engine and design after its last processed record.

    ``state`` is the serialised snapshot filter plus the shift detector (baseline, CUSUM);
    ``layout`` names the numbers packed in each estimate's blob; ``n_records`` is the next
    ``seq``; ``last_recorded_at`` is the time of the last record processed.
    """

    __tablename__ = "filter_states"
    __table_args__ = (UniqueConstraint("engine_id", "design_id"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    operator_id: Mapped[int] = mapped_column(
        ForeignKey("operators.id", ondelete="CASCADE"), index=True
    )
    engine_id: Mapped[int] = mapped_column(ForeignKey("engines.id", ondelete="CASCADE"))
    design_id: Mapped[int] = mapped_column(
        ForeignKey("estimator_designs.id", ondelete="CASCADE"), index=True
    )
    layout: Mapped[dict[str, Any]] = mapped_column(JSONDocument)
    state: Mapped[dict[str, Any]] = mapped_column(JSONDocument)
    n_records: Mapped[int] = mapped_column(Integer, default=0)
    last_recorded_at: Mapped[datetime | None] = mapped_column(UTCDateTime(), default=None)
    updated_at: Mapped[datetime] = mapped_column(UTCDateTime(), default=utcnow)


class DeteriorationBucket(Base):
    """One engine's estimates under one design summed over a week or a calendar month: what the
    fleet deterioration reads instead of every estimate.

    ``sums`` holds, as little-endian float64, the sums of the health and auxiliary values
    (``layout`` blocks h then z) over the ``n`` estimates whose record falls in the period that
    starts at ``start`` (weeks start on Monday, months on the 1st, 00:00 UTC). The estimation
    pipeline rewrites an engine's periods from the first record it (re)computes on, in the
    transaction that stores the estimates (``app.services.snapshots.buckets``).
    """

    __tablename__ = "deterioration_buckets"
    __table_args__ = (CheckConstraint("period IN ('week', 'month')", name="period"),)

    design_id: Mapped[int] = mapped_column(
        ForeignKey("estimator_designs.id", ondelete="CASCADE"), primary_key=True
    )
    period: Mapped[str] = mapped_column(String(8), primary_key=True)
    engine_id: Mapped[int] = mapped_column(Integer, primary_key=True)
    start: Mapped[datetime] = mapped_column(UTCDateTime(), primary_key=True)
    operator_id: Mapped[int] = mapped_column(Integer)
    n: Mapped[int] = mapped_column(Integer)
    sums: Mapped[bytes] = mapped_column(LargeBinary)


class FleetPeriod(Base):
    """A design's fleet over one week or month: how many engines have estimates in it, and the
    sums over those engines of their period means and of the squares of those means (little-
    endian float64, health then auxiliary values), so that the fleet deterioration reads one
    row per period, whatever the fleet's size. Kept by the pipeline with the engines' periods
    (``DeteriorationBucket``): each rewrite of an engine's period takes its old mean out and
    puts its new one in."""

    __tablename__ = "fleet_periods"
    __table_args__ = (CheckConstraint("period IN ('week', 'month')", name="period"),)

    design_id: Mapped[int] = mapped_column(
        ForeignKey("estimator_designs.id", ondelete="CASCADE"), primary_key=True
    )
    period: Mapped[str] = mapped_column(String(8), primary_key=True)
    start: Mapped[datetime] = mapped_column(UTCDateTime(), primary_key=True)
    operator_id: Mapped[int] = mapped_column(Integer)
    n_engines: Mapped[int] = mapped_column(Integer)
    sums: Mapped[bytes] = mapped_column(LargeBinary)
    squares: Mapped[bytes] = mapped_column(LargeBinary)


class EstimationBacklog(Base):
    """A mark on an engine whose snapshots its estimates do not cover yet: the estimation job's
    to-do list.

    Whatever stores snapshots, or changes what an engine's estimates depend on, adds a mark in
    its own transaction (``backlog.mark``); the estimation job deletes exactly the marks it
    read, in the transaction that stores the engine's estimates, so a mark added meanwhile
    waits for its next pass. Finding the work is a read of this table, whatever the length of
    the engines' histories.

    ``earliest``: the earliest record the mark concerns (a re-run starts before it when it is
    older than the last record processed); None: continue from the filter state. ``rows``:
    the records the mark's upload stored (None: unknown), which tells the job when records an
    upload kept in memory are all of them.
    """

    __tablename__ = "estimation_backlog"

    id: Mapped[int] = mapped_column(primary_key=True)
    operator_id: Mapped[int] = mapped_column(
        ForeignKey("operators.id", ondelete="CASCADE"), index=True
    )
    engine_id: Mapped[int] = mapped_column(
        ForeignKey("engines.id", ondelete="CASCADE"), index=True
    )
    earliest: Mapped[datetime | None] = mapped_column(UTCDateTime(), default=None)
    rows: Mapped[int | None] = mapped_column(Integer, default=None)


class FilterCheckpoint(Base):
    """The pipeline state after ``seq`` records (every N records): where a re-run restarts.

    A late record at time t restarts from the newest checkpoint whose last record is before t,
    so a re-run costs at most N records plus the records after t.
    """

    __tablename__ = "filter_checkpoints"
    __table_args__ = (UniqueConstraint("engine_id", "design_id", "seq"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    engine_id: Mapped[int] = mapped_column(ForeignKey("engines.id", ondelete="CASCADE"))
    design_id: Mapped[int] = mapped_column(
        ForeignKey("estimator_designs.id", ondelete="CASCADE"), index=True
    )
    seq: Mapped[int] = mapped_column(Integer)
    last_recorded_at: Mapped[datetime] = mapped_column(UTCDateTime())
    state: Mapped[dict[str, Any]] = mapped_column(JSONDocument)


class Event(Base):
    """A detected shift of an engine's tuners, isolated to a library fault when one fits.

    kind ``isolated_fault``: the smallest WSSR is consistent with its fault (``fault`` and
    ``magnitude``, 1.0 = the library's nominal shift); kind ``shift``: no library fault explains
    it; kind ``wear``: the wear detector's alert on the change accumulated since its baseline
    (``estimation.wear``; ``fault``, ``magnitude`` attributed, ``shift["wear"]`` the alert's
    kind, CUSUM and threshold). ``wssr`` maps every hypothesis to its WSSR; ``shift`` maps tuner
    names to the change against the baseline; ``seq`` is the record at which the detector
    raised the alarm (a record may carry one event per kind).
    """

    __tablename__ = "events"
    __table_args__ = (
        CheckConstraint(
            "kind IN (" + ", ".join(f"'{k}'" for k in EVENT_KINDS) + ")", name="kind"
        ),
        CheckConstraint(
            "status IN (" + ", ".join(f"'{s}'" for s in EVENT_STATUSES) + ")", name="status"
        ),
        UniqueConstraint("engine_id", "design_id", "seq", "kind"),
        Index("ix_events_operator_status_detected", "operator_id", "status", "detected_at"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    operator_id: Mapped[int] = mapped_column(ForeignKey("operators.id", ondelete="CASCADE"))
    engine_id: Mapped[int] = mapped_column(ForeignKey("engines.id", ondelete="CASCADE"))
    design_id: Mapped[int] = mapped_column(
        ForeignKey("estimator_designs.id", ondelete="CASCADE"), index=True
    )
    seq: Mapped[int] = mapped_column(Integer)
    detected_at: Mapped[datetime] = mapped_column(UTCDateTime())
    kind: Mapped[str] = mapped_column(String(16))
    fault: Mapped[str | None] = mapped_column(String(64), default=None)
    magnitude: Mapped[float | None] = mapped_column(Float, default=None)
    statistic: Mapped[float] = mapped_column(Float)
    wssr: Mapped[dict[str, Any]] = mapped_column(JSONDocument)
    shift: Mapped[dict[str, Any]] = mapped_column(JSONDocument)
    status: Mapped[str] = mapped_column(String(16), default="open")
    acknowledged_at: Mapped[datetime | None] = mapped_column(UTCDateTime(), default=None)
    acknowledged_by: Mapped[int | None] = mapped_column(
        ForeignKey("api_keys.id", ondelete="SET NULL"), default=None
    )
    closed_at: Mapped[datetime | None] = mapped_column(UTCDateTime(), default=None)
    closed_by: Mapped[int | None] = mapped_column(
        ForeignKey("api_keys.id", ondelete="SET NULL"), default=None
    )
    # The person (an analyst or admin API key of the operator) the alert is assigned to.
    assignee_key_id: Mapped[int | None] = mapped_column(
        ForeignKey("api_keys.id", ondelete="SET NULL"), default=None
    )
    created_at: Mapped[datetime] = mapped_column(UTCDateTime(), default=utcnow)

    comments: Mapped[list[EventComment]] = relationship(
        back_populates="event", cascade="all, delete-orphan", order_by="EventComment.id"
    )
    history: Mapped[list[EventHistory]] = relationship(
        back_populates="event", cascade="all, delete-orphan", order_by="EventHistory.id"
    )


class EventComment(Base):
    __tablename__ = "event_comments"

    id: Mapped[int] = mapped_column(primary_key=True)
    event_id: Mapped[int] = mapped_column(
        ForeignKey("events.id", ondelete="CASCADE"), index=True
    )
    author_key_id: Mapped[int | None] = mapped_column(
        ForeignKey("api_keys.id", ondelete="SET NULL"), default=None
    )
    author: Mapped[str] = mapped_column(String(200))
    body: Mapped[str] = mapped_column(Text)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime(), default=utcnow)

    event: Mapped[Event] = relationship(back_populates="comments")


class EventHistory(Base):
    """One step of an alert's handling: who (``actor``, the key's name at the time) did what
    (``action``) and when; ``reason`` is the reason given to acknowledge or close, or the
    comment's text; ``assignee`` the name of the key an assignment went to."""

    __tablename__ = "event_history"
    __table_args__ = (
        CheckConstraint(
            "action IN (" + ", ".join(f"'{a}'" for a in EVENT_ACTIONS) + ")", name="action"
        ),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    event_id: Mapped[int] = mapped_column(
        ForeignKey("events.id", ondelete="CASCADE"), index=True
    )
    action: Mapped[str] = mapped_column(String(16))
    actor_key_id: Mapped[int | None] = mapped_column(
        ForeignKey("api_keys.id", ondelete="SET NULL"), default=None
    )
    actor: Mapped[str] = mapped_column(String(200))
    assignee_key_id: Mapped[int | None] = mapped_column(
        ForeignKey("api_keys.id", ondelete="SET NULL"), default=None
    )
    assignee: Mapped[str | None] = mapped_column(String(200), default=None)
    reason: Mapped[str | None] = mapped_column(Text, default=None)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime(), default=utcnow)

    event: Mapped[Event] = relationship(back_populates="history")


# The blocks of an estimate's ``packed`` blob, in order: (block, names group).
BLOCKS = (
    ("q", "tuners"),
    ("q_sigma", "tuners"),
    ("h", "health"),
    ("h_sigma", "health"),
    ("z", "aux"),
    ("z_sigma", "aux"),
    ("residual", "sensors"),
    ("wssr", "faults"),
)
VALUE_DTYPE = "<f4"


@dataclass(frozen=True)
class EstimateLayout:
    """Names of the numbers in an estimate's blob (stored as ``filter_states.layout``).

    ``units`` maps group -> list of units, aligned with the group's names.
    """

    tuners: tuple[str, ...]
    health: tuple[str, ...]
    aux: tuple[str, ...]
    sensors: tuple[str, ...]
    faults: tuple[str, ...]
    units: dict[str, list[str]] = field(default_factory=dict)

    def names(self, group: str) -> tuple[str, ...]:
        return tuple(getattr(self, group))

    @property
    def width(self) -> int:
        return sum(len(self.names(group)) for _block, group in BLOCKS)

    def slices(self) -> dict[str, slice]:
        cached = self.__dict__.get("_slices")
        if cached is not None:
            return dict(cached)
        out, start = {}, 0
        for block, group in BLOCKS:
            n = len(self.names(group))
            out[block] = slice(start, start + n)
            start += n
        self.__dict__["_slices"] = out  # frozen dataclass: cache through __dict__
        return dict(out)

    def pack(self, rows: np.ndarray) -> list[bytes]:
        """(n, width) numbers -> n blobs."""
        rows = np.ascontiguousarray(rows, dtype=VALUE_DTYPE)
        if rows.ndim != 2 or rows.shape[1] != self.width:
            raise ValueError(f"estimate rows: expected (n, {self.width}) but found {rows.shape}")
        return [row.tobytes() for row in rows]

    def unpack(self, blobs: list[bytes]) -> np.ndarray:
        """n blobs -> (n, width) float64 numbers."""
        flat = np.frombuffer(b"".join(blobs), dtype=VALUE_DTYPE)
        return flat.reshape(len(blobs), self.width).astype(np.float64)

    def to_dict(self) -> dict[str, Any]:
        return {
            "tuners": list(self.tuners),
            "health": list(self.health),
            "aux": list(self.aux),
            "sensors": list(self.sensors),
            "faults": list(self.faults),
            "units": {k: list(v) for k, v in self.units.items()},
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> EstimateLayout:
        return cls(
            tuners=tuple(d["tuners"]),
            health=tuple(d["health"]),
            aux=tuple(d["aux"]),
            sensors=tuple(d["sensors"]),
            faults=tuple(d["faults"]),
            units={k: list(v) for k, v in d.get("units", {}).items()},
        )
