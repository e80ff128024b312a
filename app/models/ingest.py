"""Uploads, snapshots and stream recordings: the data operators send, as stored.

Snapshots keep one fixed ``DOUBLE PRECISION`` column per signal of the built-in engine, not a
JSON document of sensor values: a 100,000-row COPY then writes plain numbers (no per-row JSON
encoding on the way in, no JSON parsing on the way out), a trend query reads ten thousand rows
of native floats through the ``(engine_id, recorded_at)`` index, and the database checks each
value's type. NULL is a missing sensor. Signals outside the catalogue (an engine type's own,
``N1``, ``EGT`` ...: ``fleet.parameter_sets``) go in ``other_signals``, one JSON object of
numbers by name in stored units, NULL when a row has none: a type's signals are read by name
(``->>`` on PostgreSQL, ``json_extract`` on SQLite), so a type whose models change, or an engine
that changes type, never reads a value under another signal's name (a positional blob would).
The operating condition and ``phase`` are NULL on rows of a type whose models are not scheduled
on them (migration 0019). The unique key ``(engine_id, recorded_at)`` makes the
same snapshot twice store nothing. An engine or aircraft with data cannot be deleted (the
fleet service answers 409). Stream samples stay in Parquet files under
``data_dir/recordings``; the database holds their metadata and one row per received chunk.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

from sqlalchemy import (
    JSON,
    BigInteger,
    Boolean,
    CheckConstraint,
    Double,
    ForeignKey,
    Index,
    Integer,
    SmallInteger,
    String,
    UniqueConstraint,
    false,
    text,
)
from sqlalchemy.dialects.postgresql import JSONB
from sqlalchemy.orm import Mapped, mapped_column

from app.models.base import Base, UTCDateTime, utcnow
from app.signals import (  # noqa: F401  (the catalogue, as the tables use it)
    ACTUATORS,
    CONDITION_COLUMNS,
    MAX_CHUNK_INDEX,
    MEASURED,
    OPERATING_CONDITION,
    OTHER_SIGNALS,
    PHASES,
    SENSORS,
    SIGNALS,
    STREAM_DT_MAX_S,
    STREAM_DT_MIN_S,
    SignalSpec,
)

JSONDocument = JSON().with_variant(JSONB(), "postgresql")
BigId = BigInteger().with_variant(Integer(), "sqlite")  # SQLite autoincrements INTEGER only

UPLOAD_KINDS = ("snapshots", "stream", "stream_chunk")
UPLOAD_STATUSES = ("stored", "rejected")
# Where an upload came from: the uploads page, the C-MAPSS importer, or any other API client.
UPLOAD_SOURCES = ("browser", "cli", "api")
RECORDING_STATUSES = ("open", "closed")


def _in(column: str, values: tuple[str, ...]) -> str:
    return f"{column} IN (" + ", ".join(f"'{v}'" for v in values) + ")"


class Upload(Base):
    """One upload request: who, when, what, its checksum, counts, and its row-level errors."""

    __tablename__ = "uploads"
    __table_args__ = (
        CheckConstraint(_in("kind", UPLOAD_KINDS), name="kind"),
        CheckConstraint(_in("status", UPLOAD_STATUSES), name="status"),
        CheckConstraint(_in("source", UPLOAD_SOURCES), name="source"),
        Index("ix_uploads_operator_created", "operator_id", "created_at"),
        Index("ix_uploads_operator_checksum", "operator_id", "checksum"),
        # An Idempotency-Key names one stored upload; rejected attempts may reuse it.
        Index(
            "uq_uploads_operator_idempotency_key",
            "operator_id",
            "idempotency_key",
            unique=True,
            sqlite_where=text("status = 'stored'"),
            postgresql_where=text("status = 'stored'"),
        ),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    operator_id: Mapped[int] = mapped_column(ForeignKey("operators.id", ondelete="CASCADE"))
    api_key_id: Mapped[int | None] = mapped_column(
        ForeignKey("api_keys.id", ondelete="SET NULL"), default=None
    )
    created_at: Mapped[datetime] = mapped_column(UTCDateTime(), default=utcnow)
    kind: Mapped[str] = mapped_column(String(16))
    content_format: Mapped[str] = mapped_column(String(16))
    checksum: Mapped[str] = mapped_column(String(64))
    idempotency_key: Mapped[str | None] = mapped_column(String(200), default=None)
    status: Mapped[str] = mapped_column(String(16))
    rows_received: Mapped[int] = mapped_column(default=0)
    rows_stored: Mapped[int] = mapped_column(default=0)
    rows_duplicate: Mapped[int] = mapped_column(default=0)
    bytes_received: Mapped[int] = mapped_column(BigInteger, default=0)
    message: Mapped[str] = mapped_column(String(500), default="")
    # [{"row", "column", "reason"}, ...], at most ingest_parse.MAX_ERRORS.
    errors: Mapped[list[dict[str, Any]]] = mapped_column(JSONDocument, default=list)
    # Per affected engine: {"engine_id", "esn", "rows", "earliest", "latest"}.
    affected: Mapped[list[dict[str, Any]]] = mapped_column(JSONDocument, default=list)
    recording_id: Mapped[int | None] = mapped_column(
        ForeignKey("stream_recordings.id", ondelete="SET NULL"), default=None
    )
    # The file's name as sent (a multipart part's file name, or ``?filename=`` on a raw body).
    filename: Mapped[str | None] = mapped_column(String(255), default=None)
    source: Mapped[str] = mapped_column(String(16), default="api", server_default="api")
    # The key's name when it uploaded (kept when the key is renamed or deleted).
    api_key_name: Mapped[str | None] = mapped_column(String(200), default=None)
    # Records older than an affected engine's last estimated record: the estimation re-ran
    # the engine from the upload's earliest record (``affected[*].estimated_until``).
    back_dated: Mapped[bool] = mapped_column(Boolean, default=False, server_default=false())
    # Records recorded longer before the upload than the lateness (``upload_lateness_days``).
    rows_late: Mapped[int] = mapped_column(Integer, default=0, server_default="0")


class Snapshot(Base):
    """One steady-state report of one engine on one flight (docs/upload-format.md), in
    stored units."""

    __tablename__ = "snapshots"
    __table_args__ = (
        CheckConstraint(_in("phase", PHASES), name="phase"),
        CheckConstraint("position BETWEEN 1 AND 4", name="position"),
        # An installation recorded or corrected re-resolves its tail position's snapshots over
        # its period (``fleet.installation_records``): without it, a scan of every snapshot.
        Index("ix_snapshots_aircraft_position_time", "aircraft_id", "position", "recorded_at"),
    )

    # Keyed by the engine and the time (migration 0010): a snapshot is one engine's report at
    # one moment, and a generated id cost a sequence call and a second index per COPYed row
    # (a quarter of a bulk load). No foreign key (migration 0008): PostgreSQL checks each one
    # per COPYed row with a lookup and a lock on the referenced row, 40 % of a bulk load for
    # engine_id alone. operator_id, engine_id, aircraft_id and upload_id are written by the
    # ingest service from the resolved installation and the upload it creates in the same
    # transaction; an engine with snapshots cannot be deleted (``fleet.delete_engine``).
    engine_id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=False)
    recorded_at: Mapped[datetime] = mapped_column(UTCDateTime(), primary_key=True)
    operator_id: Mapped[int]
    aircraft_id: Mapped[int]
    position: Mapped[int] = mapped_column(SmallInteger)
    upload_id: Mapped[int]
    phase: Mapped[str | None] = mapped_column(String(8), default=None)
    flight_id: Mapped[str | None] = mapped_column(String(64), default=None)
    alt_ft: Mapped[float | None] = mapped_column(Double, default=None)
    mach: Mapped[float | None] = mapped_column(Double, default=None)
    dtamb_k: Mapped[float | None] = mapped_column(Double, default=None)
    power_pct: Mapped[float | None] = mapped_column(Double, default=None)
    wf: Mapped[float | None] = mapped_column(Double, default=None)
    vsv: Mapped[float | None] = mapped_column(Double, default=None)
    vbv: Mapped[float | None] = mapped_column(Double, default=None)
    nf: Mapped[float | None] = mapped_column(Double, default=None)
    nc: Mapped[float | None] = mapped_column(Double, default=None)
    t24: Mapped[float | None] = mapped_column(Double, default=None)
    p24: Mapped[float | None] = mapped_column(Double, default=None)
    t30: Mapped[float | None] = mapped_column(Double, default=None)
    ps30: Mapped[float | None] = mapped_column(Double, default=None)
    p30: Mapped[float | None] = mapped_column(Double, default=None)
    t48: Mapped[float | None] = mapped_column(Double, default=None)
    p50: Mapped[float | None] = mapped_column(Double, default=None)
    t50: Mapped[float | None] = mapped_column(Double, default=None)
    p15: Mapped[float | None] = mapped_column(Double, default=None)
    other_signals: Mapped[dict[str, float] | None] = mapped_column(JSONDocument, default=None)


# The table's columns in COPY order.
SNAPSHOT_COLUMNS = (
    "operator_id",
    "engine_id",
    "aircraft_id",
    "position",
    "upload_id",
    "recorded_at",
    "phase",
    "flight_id",
) + tuple(s.column for s in SIGNALS) + (OTHER_SIGNALS,)


class StreamRecording(Base):
    """A whole-flight recording of one engine at a fixed rate; samples are Parquet files.

    ``path`` is relative to ``data_dir``: a directory of ``chunk-000000.parquet`` files in
    chunk order (a whole-flight file is chunk 0).
    """

    __tablename__ = "stream_recordings"
    __table_args__ = (
        UniqueConstraint("engine_id", "started_at"),
        CheckConstraint(_in("status", RECORDING_STATUSES), name="status"),
        CheckConstraint("dt_s > 0", name="dt"),
        Index("ix_stream_recordings_operator_started", "operator_id", "started_at"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    operator_id: Mapped[int] = mapped_column(ForeignKey("operators.id", ondelete="CASCADE"))
    engine_id: Mapped[int] = mapped_column(ForeignKey("engines.id"))
    aircraft_id: Mapped[int] = mapped_column(ForeignKey("aircraft.id"))
    position: Mapped[int] = mapped_column(SmallInteger)
    flight_id: Mapped[str | None] = mapped_column(String(64), default=None)
    started_at: Mapped[datetime] = mapped_column(UTCDateTime())
    dt_s: Mapped[float] = mapped_column(Double)
    status: Mapped[str] = mapped_column(String(8))
    n_samples: Mapped[int] = mapped_column(default=0)
    n_chunks: Mapped[int] = mapped_column(default=0)
    signals: Mapped[list[str]] = mapped_column(JSONDocument, default=list)
    path: Mapped[str] = mapped_column(String(300))
    created_at: Mapped[datetime] = mapped_column(UTCDateTime(), default=utcnow)
    closed_at: Mapped[datetime | None] = mapped_column(UTCDateTime(), default=None)
    # When the retention setting deleted the sample files (app.services.streams.retention);
    # None: they are kept.
    samples_removed_at: Mapped[datetime | None] = mapped_column(UTCDateTime(), default=None)


class StreamChunk(Base):
    """One received chunk of a recording, in order; its checksum makes a resend a no-op."""

    __tablename__ = "stream_chunks"
    __table_args__ = (UniqueConstraint("recording_id", "chunk_index"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    recording_id: Mapped[int] = mapped_column(
        ForeignKey("stream_recordings.id", ondelete="CASCADE")
    )
    chunk_index: Mapped[int]
    upload_id: Mapped[int | None] = mapped_column(
        ForeignKey("uploads.id", ondelete="SET NULL"), default=None
    )
    checksum: Mapped[str] = mapped_column(String(64))
    first_sample: Mapped[int]
    n_samples: Mapped[int]
    created_at: Mapped[datetime] = mapped_column(UTCDateTime(), default=utcnow)
