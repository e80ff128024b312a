"""Estimates, filter states and events: what the estimation pipeline derives from snapshots.

Storage of estimates. A trend query reads thousands of rows of one engine and design, so each
row keeps its numbers in one fixed-width bit-packed blob (``packed``) and the names that say
which number is which live once per (engine, design) on ``filter_states.layout`` (they come from
the design). Decoding 10,000 rows is one ``b"".join``, one ``numpy.unpackbits`` and a few
vectorised operations, on SQLite and PostgreSQL alike. The blob keeps what cannot be derived,
each number at the precision the pages need (``EstimateLayout.encode``, docs/data-flow.md
"Storage of estimates"): about 58 bytes for the built-in engine's 71 numbers, where float32
took 284, so that a record costs under 150 bytes on PostgreSQL with its key and index. The
pipeline is deterministic, so a re-run writes byte-identical blobs.

Rows are derived data: they are deleted and rewritten when a late record re-runs an engine, so
every table here cascades from the design it was computed under (``estimates`` keeps only that
foreign key; the snapshot, engine and operator are the pipeline's to get right, see migration
0007).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any, NamedTuple

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
from app.signals import PHASES

EVENT_KINDS = ("shift", "isolated_fault", "wear")
EVENT_STATUSES = ("open", "acknowledged", "closed")
# What an event's history records: who assigned, acknowledged, commented on or closed it.
EVENT_ACTIONS = ("assigned", "unassigned", "acknowledged", "commented", "closed")
# The severity an open event gives its engine (kinds not named: amber).
EVENT_LEVEL = {"isolated_fault": "red", "shift": "amber"}


class Estimate(Base):
    """One snapshot's estimate under one design.

    ``packed`` holds the record's phase and numbers as ``EstimateLayout.encode`` packs them:
    tuners q_hat, auxiliary outputs z_hat (thrust deficit, stall margins) and their 1-sigma,
    sensor residuals (percent of trim) and WSSR per library fault; the health parameters h_hat
    and their 1-sigma follow from the tuners (h = V*^+ q) when the layout says how
    (``health_from_tuners``), else they are stored too. ``seq`` numbers the engine's records
    under the design in time order (0, 1, ...): the "cycles" axis of a trend, and the place a
    re-run starts from.
    """

    __tablename__ = "estimates"

    # Derived rows written by COPY, one per snapshot: the key (engine, design, seq) is the only
    # index and there is no foreign key (migration 0008: each costs a lookup per COPYed row).
    # engine_id is copied by the pipeline from the snapshots it estimates; snapshots (hence
    # their engines) are never deleted while they have rows, and a design with estimates is
    # never deleted. The snapshot is (engine_id, recorded_at). Columns in this order leave no
    # alignment padding on PostgreSQL (migration 0020).
    recorded_at: Mapped[datetime] = mapped_column(UTCDateTime())
    engine_id: Mapped[int] = mapped_column(Integer, primary_key=True)
    design_id: Mapped[int] = mapped_column(Integer, primary_key=True)
    seq: Mapped[int] = mapped_column(Integer, primary_key=True)
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
    sums over those engines of their period means (``sums``: health then auxiliary values) and
    of those means' second moments (``squares``: the products of the health values, i <= j,
    the squares of the auxiliary values, then each auxiliary value times each health value;
    ``buckets.second_moments``), little-endian float64, so that the fleet deterioration reads
    one row per period, whatever the fleet's size, and can calibrate the health and auxiliary
    means and their spread. Kept by the pipeline with the
    engines' periods (``DeteriorationBucket``): each rewrite of an engine's period takes its
    old mean out and puts its new one in."""

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


