"""Upload bodies (CSV, JSON, Parquet) to validated columns in stored units.

Everything is columnar: pyarrow reads the file, numpy and pyarrow.compute check whole columns,
and per-row Python runs only to word the errors of rows already known to be bad. Rows are
numbered from 1 in file order (CSV: the first line after the header is row 1; JSON: the first
element of ``snapshots``). At most ``MAX_ERRORS`` errors are collected, then checking stops.

Column names are the upload names of docs/upload-format.md; a ``[unit]`` suffix declares a unit
(``T30[degC]``), otherwise the stored unit is assumed. A column mapping renames foreign
columns (``{"HPC_T": "T30"}``) or drops them (``{"Ps30_raw": null}``) before anything else.

Snapshots and streams are parsed ``by_type``: any signal column is read as numbers with its
declared unit, and which columns a row may carry, which it must, and the units they convert from
are decided once the row's engine, hence its engine type, is known
(``app.services.uploads.parameters``). Without ``by_type`` the signal catalogue decides here.
"""

from __future__ import annotations

import csv
import io
import json
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from app.errors import InvalidInput
from app.services.units import UnknownUnitError, affine
from app.signals import (
    OPERATING_CONDITION,
    PHASES,
    SIGNALS,
    STREAM_DT_MAX_S,
    STREAM_DT_MIN_S,
    SignalSpec,
)

MAX_ERRORS = 100
FORMATS = ("csv", "json", "parquet")
UTC_MICROS = pa.timestamp("us", tz="UTC")

SNAPSHOT_KEYS = ("recorded_at", "tail", "position", "phase", "flight_id")
SNAPSHOT_REQUIRED = ("recorded_at", "tail", "position", "phase") + tuple(
    s.name for s in OPERATING_CONDITION
)
# Required of every snapshot whatever its engine type (the rest: its parameter set).
SNAPSHOT_REQUIRED_BY_TYPE = ("recorded_at", "tail", "position")
STREAM_KEYS = ("time_s",)
STREAM_REQUIRED = STREAM_KEYS + tuple(s.name for s in OPERATING_CONDITION)
SIGNAL_BY_NAME: dict[str, SignalSpec] = {s.name: s for s in SIGNALS}
MAX_POSITION = 4

_HEADER_UNIT = re.compile(r"^(?P<name>[^\[\]]+?)\s*\[(?P<unit>[^\[\]]*)\]$")
_NUMBER = r"^\s*[+-]?(\d+(\.\d*)?|\.\d+)([eE][+-]?\d+)?\s*$"
_NOT_FINITE = r"^\s*[+-]?(?i:nan|inf|infinity)\s*$"
_ZONE = r"(Z|z|[+-]\d\d(:?\d\d)?)$"


@dataclass(frozen=True)
class RowError:
    """Why a row (or the whole upload: ``row`` None) was refused, and in which column."""

    row: int | None
    column: str | None
    reason: str

    def as_dict(self) -> dict[str, Any]:
        return {"row": self.row, "column": self.column, "reason": self.reason}


class UploadRejected(InvalidInput):
    """A refused upload (422); ``errors`` are the row-level reasons, at most MAX_ERRORS."""

    def __init__(self, errors: list[RowError], *, truncated: bool = False) -> None:
        first = errors[0]
        where = ", ".join(
            part
            for part in (
                f"row {first.row}" if first.row is not None else "",
                f"column {first.column!r}" if first.column else "",
            )
            if part
        )
        more = f" (and {len(errors) - 1} more{'+' if truncated else ''})" if len(errors) > 1 else ""
        super().__init__(
            f"upload rejected: {where + ': ' if where else ''}{first.reason}{more}",
            details=[e.as_dict() for e in errors],
        )
        self.errors = errors
        self.truncated = truncated


class ErrorLimitReached(Exception):
    """Enough errors collected: stop checking."""


class ErrorLog:
    """Collects row errors up to ``limit``; raises ``ErrorLimitReached`` internally once reached."""

    def __init__(self, limit: int = MAX_ERRORS) -> None:
        self.limit = limit
        self.errors: list[RowError] = []
        self.cells: set[tuple[int | None, str | None]] = set()
        self.truncated = False

    def add(self, row: int | None, column: str | None, reason: str) -> None:
        if len(self.errors) >= self.limit:
            self.truncated = True
            raise ErrorLimitReached
        self.errors.append(RowError(row, column, reason))
        self.cells.add((row, column))

    def add_rows(
        self, mask: np.ndarray, column: str | None, reason: Any, values: Any = None
    ) -> None:
        """One error per true element of ``mask`` (rows are 1-based); ``reason`` may be a
        callable of the offending value (taken from ``values``)."""
        for index in np.flatnonzero(mask)[: self.limit - len(self.errors) + 1]:
            value = None if values is None else values[int(index)]
            text = reason(value) if callable(reason) else reason
            self.add(int(index) + 1, column, text)

    def raise_if_any(self) -> None:
        if self.errors:
            ordered = sorted(self.errors, key=lambda e: (e.row is not None, e.row or 0))
            raise UploadRejected(ordered, truncated=self.truncated)


