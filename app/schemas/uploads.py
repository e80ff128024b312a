"""Upload, snapshot and stream recording schemas (requests and responses, not tables)."""

from __future__ import annotations

from typing import Any

from pydantic import AwareDatetime, BaseModel, ConfigDict, Field, field_validator, model_validator

from app.signals import ACTUATORS, PHASES, SENSORS, SIGNALS, STREAM_DT_MAX_S, STREAM_DT_MIN_S
from app.signals import MAX_CHUNK_INDEX as MAX_CHUNK_INDEX  # for the streams router


class RowErrorOut(BaseModel):
    """Why a row (or the whole upload: ``row`` null) was refused, and in which column."""

    row: int | None = None
    column: str | None = None
    reason: str


class AffectedEngineOut(BaseModel):
    """An engine with new snapshots; its estimation continues from ``earliest``."""

    engine_id: int
    esn: str
    rows: int
    earliest: AwareDatetime
    latest: AwareDatetime
    estimated_until: AwareDatetime | None = Field(
        None, description="the engine's last estimated record when the upload arrived"
    )


class UploadOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    kind: str
    content_format: str
    status: str = Field(description="stored (a 2xx committed the whole batch) or rejected")
    created_at: AwareDatetime
    api_key_id: int | None
    checksum: str = Field(description="SHA-256 of the body and its options")
    idempotency_key: str | None
    rows_received: int
    rows_stored: int
    rows_duplicate: int = Field(description="rows that were stored already, skipped")
    bytes_received: int
    message: str
    affected: list[AffectedEngineOut]
    recording_id: int | None = None
    filename: str | None = Field(None, description="the uploaded file's name, when sent")
    source: str = Field("api", description="browser (uploads page), cli (importer) or api")
    api_key_name: str | None = Field(None, description="the key's name when it uploaded")
    back_dated: bool = Field(
        False, description="records older than an affected engine's last estimated record: "
        "its estimates and events from the earliest of them were redone"
    )
    rows_late: int = Field(
        0, description="records recorded longer before the upload arrived than the lateness "
        "(FLEETHEALTH_UPLOAD_LATENESS_DAYS, default 7 days) at that time"
    )
    late: bool = Field(False, description="rows_late > 0: records that arrived late")
    replayed: bool = Field(
        False, description="true when this request repeated an earlier upload and stored nothing"
    )

    @model_validator(mode="after")
    def _late(self) -> UploadOut:
        self.late = self.rows_late > 0
        return self


class UploadEventOut(BaseModel):
    """An event the upload caused (``app.services.uploads.back_dating``)."""

    model_config = ConfigDict(from_attributes=True)

    id: int
    engine_id: int
    kind: str
    fault: str | None
    detected_at: AwareDatetime
    status: str


class UploadDetail(UploadOut):
    errors: list[RowErrorOut]
    events: list[UploadEventOut] = Field(
        default_factory=list,
        description="the events it caused: detected at its own records, or (back-dated) "
        "redone by the re-run from its earliest record",
    )

    @field_validator("errors", mode="before")
    @classmethod
    def _reasons(cls, errors: Any) -> Any:
        # Refusals stored before every detail carried a reason (a chunk out of order kept
        # only its expected index): answer with the upload's message rather than fail.
        if not isinstance(errors, list):
            return errors
        return [
            {**e, "reason": e.get("reason") or "refused; see the upload's message"}
            if isinstance(e, dict) else e
            for e in errors
        ]


def _signal_doc(prefix: str, signals: Any) -> str:
    return prefix + ", ".join(f"{s.name} [{s.unit}]" for s in signals)


class SnapshotRecord(BaseModel):
    """One snapshot as uploaded (JSON). Sensors and actuators may be null (missing)."""

    model_config = ConfigDict(extra="allow")

    recorded_at: str = Field(
        description="ISO 8601 with a time zone", examples=["2026-03-01T08:15:00Z"]
    )
    tail: str
    position: int = Field(ge=1, le=4)
    phase: str = Field(description=" | ".join(PHASES))
    flight_id: str | None = None
    alt_ft: float
    mach: float
    dtamb_k: float
    power_pct: float


class SnapshotBatch(BaseModel):
    """Body of ``POST /api/v1/snapshots`` (documented here; parsed column-wise)."""

    units: dict[str, str] | None = Field(
        None, description='declared units by column, e.g. {"T30": "degC"}'
    )
    columns: dict[str, str | None] | None = Field(
        None, description='column mapping, e.g. {"HPC_T": "T30", "junk": null}'
    )
    snapshots: list[SnapshotRecord] = Field(
        description=_signal_doc("records; other keys: ", ACTUATORS + SENSORS)
    )


class EngineSnapshots(BaseModel):
    """An engine's snapshots, oldest first, signals in the stored units listed in ``units``."""

    engine_id: int
    esn: str
    count: int
    units: dict[str, str] = Field(default_factory=lambda: {s.name: s.unit for s in SIGNALS})
    snapshots: list[dict[str, Any]]


class RecordingOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    engine_id: int
    aircraft_id: int
    position: int
    flight_id: str | None
    started_at: AwareDatetime
    dt_s: float
    status: str = Field(description="open (live chunks welcome) or closed")
    n_samples: int
    n_chunks: int
    signals: list[str]
    created_at: AwareDatetime
    closed_at: AwareDatetime | None
    samples_removed_at: AwareDatetime | None = Field(
        None, description="When the stream sample retention deleted the samples (their "
        "estimates and steady-window records are kept); null: the samples are kept")


class LiveRecordingCreate(BaseModel):
    """Open a live recording; chunks (CSV or Parquet with ``time_s``) follow in order."""

    model_config = ConfigDict(extra="forbid")

    tail: str = Field(min_length=1, max_length=32)
    position: int = Field(ge=1, le=4)
    started_at: AwareDatetime
    flight_id: str | None = Field(None, max_length=64)
    dt_s: float = Field(
        ge=STREAM_DT_MIN_S, le=STREAM_DT_MAX_S, allow_inf_nan=False,
        description="sample interval in seconds, a finite number",
    )


class ChunkOut(BaseModel):
    recording: RecordingOut
    chunk_index: int
    n_samples: int
    upload_id: int | None
    replayed: bool = False


class StreamUploadOut(BaseModel):
    """A whole-flight file: its upload and the closed recording it made."""

    upload: UploadOut
    recording: RecordingOut