class EgtWindow(Base):
    """One engine's EGT window under one design: the median dEGT [K, corrected] of its last
    ``EGT_WINDOW`` records with a T48 (None without any), what the fleet status checks the
    EGT margin against, so that it reads one row per engine instead of the window's records.

    Kept by the pipeline in the transaction that stores the engine's estimates
    (``app.services.snapshots.egt``); ``n_records`` and ``last_recorded_at`` are those of the
    filter state it was taken at and ``fingerprint`` the built-in schedule's: a window whose
    stamp differs from its filter state's is not used (the status reads that engine's records).
    """

    __tablename__ = "egt_windows"

    engine_id: Mapped[int] = mapped_column(
        ForeignKey("engines.id", ondelete="CASCADE"), primary_key=True
    )
    design_id: Mapped[int] = mapped_column(
        ForeignKey("estimator_designs.id", ondelete="CASCADE"), primary_key=True, index=True
    )
    n_records: Mapped[int] = mapped_column(Integer)
    last_recorded_at: Mapped[datetime | None] = mapped_column(UTCDateTime(), default=None)
    fingerprint: Mapped[str] = mapped_column(String(64))
    median: Mapped[float | None] = mapped_column(Float, default=None)


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


# The blocks of an estimate's numbers (``EstimateLayout.width`` columns), in order:
# (block, names group).
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
# The numbers a run computes and keeps in memory (and a stream estimate's stored blob).
VALUE_DTYPE = "<f4"

# The stored form of a snapshot estimate (``EstimateLayout.encode``). Each number is an
# unsigned code of a few bits; the codes of a record are packed little-endian bit by bit.
# The phase codes of a stored estimate: the flight phases, and "" for a record of an engine type
# whose models do not depend on the flight phase.
STORED_PHASES = (*PHASES, "")
PHASE_BITS = 2  # STORED_PHASES: four
VALUE_BITS = 12  # q, z (and h when stored): a multiple of their own 1-sigma
VALUE_STEPS_PER_SIGMA = 8  # step sigma/8: error <= sigma/16, range +-256 sigma (saturates)
SIGMA_BITS = 7  # 1-sigma: logarithmic over SIGMA_RANGE, 0 = missing
SIGMA_RANGE = (0.02, 50.0)  # percent; outside: clipped to the nearer end
RESIDUAL_BITS = 8  # sign and magnitude, logarithmic above RESIDUAL_KNEE (mu-law)
RESIDUAL_KNEE = 0.02  # percent of trim
RESIDUAL_MAX = 200.0
WSSR_BITS = 8  # logarithmic over WSSR_RANGE, 0 = missing
WSSR_RANGE = (0.01, 1.0e5)

_RESIDUAL_TOP = 2 ** (RESIDUAL_BITS - 1) - 1
_RESIDUAL_STEP = math.log1p(RESIDUAL_MAX / RESIDUAL_KNEE) / _RESIDUAL_TOP
_VALUE_TOP = 2 ** (VALUE_BITS - 1) - 1  # -2**(bits-1): missing


@dataclass(frozen=True)
class _LogCode:
    """A positive number as a code of ``bits`` bits, logarithmic over [lo, hi] (clipped to
    it); code 0 is a missing number. ``table`` decodes: table[code]."""

    bits: int
    lo: float
    hi: float
    step: float = field(init=False)
    table: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        step = math.log(self.hi / self.lo) / (2**self.bits - 2)
        codes = np.arange(2**self.bits)
        object.__setattr__(self, "step", step)
        object.__setattr__(self, "table", np.where(
            codes == 0, np.nan, self.lo * np.exp((codes - 1) * step)))

    def codes(self, value: np.ndarray) -> np.ndarray:
        x = np.asarray(value, dtype=np.float32)  # float32 logarithms: the codes are short
        with np.errstate(invalid="ignore", divide="ignore"):
            steps = np.rint(np.log(np.minimum(np.maximum(x, self.lo), self.hi) * (1.0 / self.lo))
                            * (1.0 / self.step)) + 1
        steps[~np.isfinite(x)] = 0
        return steps.astype(np.int64)


_SIGMA_CODE = _LogCode(SIGMA_BITS, *SIGMA_RANGE)
_WSSR_CODE = _LogCode(WSSR_BITS, *WSSR_RANGE)
_SIGMAS = _SIGMA_CODE.table
_WSSRS = _WSSR_CODE.table


