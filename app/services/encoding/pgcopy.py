"""PostgreSQL binary COPY payloads built column-wise with numpy (no per-row Python).

The binary format (PostgreSQL docs, "COPY ... Binary Format"): a 19-byte header, then per
row an int16 field count and per field an int32 byte length (-1: NULL) and the value in
network byte order; an int16 -1 ends the data. The server parses no text, which makes a bulk
load about a third faster than CSV. Every field's place in the buffer follows from the
lengths of the fields before it, so each column is written with one scatter.

Supported column types: int2, int4, int8, float8, timestamptz (microseconds since
2000-01-01 UTC), text (UTF-8) and jsonb (its JSON text after a version byte, 1).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

HEADER = b"PGCOPY\n\xff\r\n\x00" + (0).to_bytes(4, "big") + (0).to_bytes(4, "big")
TRAILER = (-1).to_bytes(2, "big", signed=True)
# Microseconds from the Unix epoch to PostgreSQL's epoch, 2000-01-01 UTC.
PG_EPOCH_US = 946_684_800_000_000
JSONB_VERSION = 1
_TEXT = {"text": 0, "jsonb": 1}  # variable-length types: bytes before the UTF-8 text
FIXED = {"int2": ">i2", "int4": ">i4", "int8": ">i8", "float8": ">f8", "timestamptz": ">i8"}


def _fixed_values(column: pa.ChunkedArray | pa.Array, pg_type: str) -> np.ndarray:
    if pg_type == "timestamptz":
        micros = pc.cast(pc.cast(column, pa.timestamp("us", tz="UTC")), pa.int64())
        values = np.asarray(pc.fill_null(micros, 0).to_numpy(zero_copy_only=False))
        return (values - PG_EPOCH_US).astype(FIXED[pg_type])
    if pg_type == "float8":
        filled = pc.fill_null(pc.cast(column, pa.float64()), 0.0)
    else:
        filled = pc.fill_null(pc.cast(column, pa.int64()), 0)
    return np.asarray(filled.to_numpy(zero_copy_only=False)).astype(FIXED[pg_type])


def binary_copy_payload(table: pa.Table, pg_types: Mapping[str, str]) -> bytes:
    """The rows of ``table`` as a whole ``COPY ... FROM STDIN (FORMAT binary)`` payload.

    ``pg_types`` gives each column's PostgreSQL type (keys in ``table.column_names`` order).
    """
    return HEADER + binary_copy_rows(table, pg_types) + TRAILER


def binary_copy_rows(table: pa.Table, pg_types: Mapping[str, str]) -> bytes:
    """The tuples of a binary COPY payload, without its header and trailer (for batches)."""
    n = table.num_rows
    names = table.column_names
    lengths = np.empty((n, len(names)), dtype=np.int64)  # payload bytes, -1 for NULL
    prepared: list[tuple[str, object]] = []
    for j, name in enumerate(names):
        column = table[name]
        pg_type = pg_types[name]
        valid = np.asarray(pc.is_valid(column).to_numpy(zero_copy_only=False), dtype=bool)
        if pg_type in _TEXT:
            text = pc.cast(column, pa.large_string()).combine_chunks()
            offsets = np.frombuffer(text.buffers()[1], dtype=np.int64)[
                text.offset : text.offset + n + 1
            ]
            chars = text.buffers()[2]
            data = (
                np.frombuffer(chars, dtype=np.uint8) if chars is not None else np.empty(0, np.uint8)
            )
            lengths[:, j] = np.where(valid, np.diff(offsets) + _TEXT[pg_type], -1)
            prepared.append((pg_type, (offsets, data)))
        else:
            values = _fixed_values(column, pg_type)
            lengths[:, j] = np.where(valid, values.dtype.itemsize, -1)
            prepared.append(("fixed", values))
    field_bytes = 4 + np.maximum(lengths, 0)
    row_bytes = 2 + field_bytes.sum(axis=1)
    row_start = np.concatenate([[0], np.cumsum(row_bytes)[:-1]]).astype(np.int64)
    buffer = np.zeros(int(row_bytes.sum()), dtype=np.uint8)
    _scatter(buffer, row_start, np.full(n, len(names), dtype=">i2"))
    # Field j starts after the row's count and the fields before it.
    field_start = row_start[:, None] + 2 + np.cumsum(field_bytes, axis=1) - field_bytes
    for j, (kind, payload) in enumerate(prepared):
        start = field_start[:, j]
        _scatter(buffer, start, lengths[:, j].astype(">i4"))
        present = lengths[:, j] >= 0
        if kind == "fixed":
            assert isinstance(payload, np.ndarray)
            _scatter(buffer, start[present] + 4, payload[present])
        else:
            offsets, data = payload  # type: ignore[misc]
            prefix = _TEXT[kind]
            if prefix:  # jsonb: the format's version byte first
                buffer[start[present] + 4] = JSONB_VERSION
            sizes = np.where(present, lengths[:, j] - prefix, 0)
            if sizes.sum():
                # Byte k of row i's string goes to start_i + 4 + prefix + k.
                shift = np.repeat(start + 4 + prefix - offsets[:-1], sizes)
                source = np.repeat(offsets[:-1], sizes) + _ranks(sizes)
                buffer[shift + source] = data[source]
    return buffer.tobytes()


def _ranks(sizes: np.ndarray) -> np.ndarray:
    """0..size-1 for each run of ``sizes``, concatenated."""
    total = int(sizes.sum())
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    return np.arange(total) - np.repeat(starts, sizes)


def _scatter(buffer: np.ndarray, starts: np.ndarray, values: np.ndarray) -> None:
    """Write each big-endian value's bytes at its start offset."""
    if values.size == 0:
        return
    width = values.dtype.itemsize
    raw = np.ascontiguousarray(values).view(np.uint8).reshape(-1, width)
    buffer[starts[:, None] + np.arange(width)] = raw


