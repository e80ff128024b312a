"""Snapshot rows checked against the parameter set of their engine's type.

Once each row is resolved to the engine installed at its tail, position and time, the row's
engine type decides (``fleet.parameter_sets``): which signal columns it may carry (a value in
a column the type does not have refuses the upload, naming the column and the type), which
columns it must carry (the operating condition and ``phase`` when the type's models are
scheduled on them), and the unit of each signal (the model file's, for a signal outside the
catalogue). Values are converted to the unit they are stored in and their physical range is
checked, type by type, so one upload may hold engines of two types.

A stream recording is one engine's samples: ``check_stream`` checks and converts them against
that engine's type the same way (``time_s``, which every sample carries, the parser requires;
the operating-condition columns are required of a type scheduled on them, on every sample, and
of no other: a single-point type's steady windows are found on its own signals,
``streams.steady``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.models import Engine
from app.services.fleet.parameter_sets import (
    CONDITIONS,
    ParameterSet,
    parameter_sets,
    stored_spec,
)
from app.services.units import UnknownUnitError, affine
from app.services.uploads.parse import (
    ErrorLimitReached,
    ErrorLog,
    ParsedTable,
    convert_signal,
)
from app.signals import SignalSpec


@dataclass(frozen=True)
class TypedRows:
    """Rows converted to stored units, and the parameter set of each engine type among them."""

    table: pa.Table
    types: dict[int, ParameterSet]


def _valid(table: pa.Table, name: str) -> np.ndarray:
    return np.asarray(pc.fill_null(pc.is_valid(table[name]), False).to_numpy(
        zero_copy_only=False), dtype=bool)


def check_parameters(session: Session, rows: pa.Table, parsed: ParsedTable) -> TypedRows:
    """``rows`` (resolved: with ``engine_id``) checked and converted per engine type; an
    ``UploadRejected`` names every refused column, row and type (nothing is stored)."""
    engine_ids = rows["engine_id"].to_numpy(zero_copy_only=False)
    unique = np.unique(engine_ids)
    type_of_engine: dict[int, int] = {engine_id: type_id for engine_id, type_id in session.execute(
        select(Engine.id, Engine.engine_type_id).where(Engine.id.in_(unique.tolist())))}
    row_types = np.array([type_of_engine[int(e)] for e in unique], dtype=np.int64)[
        np.searchsorted(unique, engine_ids)]
    types = parameter_sets(session, sorted(set(row_types.tolist())))
    masks = {type_id: row_types == type_id for type_id in types}
    return TypedRows(_checked(rows, parsed, types, masks, kind="snapshots"), types)


def check_stream(session: Session, engine_type_id: int, parsed: ParsedTable) -> ParsedTable:
    """A stream's samples (one engine, of type ``engine_type_id``) checked and converted to
    their stored units; an ``UploadRejected`` names each column the type does not have, and
    each operating-condition column it is scheduled on that the samples lack."""
    types = parameter_sets(session, [engine_type_id])
    masks = {engine_type_id: np.ones(parsed.num_rows, dtype=bool)}
    table = _checked(parsed.table, parsed, types, masks, kind="stream")
    return ParsedTable(table, parsed.units, parsed.sources)


def _checked(
    table: pa.Table, parsed: ParsedTable, types: dict[int, ParameterSet],
    masks: dict[int, np.ndarray], *, kind: str,
) -> pa.Table:
    log = ErrorLog()
    try:
        _check_columns(table, parsed, types, masks, log)
        _check_required(table, parsed, types, masks, kind, log)
        log.raise_if_any()
        table = _convert(table, parsed, types, masks, log)
    except ErrorLimitReached:
        pass
    log.raise_if_any()
    return table


def _check_columns(
    table: pa.Table, parsed: ParsedTable, types: dict[int, ParameterSet],
    masks: dict[int, np.ndarray], log: ErrorLog,
) -> None:
    """A value in a column its row's type does not have refuses the upload."""
    for name, source in parsed.sources.items():
        valid = _valid(table, name)
        known_by_any = False
        for type_id, params in types.items():
            if params.knows(name):
                known_by_any = True
                continue
            carried = np.flatnonzero(valid & masks[type_id])
            if carried.size:
                log.add(None, source,
                        f"unknown column {name!r} for engine type {params.engine_type!r}: "
                        f"not one of its parameters ({_listed(params)}); row "
                        f"{int(carried[0]) + 1} and {carried.size - 1} more rows of this type "
                        "carry it")
        if not known_by_any and not valid.any():
            names = ", ".join(repr(p.engine_type) for p in types.values())
            log.add(None, source, f"unknown column {name!r} for engine type {names}: not one "
                                  "of its parameters")


def _listed(params: ParameterSet) -> str:
    return ", ".join(params.names[:16]) + (" ..." if len(params.names) > 16 else "")


def _check_required(
    table: pa.Table, parsed: ParsedTable, types: dict[int, ParameterSet],
    masks: dict[int, np.ndarray], kind: str, log: ErrorLog,
) -> None:
    """The operating condition (and a snapshot's phase) of a type scheduled on them, on each
    of its rows."""
    sources = {"phase": "phase", **parsed.sources}
    for type_id, params in types.items():
        for name in params.required(kind):
            if name not in table.column_names:
                log.add(None, name, f"required column {name!r} is missing (engine type "
                                    f"{params.engine_type!r} is scheduled on it)")
                continue
            missing = masks[type_id] & ~_valid(table, name)
            for index in np.flatnonzero(missing):
                if (int(index) + 1, sources.get(name, name)) not in log.cells:
                    log.add(int(index) + 1, sources.get(name, name), "value is missing")


def _convert(
    table: pa.Table, parsed: ParsedTable, types: dict[int, ParameterSet],
    masks: dict[int, np.ndarray], log: ErrorLog,
) -> pa.Table:
    """Each signal column in its stored unit, converted from the declared unit. An undeclared
    unit is the stored one: the catalogue's for a catalogue signal (as every upload has
    meant it), the model file's for any other."""
    for name, source in parsed.sources.items():
        values = table[name]
        for type_id, params in types.items():
            spec = params.signal(name) or CONDITIONS.get(name)
            if spec is None:
                continue  # refused above wherever a row of this type carries a value
            stored = stored_spec(spec) if name not in CONDITIONS else spec
            unit = parsed.units.get(name) or stored.unit
            if not _converts(name, source, unit, stored, params, log):
                continue
            values = convert_signal(values, source, unit, stored, log, rows=masks[type_id])
        index = table.column_names.index(name)
        table = table.set_column(index, name, values)
    return table


def _converts(
    name: str, source: str, unit: str, stored: SignalSpec, params: ParameterSet, log: ErrorLog
) -> bool:
    if unit == stored.unit:
        return True
    try:
        affine(stored.quantity, unit, stored.unit, reference=stored.percent_reference)
    except UnknownUnitError as exc:
        reason = (str(exc) if stored.quantity else
                  f"engine type {params.engine_type!r} takes {name!r} in {stored.unit!r} "
                  f"only (not {unit!r})")
        log.add(None, source, reason)
        return False
    return True