@dataclass(frozen=True)
class ColumnSpec:
    """An uploaded column: its name in the file, the name it stands for, its declared unit."""

    source: str
    target: str
    unit: str | None


@dataclass(frozen=True)
class ParsedTable:
    """Validated rows: ``table`` has the upload names as columns, signals in stored units.

    Snapshots: recorded_at timestamp[us, UTC], tail, phase, flight_id strings, position int16,
    signals float64 (null = missing). Streams: time_s float64 and signals.
    """

    table: pa.Table
    # by_type: the declared unit of each signal column (None: undeclared) and the file column
    # it came from; values are as sent, not converted yet.
    units: Mapping[str, str | None] = field(default_factory=dict)
    sources: Mapping[str, str] = field(default_factory=dict)

    @property
    def num_rows(self) -> int:
        return self.table.num_rows

    @property
    def signals(self) -> tuple[str, ...]:
        """The signal columns: the catalogue's, and (by_type) every other one sent."""
        return tuple(name for name in self.table.column_names
                     if name in SIGNAL_BY_NAME or name in self.sources)


# ---------------------------------------------------------------- columns and units


def split_unit(header: str) -> tuple[str, str | None]:
    """``"T30[degC]"`` -> ``("T30", "degC")``; a plain name has no declared unit."""
    match = _HEADER_UNIT.match(header.strip())
    if match:
        return match.group("name").strip(), match.group("unit").strip()
    return header.strip(), None


def resolve_columns(
    headers: Iterable[str],
    *,
    allowed: Iterable[str] | None,
    required: Iterable[str],
    mapping: Mapping[str, str | None] | None = None,
    units: Mapping[str, str] | None = None,
    log: ErrorLog,
    keys: tuple[str, ...] = SNAPSHOT_KEYS,
) -> list[ColumnSpec]:
    """Map file columns to upload names: apply the mapping, split units, refuse unknowns.

    ``mapping`` keys are file column names (with or without their ``[unit]``); a None value
    drops the column. ``units`` declares units by upload name (the JSON ``"units"`` object).
    ``allowed`` None takes any name as a signal whose unit is checked later (by type), except
    the ``keys`` (no unit).
    """
    mapping = dict(mapping or {})
    units = dict(units or {})
    by_type = allowed is None
    allowed_set = set(allowed or ())
    specs: list[ColumnSpec] = []
    seen: dict[str, str] = {}
    for header in headers:
        name, unit = split_unit(header)
        if header in mapping or name in mapping:
            target = mapping[header] if header in mapping else mapping[name]
            if target is None:
                continue
            target, mapped_unit = split_unit(target)
            unit = mapped_unit or unit
        else:
            target = name
        if not target:
            log.add(None, header, "a column has no name")
            continue
        if not by_type and target not in allowed_set:
            log.add(None, header, f"unknown column {target!r}")
            continue
        if target in seen:
            log.add(None, header, f"column {target!r} appears twice (also as {seen[target]!r})")
            continue
        seen[target] = header
        unit = unit or units.get(target)
        if unit is not None and by_type and target in keys:
            log.add(None, header, f"column {target!r} takes no unit (got {unit!r})")
        elif unit is not None and not by_type:
            _check_unit(target, unit, header, log)
        specs.append(ColumnSpec(header, target, unit))
    for name in units:
        if name not in seen and name in SIGNAL_BY_NAME:
            continue  # a declared unit for an absent optional column is harmless
        if not by_type and name not in allowed_set:
            log.add(None, name, f"unit declared for unknown column {name!r}")
    for name in required:
        if name not in seen:
            log.add(None, name, f"required column {name!r} is missing")
    return specs


def _check_unit(target: str, unit: str, header: str, log: ErrorLog) -> None:
    signal = SIGNAL_BY_NAME.get(target)
    if signal is None:
        log.add(None, header, f"column {target!r} takes no unit (got {unit!r})")
        return
    try:
        affine(signal.quantity, unit, signal.unit, reference=signal.percent_reference)
    except UnknownUnitError as exc:
        log.add(None, header, str(exc))


