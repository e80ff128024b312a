"""A recording's steady windows as records of the engine: streams in the engine's history.

When samples of a recording are stored (a whole-flight file, or a live chunk that completes
windows), its complete windows on the fixed grid from the recording's first sample are checked
for steadiness (``estimation.steady_windows``: power setting, Mach number, altitude rate and the
spools' transient index) and each steady window of the take-off, climb or cruise becomes one
snapshot of the engine: the mean of every signal (operating condition, actuators, sensors) over
the window, the window's phase, the recording's flight, ``recorded_at`` the window's middle (an
engine type's own signals, outside the catalogue, among them: stored by name as any snapshot's
are), stored in ``snapshots`` with the upload that carried the samples and marked in the
estimation backlog like any upload's rows. The snapshot pipeline then runs the engine's filter,
shift and wear detectors over them with the engine's snapshots, under one baseline, and the
trend shows them (``trends.service.stream_records``: a record is a stream window when its upload
belongs to a recording).

Idempotent: a window's time depends only on the recording's start and the grid, and a window
whose (engine, recorded_at) is stored already is not stored again; a resent chunk or a
replayed file stores nothing. A live chunk re-reads the samples from the start of the first
window it completes, so a window split by a chunk boundary is summarised whole.
"""

from __future__ import annotations

from datetime import timedelta
from pathlib import Path

import numpy as np
import pyarrow as pa
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.models import Snapshot, StreamChunk, StreamRecording, Upload
from app.services.snapshots import backlog
from app.services.streams import samples
from app.services.uploads import store as uploads_store
from app.signals import SIGNALS
from estimation.steady_windows import (
    SteadyCriteria,
    field_of,
    steady_windows,
    window_length,
    window_means,
)

CRITERIA = SteadyCriteria()
SPOOLS = ("Nf", "Nc")  # the spool speeds whose transient index marks a window unsettled


def _column(table: pa.Table, name: str) -> np.ndarray:
    if name not in table.column_names:
        return np.full(table.num_rows, np.nan)
    return np.asarray(table[name].to_numpy(zero_copy_only=False), float)


def summarise_windows(
    session: Session, data_dir: Path, recording: StreamRecording, upload: Upload,
    from_sample: int,
) -> int:
    """Store the steady windows completed by the samples from ``from_sample`` on as
    snapshots of ``upload``, mark the engine's backlog; the number stored."""
    if recording.samples_removed_at is not None:
        return 0  # removed by the retention: the windows stored before stay
    W = window_length(float(recording.dt_s), CRITERIA.window_s)
    first_window = from_sample // W
    if (int(recording.n_samples) // W) <= first_window:
        return 0
    chunks = session.scalars(
        select(StreamChunk).where(StreamChunk.recording_id == recording.id)
        .order_by(StreamChunk.chunk_index)
    ).all()
    table = samples.read_from(data_dir, recording, chunks, first_window * W)
    # The first sample (the departure field when on the ground): read again only when the
    # samples read start later.
    field = (table if first_window == 0 else samples.read_from(data_dir, recording, chunks[:1], 0)
             ).slice(0, 1)
    field_alt = (field_of(float(_column(field, "alt_ft")[0]), float(_column(field, "mach")[0]),
                          CRITERIA) if field.num_rows else None)
    spool_names = [s for s in SPOOLS if s in table.column_names]
    spools = np.column_stack([_column(table, s) for s in spool_names]) if spool_names else None
    windows = steady_windows(
        _column(table, "alt_ft"), _column(table, "mach"), _column(table, "power_pct"), spools,
        float(recording.dt_s), field_alt, first_window, CRITERIA,
    )
    if not windows:
        return 0
    offset = first_window * W
    starts = np.array([w.start - offset for w in windows])
    time_s = _column(table, "time_s")
    middle = (time_s[starts] + time_s[starts + W - 1]) / 2.0
    times = [recording.started_at + timedelta(microseconds=round(float(m) * 1e6))
             for m in middle]
    stored = set(session.scalars(
        select(Snapshot.recorded_at).where(
            Snapshot.engine_id == recording.engine_id,
            Snapshot.recorded_at >= min(times), Snapshot.recorded_at <= max(times))
    ).all())
    keep = [j for j, t in enumerate(times) if t not in stored]
    if not keep:
        return 0
    catalogue = [s.name for s in SIGNALS]
    names = catalogue + [n for n in table.column_names if n not in catalogue and n != "time_s"]
    means = window_means(np.column_stack([_column(table, name) for name in names]),
                         starts[keep], W)
    n = len(keep)
    columns: dict[str, pa.Array] = {
        "engine_id": pa.array(np.full(n, recording.engine_id, dtype=np.int64)),
        "aircraft_id": pa.array(np.full(n, recording.aircraft_id, dtype=np.int64)),
        "position": pa.array(np.full(n, recording.position, dtype=np.int16)),
        "recorded_at": pa.array([times[j] for j in keep], pa.timestamp("us", tz="UTC")),
        "phase": pa.array([windows[j].phase for j in keep], pa.string()),
        "flight_id": pa.array([recording.flight_id] * n, pa.string()),
    }
    for k, name in enumerate(names):
        values = means[:, k]
        columns[name] = pa.array(values, pa.float64(), mask=~np.isfinite(values))
    rows = pa.table(columns)
    affected = uploads_store.record_affected(session, upload, rows)
    upload.message = f"{upload.message}; {n} steady windows summarised"
    uploads_store.insert_snapshots(session, rows, operator_id=recording.operator_id,
                                   upload_id=upload.id)
    backlog.mark(session, recording.operator_id,
                 {a.engine_id: (a.earliest, a.rows) for a in affected})
    session.flush()
    return n
