"""A recording's samples on disk: one Parquet file per chunk under
``data_dir/recordings/<operator>/<recording>/`` (time_s and the signals, stored units)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from app.models import StreamChunk, StreamRecording


def chunk_path(data_dir: Path, recording: StreamRecording, index: int) -> Path:
    return data_dir / recording.path / f"chunk-{index:06d}.parquet"


def read_all(data_dir: Path, recording: StreamRecording) -> pa.Table:
    """All samples of a recording in order."""
    tables = [pq.read_table(chunk_path(data_dir, recording, i)) for i in range(recording.n_chunks)]
    if not tables:
        return pa.table({"time_s": pa.array([], pa.float64())})
    return pa.concat_tables(tables, promote_options="default")


def read_from(data_dir: Path, recording: StreamRecording, chunks: Sequence[StreamChunk],
              start: int) -> pa.Table:
    """Samples ``start`` .. end of the recording, from those of ``chunks`` (in order) that
    hold them; an empty ``time_s`` column when none does."""
    tables, first = [], None
    for chunk in chunks:
        if chunk.first_sample + chunk.n_samples <= start:
            continue
        if first is None:
            first = chunk.first_sample
        tables.append(pq.read_table(chunk_path(data_dir, recording, chunk.chunk_index)))
    if not tables or first is None:
        return pa.table({"time_s": pa.array([], pa.float64())})
    return pa.concat_tables(tables, promote_options="default").slice(start - first)