# ---------------------------------------------------------------- column coercion


def _mask(array: pa.Array | pa.ChunkedArray) -> np.ndarray:
    """Boolean numpy mask of a pyarrow boolean result, nulls as False."""
    return np.asarray(pc.fill_null(array, False).to_numpy(zero_copy_only=False), dtype=bool)


def _string_values(array: pa.Array | pa.ChunkedArray) -> list[Any]:
    return array.to_pylist()


def coerce_float(array: pa.ChunkedArray, column: str, log: ErrorLog) -> pa.ChunkedArray:
    """Float64 column; strings must be decimal numbers, NaN and infinity are refused."""
    kind = array.type
    if pa.types.is_floating(kind) or pa.types.is_integer(kind) or pa.types.is_null(kind):
        values = pc.cast(array, pa.float64())
    elif pa.types.is_string(kind) or pa.types.is_large_string(kind):
        strings = pc.utf8_trim_whitespace(array)
        strings = pc.if_else(pc.equal(strings, ""), pa.scalar(None, pa.string()), strings)
        bad = ~_mask(pc.match_substring_regex(strings, _NUMBER)) & _mask(pc.is_valid(strings))
        not_finite = _mask(pc.match_substring_regex(strings, _NOT_FINITE))
        if bad.any():
            texts = _string_values(strings)
            log.add_rows(
                bad & ~not_finite,
                column,
                lambda v: f"{v!r} is not a number",
                texts,
            )
            log.add_rows(
                not_finite,
                column,
                lambda v: f"{v.strip()} is not a number the API accepts (a missing value is empty)",
                texts,
            )
            strings = pc.if_else(pa.array(bad), pa.scalar(None, pa.string()), strings)
        values = pc.cast(strings, pa.float64())
        return values if isinstance(values, pa.ChunkedArray) else pa.chunked_array([values])
    else:
        log.add(None, column, f"column {column!r} must be numeric, not {kind}")
        return pa.chunked_array([pa.nulls(len(array), pa.float64())])
    finite = pc.is_finite(values)
    not_finite = ~_mask(finite) & _mask(pc.is_valid(values))
    if not_finite.any():
        numbers = values.to_numpy(zero_copy_only=False)
        values = pc.if_else(pa.array(not_finite), pa.scalar(None, pa.float64()), values)
        log.add_rows(
            not_finite,
            column,
            lambda v: f"{v} is not a number the API accepts (send null)",
            numbers,
        )
    return values


def coerce_timestamp(array: pa.ChunkedArray, column: str, log: ErrorLog) -> pa.ChunkedArray:
    """UTC timestamps; strings must be ISO 8601 with a zone, timestamp columns must be tz-aware."""
    kind = array.type
    if pa.types.is_timestamp(kind):
        if kind.tz is None:
            log.add(None, column, "timestamps carry no time zone (naive timestamps are refused)")
            return pa.chunked_array([pa.nulls(len(array), UTC_MICROS)])
        return pc.cast(array, UTC_MICROS)
    if not (pa.types.is_string(kind) or pa.types.is_large_string(kind)):
        log.add(None, column, f"column {column!r} must hold ISO 8601 timestamps, not {kind}")
        return pa.chunked_array([pa.nulls(len(array), UTC_MICROS)])
    strings = pc.utf8_trim_whitespace(array)
    try:
        return pc.cast(strings, UTC_MICROS)
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
        pass
    texts = _string_values(strings)
    zone = _mask(pc.match_substring_regex(strings, _ZONE))
    parsed: list[Any] = []
    for index, text in enumerate(texts):
        if text is None or text == "":
            parsed.append(None)
            continue
        try:
            parsed.append(pc.cast(pa.array([text]), UTC_MICROS)[0].as_py())
        except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
            parsed.append(None)
            if not zone[index] and _looks_like_time(text):
                log.add(index + 1, column, f"{text!r} has no time zone (add Z or an offset)")
            else:
                log.add(index + 1, column, f"{text!r} is not an ISO 8601 timestamp")
    return pa.chunked_array([pa.array(parsed, UTC_MICROS)])


def _looks_like_time(text: str) -> bool:
    try:
        pc.cast(pa.array([text]), pa.timestamp("us"))
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
        return False
    return True


# Longest text each column may hold (the table's column widths); longer values are refused by
# name instead of failing at the database (PostgreSQL) or being stored whole (SQLite).
MAX_TEXT = {"tail": 32, "phase": 8, "flight_id": 64}


