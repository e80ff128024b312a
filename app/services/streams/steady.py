"""A recording's steady windows as records of the engine: streams in the engine's history.

When samples of a recording are stored (a whole-flight file, or a live chunk that completes
windows), its complete windows on the fixed grid from the recording's first sample are checked
for steadiness (``estimation.steady_windows``) and each steady window becomes one snapshot of
the engine. What steady means depends on the engine's type (``fleet.parameter_sets``):

- the built-in engine's type (and a type with no model yet, on the catalogue): power setting,
  Mach number, altitude rate and the spools' transient index; a window of the take-off, climb
  or cruise is kept, with its phase;
- a type of imported models: its own inputs held and its own sensors settled
  (``held_steady``), and, when the recording carries alt_ft, mach and power_pct, the
  condition's criteria and phase as well; a recording without them (a single-point type needs
  none) gives windows with no phase.

Each kept window is the mean of every signal (operating condition, actuators, sensors) over
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

from app.models import Engine, Snapshot, StreamChunk, StreamRecording, Upload
from app.services.fleet.parameter_sets import ParameterSet, parameter_sets
from app.services.snapshots import backlog
from app.services.streams import samples
from app.services.uploads import store as uploads_store
from app.signals import SIGNALS
from estimation.steady_windows import (
    SteadyCriteria,
    SteadyWindow,
    field_of,
    held_steady,
    steady_windows,
    unphased_windows,
    window_length,
    window_means,
)

CRITERIA = SteadyCriteria()
SPOOLS = ("Nf", "Nc")  # the spool speeds whose transient index marks a window unsettled
FLIGHT = ("alt_ft", "mach", "power_pct")  # the condition a window's phase is told from


def _column(table: pa.Table, name: str) -> np.ndarray:
    if name not in table.column_names:
        return np.full(table.num_rows, np.nan)
    return np.asarray(table[name].to_numpy(zero_copy_only=False), float)


def _columns(table: pa.Table, names: tuple[str, ...]) -> np.ndarray | None:
    present = [n for n in names if n in table.column_names]
    return np.column_stack([_column(table, n) for n in present]) if present else None


def _own_signals(params: ParameterSet) -> bool:
    """Whether a type's windows are judged on its own inputs and sensors: a type of imported
    models (the built-in engine's models tell phases, and a type with no model yet has the
    catalogue)."""
    return params.from_models and not params.phase_required


def _windows(
    session: Session, data_dir: Path, recording: StreamRecording, chunks: list[StreamChunk],
    table: pa.Table, first_window: int,
) -> list[SteadyWindow]:
    """The steady windows of ``table`` (the samples from window ``first_window`` on)."""
    engine = session.get(Engine, recording.engine_id)
    assert engine is not None
    params = parameter_sets(session, [engine.engine_type_id])[engine.engine_type_id]
    dt = float(recording.dt_s)
    held = None
    if _own_signals(params):
        held = held_steady(_columns(table, params.inputs), _columns(table, params.sensors), dt,
                           CRITERIA)
        if not all(c in table.column_names for c in FLIGHT):
            return unphased_windows(held, dt, first_window, CRITERIA)
    # The first sample (the departure field when on the ground): read again only when the
    # samples read start later.
    field = (table if first_window == 0 else samples.read_from(data_dir, recording, chunks[:1], 0)
             ).slice(0, 1)
    field_alt = (field_of(float(_column(field, "alt_ft")[0]), float(_column(field, "mach")[0]),
                          CRITERIA) if field.num_rows else None)
    spools = None if held is not None else _columns(table, SPOOLS)
    return steady_windows(
        _column(table, "alt_ft"), _column(table, "mach"), _column(table, "power_pct"), spools,
        dt, field_alt, first_window, CRITERIA, held,
    )


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
    windows = _windows(session, data_dir, recording, list(chunks), table, first_window)
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