# ---------------------------------------------------------------------- fixed-width rows
#
# When every field of every row has the same width (no NULL, text of one length), a binary
# COPY row is a fixed record: int16 field count, then per field an int32 length and the value.
# A numpy structured dtype then writes all rows in one step, with no scatter at all.


def record_dtype(widths: Sequence[tuple[str, np.dtype]]) -> np.dtype:
    """The structured dtype of one fixed-width binary COPY row of these (name, value dtype)
    fields, big-endian and unaligned as on the wire."""
    fields: list[tuple[str, Any]] = [("__count", ">i2")]
    for name, dtype in widths:
        fields.append((f"__len_{name}", ">i4"))
        fields.append((name, dtype))
    return np.dtype(fields)


def fixed_copy_rows(columns: Sequence[tuple[str, np.ndarray]]) -> bytes:
    """Rows of a binary COPY payload (no header or trailer) from equal-length arrays whose
    values all have one width: big-endian numbers (``>i4``, ``>i8``, ``>f8``; a timestamptz is
    ``>i8`` microseconds since ``PG_EPOCH_US``) or raw bytes (``S{w}``/``V{w}`` for text of
    one length and bytea; a 2-D uint8 array [n, w] is taken as ``V{w}``)."""
    prepared = []
    for name, values in columns:
        if values.ndim == 2:
            values = np.ascontiguousarray(values, dtype=np.uint8).view(
                np.dtype((np.void, values.shape[1]))
            )[:, 0]
        prepared.append((name, values))
    n = len(prepared[0][1]) if prepared else 0
    dtype = record_dtype([(name, values.dtype) for name, values in prepared])
    rows = np.empty(n, dtype=dtype)
    rows["__count"] = len(prepared)
    for name, values in prepared:
        rows[f"__len_{name}"] = values.dtype.itemsize
        rows[name] = values
    return rows.tobytes()