def coerce_string(
    array: pa.ChunkedArray, column: str, log: ErrorLog, *, max_length: int | None = None
) -> pa.ChunkedArray:
    """Text: trimmed, empty as missing; NUL characters and values over ``max_length``
    characters are refused per row (neither database stores them as given)."""
    strings = _as_text(array, column, log)
    if strings is None:
        return pa.chunked_array([pa.nulls(len(array), pa.string())])
    values = _string_values(strings)
    log.add_rows(_mask(pc.match_substring(strings, "\x00")), column,
                 "contains a NUL character")
    if max_length is not None:
        too_long = _mask(pc.greater(pc.utf8_length(strings), max_length))
        log.add_rows(too_long, column,
                     lambda v: f"is {len(v)} characters long, over the limit of {max_length}",
                     values)
    return strings


def _as_text(array: pa.ChunkedArray, column: str, log: ErrorLog) -> pa.ChunkedArray | None:
    kind = array.type
    if pa.types.is_string(kind) or pa.types.is_large_string(kind):
        strings = pc.utf8_trim_whitespace(pc.cast(array, pa.string()))
    elif pa.types.is_integer(kind) or pa.types.is_null(kind):
        strings = pc.cast(array, pa.string())
    elif pa.types.is_dictionary(kind):
        return _as_text(pc.cast(array, pa.string()), column, log)
    else:
        log.add(None, column, f"column {column!r} must hold text, not {kind}")
        return None
    return pc.if_else(pc.equal(strings, ""), pa.scalar(None, pa.string()), strings)


def coerce_position(array: pa.ChunkedArray, column: str, log: ErrorLog) -> pa.ChunkedArray:
    """Engine position: an integer 1..4 (text digits, integers, or integral floats)."""
    kind = array.type
    if pa.types.is_string(kind) or pa.types.is_large_string(kind):
        strings = pc.utf8_trim_whitespace(array)
        valid = _mask(pc.is_valid(strings)) & ~_mask(pc.equal(strings, ""))
        digits = _mask(pc.match_substring_regex(strings, r"^[0-9]+$"))
        bad = valid & ~digits
        log.add_rows(
            bad,
            column,
            lambda v: f"{v!r} is not an engine position (1..4)",
            _string_values(strings),
        )
        strings = pc.if_else(pa.array(valid & digits), strings, pa.scalar(None, pa.string()))
        # Through float64: digits beyond int64 become a large number refused below by range.
        numbers = pc.cast(strings, pa.float64()).to_numpy(zero_copy_only=False)
    elif pa.types.is_integer(kind) or pa.types.is_null(kind) or pa.types.is_floating(kind):
        numbers = pc.cast(array, pa.float64()).to_numpy(zero_copy_only=False)
        integral = np.isnan(numbers) | (numbers == np.round(numbers))
        log.add_rows(~integral, column, lambda v: f"{v} is not an engine position (1..4)", numbers)
        numbers = np.where(integral, numbers, np.nan)
    else:
        log.add(None, column, f"column {column!r} must hold integers 1..4, not {kind}")
        return pa.chunked_array([pa.nulls(len(array), pa.int16())])
    out = ~np.isnan(numbers) & ((numbers < 1) | (numbers > MAX_POSITION))
    log.add_rows(out, column, lambda v: f"position {v:.0f} is outside 1..{MAX_POSITION}", numbers)
    keep = np.where(out, np.nan, numbers)
    return pa.chunked_array([pa.array(keep, pa.float64(), from_pandas=True).cast(pa.int16())])


# ---------------------------------------------------------------- validation


def _require_present(
    table: pa.Table, specs: list[ColumnSpec], names: Iterable[str], log: ErrorLog
) -> None:
    """Required values may not be null; cells already refused for another reason are skipped."""
    source = {spec.target: spec.source for spec in specs}
    for name in names:
        if name in table.column_names:
            missing = ~_mask(pc.is_valid(table[name]))
            if not missing.any():
                continue
            for index in np.flatnonzero(missing):
                if (int(index) + 1, source[name]) not in log.cells:
                    log.add(int(index) + 1, source[name], "value is missing")