def _value_codes(value: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Two's complement codes of value / (sigma / 8); ``sigma`` as decoded."""
    if np.isnan(sigma).any():
        sigma = np.where(np.isnan(sigma), 1.0, sigma)
    with np.errstate(invalid="ignore"):
        steps = np.rint(value * VALUE_STEPS_PER_SIGMA / sigma)
        steps = np.minimum(np.maximum(steps, -_VALUE_TOP), _VALUE_TOP)
    steps[~np.isfinite(value)] = -_VALUE_TOP - 1
    return steps.astype(np.int64) & (2**VALUE_BITS - 1)


def _fitting(codes: np.ndarray, value: np.ndarray) -> np.ndarray:
    """Sigma codes raised where a value lies beyond +-256 of its sigma: such a record shows a
    wider band rather than a clipped value (none of the built-in engine's estimates does)."""
    with np.errstate(invalid="ignore"):
        need = np.abs(value) * (VALUE_STEPS_PER_SIGMA / (_VALUE_TOP - 0.5))
        short = np.isfinite(need) & (codes > 0) & (_SIGMAS[codes] < need)
    if short.any():
        raised = np.searchsorted(_SIGMAS[1:], need[short]) + 1
        codes = codes.copy()
        codes[short] = np.minimum(raised, 2**SIGMA_BITS - 1)
    return codes


def _values(codes: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    half = _VALUE_TOP + 1
    steps = ((codes ^ half) - half).astype(np.float64)  # two's complement
    missing = steps == -half
    if np.isnan(sigma).any():
        sigma = np.where(np.isnan(sigma), 1.0, sigma)
    out = steps * sigma
    out *= 1.0 / VALUE_STEPS_PER_SIGMA
    if missing.any():
        out[missing] = np.nan
    return out


def _residual_codes(value: np.ndarray) -> np.ndarray:
    x = np.asarray(value, dtype=np.float32)  # float32 logarithms: codes are 8 bits
    with np.errstate(invalid="ignore"):
        magnitude = np.rint(np.log1p(np.abs(x) * (1.0 / RESIDUAL_KNEE)) * (1.0 / _RESIDUAL_STEP))
        magnitude = np.minimum(magnitude, _RESIDUAL_TOP)
    codes = magnitude + (np.signbit(x) & (magnitude > 0)) * (_RESIDUAL_TOP + 1)
    codes[~np.isfinite(x)] = _RESIDUAL_TOP + 1
    return codes.astype(np.int64)


def _residual_table() -> np.ndarray:
    codes = np.arange(2**RESIDUAL_BITS)
    negative = codes > _RESIDUAL_TOP
    magnitude = np.where(negative, codes - _RESIDUAL_TOP - 1, codes)
    out = RESIDUAL_KNEE * np.expm1(magnitude * _RESIDUAL_STEP)
    out = np.where(negative, -out, out)
    return np.where(codes == _RESIDUAL_TOP + 1, np.nan, out)


_RESIDUALS = _residual_table()


def _residuals(codes: np.ndarray) -> np.ndarray:
    return _RESIDUALS[codes]


class Decoded(NamedTuple):
    """Stored estimates decoded: values (n, width) per ``EstimateLayout.slices`` and each
    record's phase as its index in ``STORED_PHASES``."""

    values: np.ndarray
    phase: np.ndarray


@dataclass(frozen=True)
class EstimateLayout:
    """Names of the numbers of an estimate (stored as ``filter_states.layout``).

    ``units`` maps group -> list of units, aligned with the group's names.
    ``health_from_tuners``: V*^+ [health, tuners], h = V*^+ q, when the health values follow
    from the tuners (the snapshot pipeline's designs); None: they are stored.
    """

    tuners: tuple[str, ...]
    health: tuple[str, ...]
    aux: tuple[str, ...]
    sensors: tuple[str, ...]
    faults: tuple[str, ...]
    units: dict[str, list[str]] = field(default_factory=dict)
    health_from_tuners: tuple[tuple[float, ...], ...] | None = None

    def names(self, group: str) -> tuple[str, ...]:
        return tuple(getattr(self, group))

    @property
    def width(self) -> int:
        return self.slices()[BLOCKS[-1][0]].stop  # the last block's end

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
        """(n, width) numbers -> n float32 blobs (a stream estimate's stored form)."""
        rows = np.ascontiguousarray(rows, dtype=VALUE_DTYPE)
        if rows.ndim != 2 or rows.shape[1] != self.width:
            raise ValueError(f"estimate rows: expected (n, {self.width}) but found {rows.shape}")
        return [row.tobytes() for row in rows]

    def unpack(self, blobs: list[bytes]) -> np.ndarray:
        """n float32 blobs -> (n, width) float64 numbers."""
        flat = np.frombuffer(b"".join(blobs), dtype=VALUE_DTYPE)
        return flat.reshape(len(blobs), self.width).astype(np.float64)

    # The stored form of a snapshot estimate.

    def _health_map(self) -> tuple[np.ndarray, np.ndarray | None] | None:
        """(V*^+, its single column per health row or None when a row mixes tuners)."""
        if self.health_from_tuners is None:
            return None
        cached = self.__dict__.get("_health_cache")
        if cached is None:
            vp = np.asarray(self.health_from_tuners, dtype=np.float64).reshape(
                len(self.health), len(self.tuners))
            nonzero = np.abs(vp) > 1e-12 * max(float(np.abs(vp).max(initial=0.0)), 1e-300)
            single = np.argmax(nonzero, axis=1) if np.all(nonzero.sum(axis=1) <= 1) else None
            cached = (vp, single)
            self.__dict__["_health_cache"] = cached
        return cached  # type: ignore[no-any-return]

    def _parts(self) -> tuple[list[str], list[str]]:
        """The sigma blocks and value blocks stored, in order."""
        health = self._health_map()
        sigmas = ["q_sigma", "z_sigma"]
        if health is None or health[1] is None:
            sigmas.append("h_sigma")
        values = ["q", "z"] + (["h"] if health is None else [])
        return sigmas, values

    def _counts(self) -> tuple[int, int, int]:
        """Bytes of sigmas (at least ``PHASE_BITS``: they carry the phase), 12-bit pairs of
        values, and the number of values."""
        sigmas, values = self._parts()
        s = self.slices()
        n_sigma = sum(s[b].stop - s[b].start for b in sigmas)
        n_value = sum(s[b].stop - s[b].start for b in values)
        return max(n_sigma, PHASE_BITS), (n_value + 1) // 2, n_value

    @property
    def stored_bytes(self) -> int:
        """Bytes of one stored estimate."""
        n_sigma, n_pairs, _n_value = self._counts()
        return n_sigma + 3 * n_pairs + len(self.sensors) + len(self.faults)

    def encode(self, values: np.ndarray, phase: np.ndarray) -> np.ndarray:
        """(n, width) numbers and n phase indices -> (n, ``stored_bytes``) uint8 rows.

        A row: one byte per 1-sigma (a 7-bit code; the top bits of the first ``PHASE_BITS``
        bytes hold the phase), the values (tuners, auxiliary outputs; health values when they
        do not follow from the tuners) as 12-bit multiples of their decoded 1-sigma, two in
        three bytes, then one byte per residual and per WSSR. The values are coded against
        the decoded sigmas, so decoding returns each within 1/16 of its 1-sigma
        (docs/data-flow.md gives every tolerance).
        """
        values = np.asarray(values, dtype=np.float64)
        if values.ndim != 2 or values.shape[1] != self.width:
            raise ValueError(
                f"estimate rows: expected (n, {self.width}) but found {values.shape}")
        n = len(values)
        s = self.slices()
        sigma_blocks, value_blocks = self._parts()
        n_sigma, n_pairs, n_value = self._counts()
        sig = {k: _SIGMA_CODE.codes(values[:, s[k]]) for k in sigma_blocks}
        for k in value_blocks:
            sig[k + "_sigma"] = _fitting(sig[k + "_sigma"], values[:, s[k]])
        dec = {k: _SIGMAS[c] for k, c in sig.items()}
        out = np.zeros((n, self.stored_bytes), dtype=np.uint8)
        sigma_codes = np.zeros((n, n_sigma), dtype=np.int64)
        stacked = np.concatenate([sig[k] for k in sigma_blocks], axis=1)
        sigma_codes[:, : stacked.shape[1]] = stacked
        bits = (np.asarray(phase, dtype=np.int64)[:, None] >> np.arange(PHASE_BITS)) & 1
        sigma_codes[:, :PHASE_BITS] |= bits << 7
        out[:, :n_sigma] = sigma_codes
        value_codes = np.zeros((n, 2 * n_pairs), dtype=np.int64)
        value_codes[:, :n_value] = np.concatenate(
            [_value_codes(values[:, s[k]], dec[k + "_sigma"]) for k in value_blocks], axis=1)
        first, second = value_codes[:, 0::2], value_codes[:, 1::2]
        triples = np.stack([first & 0xFF, (first >> 8) | ((second & 0xF) << 4), second >> 4],
                           axis=2)
        at = n_sigma + 3 * n_pairs
        out[:, n_sigma:at] = triples.reshape(n, 3 * n_pairs)
        ny = len(self.sensors)
        out[:, at:at + ny] = _residual_codes(values[:, s["residual"]])
        out[:, at + ny:] = _WSSR_CODE.codes(values[:, s["wssr"]])
        return out

    def decode(self, raw: bytes | np.ndarray, n: int | None = None) -> Decoded:
        """Stored estimates (the rows' blobs joined, or (n, stored_bytes) uint8) -> numbers
        (float64) and phase indices."""
        rows = np.frombuffer(raw, dtype=np.uint8) if isinstance(raw, bytes) else raw
        rows = rows.reshape(-1 if n is None else n, self.stored_bytes)
        count = len(rows)
        s = self.slices()
        sigma_blocks, value_blocks = self._parts()
        n_sigma, n_pairs, n_value = self._counts()
        out = np.empty((count, self.width))
        head = rows[:, :n_sigma]
        phase = np.zeros(count, dtype=np.intp)
        for j in range(PHASE_BITS):
            phase |= (head[:, j] >> 7).astype(np.intp) << j
        head = head & 0x7F
        sigma = _SIGMAS[head]
        at = 0
        for k in sigma_blocks:
            width = s[k].stop - s[k].start
            out[:, s[k]] = sigma[:, at:at + width]
            at += width
        triples = rows[:, n_sigma:n_sigma + 3 * n_pairs].reshape(count, n_pairs, 3)
        triples = triples.astype(np.int16)
        codes = np.empty((count, 2 * n_pairs), dtype=np.int16)
        codes[:, 0::2] = triples[..., 0] | ((triples[..., 1] & 0xF) << 8)
        codes[:, 1::2] = (triples[..., 1] >> 4) | (triples[..., 2] << 4)
        at = 0
        for k in value_blocks:
            width = s[k].stop - s[k].start
            out[:, s[k]] = _values(codes[:, at:at + width], out[:, s[k + "_sigma"]])
            at += width
        health = self._health_map()
        if health is not None:
            vp, single = health
            out[:, s["h"]] = out[:, s["q"]] @ vp.T
            if single is not None:
                out[:, s["h_sigma"]] = out[:, s["q_sigma"]][:, single] * np.abs(
                    vp[np.arange(len(vp)), single])
        at = n_sigma + 3 * n_pairs
        ny = len(self.sensors)
        out[:, s["residual"]] = _RESIDUALS[rows[:, at:at + ny]]
        out[:, s["wssr"]] = _WSSRS[rows[:, at + ny:]]
        return Decoded(out, phase)

    def as_stored(self, values: np.ndarray) -> np.ndarray:
        """(n, width) numbers as their stored form gives them back (decoding a decoded row
        gives it again)."""
        return self.decode(self.encode(values, np.zeros(len(values), dtype=np.int64))).values

    def decode_blobs(self, blobs: list[bytes]) -> np.ndarray:
        """n stored blobs -> (n, width) float64 numbers."""
        return self.decode(b"".join(blobs), len(blobs)).values

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "tuners": list(self.tuners),
            "health": list(self.health),
            "aux": list(self.aux),
            "sensors": list(self.sensors),
            "faults": list(self.faults),
            "units": {k: list(v) for k, v in self.units.items()},
        }
        if self.health_from_tuners is not None:
            out["health_from_tuners"] = [list(row) for row in self.health_from_tuners]
        return out

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> EstimateLayout:
        vp = d.get("health_from_tuners")
        return cls(
            tuners=tuple(d["tuners"]),
            health=tuple(d["health"]),
            aux=tuple(d["aux"]),
            sensors=tuple(d["sensors"]),
            faults=tuple(d["faults"]),
            units={k: list(v) for k, v in d.get("units", {}).items()},
            health_from_tuners=None if vp is None else tuple(tuple(float(x) for x in row)
                                                             for row in vp),
        )