# Physical bounds per quantity in its stored unit (app.signals): wider than any engine
# reaches (the built-in engine's hottest station, T48 at take-off on a hot day, reaches about
# 6200 degR; compressor delivery under 1000 psia, spools under 40000 rpm, fuel under 20 pps),
# narrow enough that a unit slip or a garbage value (1e308) is refused rather than stored.
QUANTITY_BOUNDS: dict[tuple[str, str], tuple[float, float]] = {
    ("temperature", "degR"): (0.0, 10000.0),
    ("pressure", "psia"): (0.0, 2000.0),
    ("rotational_speed", "rpm"): (0.0, 60000.0),
    ("mass_flow", "pps"): (0.0, 100.0),
    ("percent", "%"): (0.0, 200.0),
    ("length", "ft"): (-2000.0, 60000.0),
    ("dimensionless", "1"): (0.0, 1.0),
    ("temperature_difference", "K"): (-100.0, 100.0),
}


def signal_bounds(signal: SignalSpec) -> tuple[float | None, float | None]:
    """(low, high) of a stored signal: its own range within its quantity's physical bounds."""
    low, high = QUANTITY_BOUNDS.get((signal.quantity, signal.unit), (None, None))
    if signal.low is not None:
        low = signal.low if low is None else max(low, signal.low)
    if signal.high is not None:
        high = signal.high if high is None else min(high, signal.high)
    return low, high


def _convert_signals(
    columns: dict[str, pa.ChunkedArray], specs: list[ColumnSpec], log: ErrorLog
) -> None:
    """Convert declared units to stored units in place and check physical ranges."""
    for spec in specs:
        signal = SIGNAL_BY_NAME.get(spec.target)
        if signal is None:
            continue
        columns[spec.target] = convert_signal(
            columns[spec.target], spec.source, spec.unit or signal.unit, signal, log)


def convert_signal(
    values: pa.ChunkedArray | pa.Array,
    source: str,
    unit: str,
    signal: SignalSpec,
    log: ErrorLog,
    rows: np.ndarray | None = None,
) -> pa.ChunkedArray | pa.Array:
    """``values`` sent in ``unit`` as ``signal`` stores them (its unit), with its physical
    range checked; errors name the file column ``source``. ``rows`` (a boolean mask) limits
    both to those rows: the others are returned as given."""
    if unit != signal.unit:
        a, b = affine(signal.quantity, unit, signal.unit, reference=signal.percent_reference)
        converted = pc.add(pc.multiply(values, a), b)
        values = converted if rows is None else pc.if_else(pa.array(rows), converted, values)
    numbers = values.to_numpy(zero_copy_only=False)
    if rows is not None:
        numbers = np.where(rows, numbers, np.nan)
    shown = f" {signal.unit}" if signal.unit not in ("1", "%") else signal.unit
    low, high = signal_bounds(signal)
    if low is not None:
        with np.errstate(invalid="ignore"):
            below = numbers < low
        log.add_rows(
            below,
            source,
            lambda v, b=low, u=shown: f"{v:g}{u} is below {b:g}{u}",
            numbers,
        )
    if high is not None:
        with np.errstate(invalid="ignore"):
            above = numbers > high
        log.add_rows(
            above,
            source,
            lambda v, b=high, u=shown: f"{v:g}{u} is above the physical bound {b:g}{u}",
            numbers,
        )
    return values


def _check_duplicates(table: pa.Table, log: ErrorLog) -> None:
    """Two rows for one tail, position and time are one snapshot sent twice: refuse both."""
    if table.num_rows < 2:
        return
    tails = pc.dictionary_encode(table["tail"].combine_chunks()).indices
    keys = [
        np.asarray(tails.fill_null(-1).to_numpy(zero_copy_only=False), dtype=np.int64),
        np.asarray(pc.fill_null(table["position"], 0).to_numpy(zero_copy_only=False), np.int64),
        pc.fill_null(pc.cast(table["recorded_at"], pa.int64()), 0).to_numpy(zero_copy_only=False),
    ]
    complete = np.ones(table.num_rows, dtype=bool)
    for name in ("tail", "position", "recorded_at"):
        complete &= _mask(pc.is_valid(table[name]))
    order = np.flatnonzero(complete)
    if order.size < 2:
        return
    order = order[np.lexsort([k[order] for k in keys[::-1]])]
    sorted_keys = [k[order] for k in keys]
    same = np.ones(len(order) - 1, dtype=bool)
    for k in sorted_keys:
        same &= k[1:] == k[:-1]
    for i in np.flatnonzero(same):
        first, second = sorted((int(order[i]) + 1, int(order[i + 1]) + 1))
        log.add(
            second,
            "recorded_at",
            f"duplicate of row {first} (same tail, position and recorded_at)",
        )


def _build(
    columns: dict[str, pa.ChunkedArray],
    specs: list[ColumnSpec],
    *,
    kind: str,
    log: ErrorLog,
    by_type: bool = False,
) -> ParsedTable:
    """Coerce every raw column, validate, convert units and return the validated table."""
    coerced: dict[str, pa.ChunkedArray] = {}
    for spec in specs:
        raw = columns[spec.target]
        if spec.target == "recorded_at":
            coerced[spec.target] = coerce_timestamp(raw, spec.source, log)
        elif spec.target == "position":
            coerced[spec.target] = coerce_position(raw, spec.source, log)
        elif spec.target in ("tail", "flight_id"):
            coerced[spec.target] = coerce_string(raw, spec.source, log,
                                                 max_length=MAX_TEXT[spec.target])
        elif spec.target == "phase":
            phases = coerce_string(raw, spec.source, log)
            bad = ~_mask(pc.is_in(phases, pa.array(PHASES))) & _mask(pc.is_valid(phases))
            log.add_rows(
                bad,
                spec.source,
                lambda v: f"phase {v!r} is not one of {', '.join(PHASES)}",
                _string_values(phases),
            )
            coerced[spec.target] = phases
        else:
            coerced[spec.target] = coerce_float(raw, spec.source, log)
    table = pa.table(coerced)
    _require_present(table, specs, _required(kind, by_type), log)
    if not by_type:
        _convert_signals(coerced, specs, log)
        table = pa.table(coerced)
    if kind == "snapshots":
        _check_duplicates(table, log)
    else:
        _check_time_axis(table, log)
    if not by_type:
        return ParsedTable(table)
    signals = [s for s in specs if s.target not in _keys(kind)]
    return ParsedTable(table, {s.target: s.unit for s in signals},
                       {s.target: s.source for s in signals})


def _check_time_axis(table: pa.Table, log: ErrorLog) -> None:
    """Stream samples: time_s strictly increasing at one fixed rate."""
    if "time_s" not in table.column_names or table.num_rows < 2:
        return
    t = table["time_s"].to_numpy(zero_copy_only=False)
    steps = np.diff(t)
    log.add_rows(np.concatenate([[False], ~(steps > 0)]), "time_s", "time_s does not increase")
    if not (steps > 0).all():
        return
    dt = float(np.median(steps))
    if not STREAM_DT_MIN_S <= dt <= STREAM_DT_MAX_S:
        log.add(
            2, "time_s",
            f"sample interval {dt:g} s is outside {STREAM_DT_MIN_S:g} s to {STREAM_DT_MAX_S:g} s",
        )
        return
    off = np.abs(steps - dt) > 1e-6 * max(dt, 1.0) + 1e-9
    log.add_rows(
        np.concatenate([[False], off]),
        "time_s",
        lambda _v: f"step differs from the fixed sample interval {dt:g} s",
    )


# ---------------------------------------------------------------- formats


def _allowed(kind: str, by_type: bool = False) -> tuple[str, ...] | None:
    if by_type:
        return None
    signals = tuple(SIGNAL_BY_NAME)
    return (SNAPSHOT_KEYS + signals) if kind == "snapshots" else ("time_s",) + signals


def _required(kind: str, by_type: bool = False) -> tuple[str, ...]:
    if kind != "snapshots":
        # By type, the operating condition is required of a type scheduled on it only
        # (``uploads.parameters.check_stream``).
        return STREAM_KEYS if by_type else STREAM_REQUIRED
    return SNAPSHOT_REQUIRED_BY_TYPE if by_type else SNAPSHOT_REQUIRED


def _keys(kind: str) -> tuple[str, ...]:
    """The columns that are not signals."""
    return SNAPSHOT_KEYS if kind == "snapshots" else STREAM_KEYS


def _typed(target: str) -> pa.DataType:
    if target == "recorded_at":
        return UTC_MICROS
    if target in ("tail", "phase", "flight_id"):
        return pa.string()
    if target == "position":
        return pa.int16()
    return pa.float64()


def _finish(
    raw: dict[str, pa.ChunkedArray], specs: list[ColumnSpec], kind: str, log: ErrorLog,
    by_type: bool = False,
) -> ParsedTable:
    parsed: ParsedTable | None = None
    try:
        parsed = _build(raw, specs, kind=kind, log=log, by_type=by_type)
    except ErrorLimitReached:
        pass
    log.raise_if_any()
    assert parsed is not None
    return parsed


def parse_csv(
    body: bytes,
    *,
    kind: str = "snapshots",
    mapping: Mapping[str, str | None] | None = None,
    by_type: bool = False,
) -> ParsedTable:
    """CSV with a header line (comma separated, UTF-8)."""
    log = ErrorLog()
    if not body or body.isspace():  # neither copies the body
        raise UploadRejected([RowError(None, None, "the body is empty")])
    end = body.find(b"\n")
    try:
        first_line = body[: end if end >= 0 else len(body)].decode("utf-8-sig").rstrip("\r")
    except UnicodeDecodeError:
        raise UploadRejected([RowError(None, None, "the CSV header is not UTF-8")]) from None
    headers = next(csv.reader([first_line]), [])
    specs: list[ColumnSpec] = []
    try:
        specs = resolve_columns(
            headers, allowed=_allowed(kind, by_type), required=_required(kind, by_type),
            mapping=mapping, log=log, keys=_keys(kind),
        )
    except ErrorLimitReached:
        pass
    log.raise_if_any()
    if len(set(headers)) != len(headers):
        raise UploadRejected([RowError(None, None, "the CSV header repeats a column name")])
    wanted = {s.source for s in specs}
    read = pacsv.ReadOptions(use_threads=True, block_size=1 << 22)
    parse = pacsv.ParseOptions(newlines_in_values=False)

    def convert(types: Mapping[str, pa.DataType]) -> pacsv.ConvertOptions:
        return pacsv.ConvertOptions(
            column_types=dict(types),
            include_columns=[h for h in headers if h in wanted],
            null_values=[""],
            strings_can_be_null=True,
            quoted_strings_can_be_null=True,
        )

    fast = {s.source: _typed(s.target) for s in specs}
    try:
        table = pacsv.read_csv(io.BytesIO(body), read, parse, convert(fast))
    except pa.ArrowInvalid as exc:
        if "CSV conversion error" not in str(exc):
            reason = f"malformed CSV: {_arrow_reason(exc)}"
            raise UploadRejected([RowError(None, None, reason)]) from None
        # A value did not convert: read everything as text to name each bad cell.
        try:
            table = pacsv.read_csv(
                io.BytesIO(body), read, parse, convert({h: pa.string() for h in wanted})
            )
        except pa.ArrowInvalid as exc2:
            raise UploadRejected(
                [RowError(None, None, f"malformed CSV: {_arrow_reason(exc2)}")]
            ) from None
    if table.num_rows == 0:
        raise UploadRejected([RowError(None, None, "the CSV has a header but no rows")])
    raw = {s.target: table[s.source] for s in specs}
    return _finish(raw, specs, kind, log, by_type)


def _arrow_reason(exc: Exception) -> str:
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return text[:300]


def parse_parquet(
    body: bytes,
    *,
    kind: str = "snapshots",
    mapping: Mapping[str, str | None] | None = None,
    by_type: bool = False,
) -> ParsedTable:
    """Parquet; column names may carry ``[unit]``; timestamps must be tz-aware or zoned text."""
    log = ErrorLog()
    if not body:
        raise UploadRejected([RowError(None, None, "the body is empty")])
    try:
        table = pq.read_table(pa.BufferReader(body))
    except (pa.ArrowException, OSError, ValueError) as exc:
        raise UploadRejected(
            [RowError(None, None, f"malformed Parquet: {_arrow_reason(exc)}")]
        ) from None
    specs: list[ColumnSpec] = []
    try:
        specs = resolve_columns(
            table.column_names,
            allowed=_allowed(kind, by_type),
            required=_required(kind, by_type),
            mapping=mapping,
            log=log,
            keys=_keys(kind),
        )
    except ErrorLimitReached:
        pass
    log.raise_if_any()
    if table.num_rows == 0:
        raise UploadRejected([RowError(None, None, "the Parquet file has no rows")])
    raw = {s.target: table[s.source] for s in specs}
    return _finish(raw, specs, kind, log, by_type)


def _reject_constant(name: str) -> float:
    # NaN / Infinity literals parse as NaN/inf and are then refused with their row and column.
    return float(name.replace("Infinity", "inf"))


def parse_json(body: bytes, *, kind: str = "snapshots", by_type: bool = False) -> ParsedTable:
    """``{"units": {...}?, "columns": {...}?, "snapshots": [{...}, ...]}``."""
    if not body.strip():
        raise UploadRejected([RowError(None, None, "the body is empty")])
    try:
        document = json.loads(body, parse_constant=_reject_constant)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise UploadRejected([RowError(None, None, f"malformed JSON: {exc}")]) from None
    except RecursionError:
        raise UploadRejected([RowError(None, None, "malformed JSON: nested too deeply")]) from None
    records_key = "snapshots" if kind == "snapshots" else "samples"
    if not isinstance(document, dict) or not isinstance(document.get(records_key), list):
        raise UploadRejected(
            [RowError(None, None, f'the body must be an object with a "{records_key}" list')]
        )
    extra = set(document) - {records_key, "units", "columns"}
    if extra:
        raise UploadRejected(
            [RowError(None, name, f"unknown top-level key {name!r}") for name in sorted(extra)]
        )
    units = document.get("units") or {}
    mapping = document.get("columns") or {}
    if not isinstance(units, dict) or not all(isinstance(v, str) for v in units.values()):
        raise UploadRejected([RowError(None, "units", '"units" must map names to unit strings')])
    if not isinstance(mapping, dict):
        raise UploadRejected([RowError(None, "columns", '"columns" must be an object')])
    records = document[records_key]
    if not records:
        raise UploadRejected([RowError(None, None, f'"{records_key}" is empty')])
    log = ErrorLog()
    specs: list[ColumnSpec] = []
    raw: dict[str, pa.ChunkedArray] = {}
    try:
        for index, record in enumerate(records):
            if not isinstance(record, dict):
                log.add(index + 1, None, "each record must be a JSON object")
        log.raise_if_any()
        keys: dict[str, None] = {}
        for record in records:
            keys.update(dict.fromkeys(record))
        specs = resolve_columns(
            keys,
            allowed=_allowed(kind, by_type),
            required=_required(kind, by_type),
            mapping=mapping,
            units=units,
            log=log,
            keys=_keys(kind),
        )
        log.raise_if_any()
        raw = {s.target: _json_column(records, s, log) for s in specs}
    except ErrorLimitReached:
        log.raise_if_any()
    return _finish(raw, specs, kind, log, by_type)


def _json_column(records: list[dict[str, Any]], spec: ColumnSpec, log: ErrorLog) -> pa.ChunkedArray:
    values = [record.get(spec.source) for record in records]
    numeric = _typed(spec.target) in (pa.float64(), pa.int16())
    # The set of Python types in the column decides; pyarrow alone would take true as 1.0.
    allowed = {int, float, type(None)} if numeric else {str, type(None)}
    if set(map(type, values)) <= allowed:
        try:
            return pa.chunked_array(
                [pa.array(values, type=pa.float64() if numeric else pa.string())]
            )
        except (pa.ArrowInvalid, OverflowError, UnicodeEncodeError):
            pass  # an integer beyond 64 bits or a lone surrogate: found value by value below
    return pa.chunked_array([_json_column_with_errors(values, spec, numeric, log)])


def _json_column_with_errors(
    values: list[Any], spec: ColumnSpec, numeric: bool, log: ErrorLog
) -> pa.Array:
    expect: tuple[type, ...] = (int, float) if numeric else (str,)
    word = "a number" if numeric else "text"
    clean: list[Any] = []
    for index, value in enumerate(values):
        ok = value is None or (isinstance(value, expect) and not isinstance(value, bool))
        if not ok:
            log.add(index + 1, spec.source, f"{_shown(value)} is not {word}")
        elif isinstance(value, int):
            try:
                value = float(value)
            except OverflowError:
                log.add(index + 1, spec.source, f"{_shown(value)} is out of range")
                ok, value = False, None
        elif isinstance(value, str) and not _encodable(value):
            log.add(index + 1, spec.source, "is not valid Unicode text (a lone surrogate)")
            ok, value = False, None
        clean.append(value if ok else None)
    return pa.array(clean, type=pa.float64() if numeric else pa.string())


def _encodable(text: str) -> bool:
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def _shown(value: Any, limit: int = 40) -> str:
    """A value as the error message quotes it: JSON, cut to ``limit`` characters."""
    try:
        text = json.dumps(value)
    except (ValueError, TypeError):
        text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def parse_body(
    body: bytes,
    content_format: str,
    *,
    kind: str = "snapshots",
    mapping: Mapping[str, str | None] | None = None,
    by_type: bool = False,
) -> ParsedTable:
    """Dispatch on the body's format: ``csv``, ``json`` or ``parquet``. ``by_type``: signals
    are left in the units sent, for ``uploads.parameters``."""
    if content_format == "csv":
        return parse_csv(body, kind=kind, mapping=mapping, by_type=by_type)
    if content_format == "parquet":
        return parse_parquet(body, kind=kind, mapping=mapping, by_type=by_type)
    if content_format == "json":
        return parse_json(body, kind=kind, by_type=by_type)
    raise UploadRejected([RowError(None, None, f"unsupported format {content_format!r}")])
