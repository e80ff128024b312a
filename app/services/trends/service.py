"""Trends per engine serial number and per tail: estimates over time, decimated, JSON or CSV.

An engine's trend is its estimates under one design (the engine type's active design unless
another is asked for), in time order, each signal with its 1-sigma band. A long history is
decimated into at most ``max_points`` buckets of consecutive records; each bucket keeps the
mean and the min/max envelope of every signal, so a spike survives decimation. A tail's trend is
the union over its installations: each engine's trend cut to the period it sat on that tail.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from typing import Any

import numpy as np
from sqlalchemy import (
    Float,
    Integer,
    String,
    and_,
    cast,
    func,
    literal,
    literal_column,
    null,
    select,
    type_coerce,
    union_all,
)
from sqlalchemy.orm import Session

from app.errors import InvalidInput, NotFound
from app.models import (
    Aircraft,
    Engine,
    EngineType,
    EstimatorDesign,
    Installation,
    MaintenanceAction,
    Snapshot,
    Upload,
)
from app.models.estimates import (
    BLOCKS,
    STORED_PHASES,
    Estimate,
    EstimateLayout,
    Event,
    FilterState,
)
from app.services.common import json_numbers_or_null
from app.services.designs import calibration
from app.services.encoding import json_numbers
from app.services.encoding.json_numbers import RawJSON
from app.services.encoding.pgcopy import PG_EPOCH_US
from app.services.fleet.performance import SERIES_OF_AUX
from app.services.snapshots import estimator
from app.services.trends import health as health_view
from app.services.trends.performance import performance_group
from estimation import uncertainty

# Why a trend has no ``performance`` group (a design of another engine type than the built-in).
PERFORMANCE_NOTE = (
    "EGT margin, ΔEGT, thrust in engineering units and stall margins are computed from the "
    "built-in engine's nonlinear model; this engine's type is not the built-in engine, so its "
    "trend has the estimates of its own model only (health parameters, auxiliary outputs, "
    "residuals, WSSR)."
)
# Trend groups as the dashboard draws them: (key, value block, sigma block, names group, label).
GROUPS = (
    ("tuners", "q", "q_sigma", "tuners", "Tuners"),
    ("health", "h", "h_sigma", "health", "Health parameters"),
    ("aux", "z", "z_sigma", "aux", "Auxiliary outputs"),
    ("residuals", "residual", None, "sensors", "Sensor residuals"),
    ("wssr", "wssr", None, "faults", "WSSR per fault hypothesis"),
)
DEFAULT_UNITS = {"tuners": "%", "health": "%", "aux": "%", "sensors": "%", "faults": "1"}
DEFAULT_MAX_POINTS = 500


@dataclass(frozen=True)
class TrendData:
    """Decoded estimates of one engine and design, in time order (not decimated).

    epoch : (n,) seconds since 1970 UTC; seq : (n,) record numbers; phase : n strings;
    values : (n, width) per ``layout``, float64 as decoded from the stored form
    (``EstimateLayout.decode``; bucket means, minima and maxima are taken from them).
    """

    layout: EstimateLayout
    epoch: np.ndarray
    seq: np.ndarray
    phase: list[str]
    values: np.ndarray


def epoch_seconds(session: Session) -> Any:
    """recorded_at as seconds since 1970 computed by the database: no datetime object per row."""
    if session.get_bind().dialect.name == "sqlite":
        # SQLite keeps UTC text; julianday keeps the fraction of a second.
        return (func.julianday(Estimate.__table__.c.recorded_at) - 2440587.5) * 86400.0
    return cast(func.extract("epoch", Estimate.__table__.c.recorded_at), Float)


def to_json(document: Any) -> bytes:
    """JSON bytes of a trend or status dict (timestamps as ISO 8601 UTC).

    Routes send these bytes directly: the dicts are built to the response models' shape, and
    validating half a million floats again would cost more than building them.
    """
    return json_numbers.dumps(document, _json_default)


def _json_default(value: Any) -> Any:
    if isinstance(value, datetime):
        return value.astimezone(UTC).isoformat().replace("+00:00", "Z")
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"cannot encode {type(value).__name__} as JSON")


def _iso(epoch: float) -> str:
    return datetime.fromtimestamp(float(epoch), UTC).isoformat().replace("+00:00", "Z")


def _iso_list(epoch: np.ndarray) -> list[str]:
    """``[_iso(t) for t in epoch]``; whole seconds (the usual case) formatted by numpy."""
    if len(epoch) and np.all(np.floor(epoch) == epoch) and np.all(np.abs(epoch) < 2.5e11):
        text = np.datetime_as_string(epoch.astype(np.int64).astype("datetime64[s]"))
        return [f"{t}Z" for t in text.tolist()]
    return [_iso(t) for t in epoch]


def get_engine(session: Session, operator_id: int, engine_id: int) -> Engine:
    engine = session.get(Engine, engine_id)
    if engine is None or engine.operator_id != operator_id:
        raise NotFound(f"engine {engine_id} not found")
    return engine


def resolve_design(
    session: Session, operator_id: int, engine: Engine, design_id: int | None
) -> EstimatorDesign | None:
    """The design to show: ``design_id`` if given, else the engine type's active design, else
    the design of the engine's most recently updated filter state (None: nothing estimated)."""
    if design_id is not None:
        design = session.get(EstimatorDesign, design_id)
        if design is None or design.operator_id != operator_id:
            raise NotFound(f"design {design_id} not found")
        return design
    design = session.scalar(
        select(EstimatorDesign).where(
            EstimatorDesign.engine_type_id == engine.engine_type_id,
            EstimatorDesign.active.is_(True),
        )
    )
    if design is not None:
        return design
    state = session.scalar(
        select(FilterState)
        .where(FilterState.engine_id == engine.id)
        .order_by(FilterState.updated_at.desc(), FilterState.id.desc())
        .limit(1)
    )
    return None if state is None else session.get(EstimatorDesign, state.design_id)


@dataclass(frozen=True)
class TrendTarget:
    """What a trend shows: the engine, its type's name and the design (None: not estimated);
    ``layout`` is the filter state's layout document when already read (None: read it)."""

    engine_id: int
    esn: str
    engine_type: str
    design_id: int | None
    design_name: str | None
    layout: dict[str, Any] | None = None


def trend_target(
    session: Session, operator_id: int, engine_id: int, design_id: int | None
) -> TrendTarget:
    """The engine and design of a trend. With the engine type's active design (the usual
    case), one query reads the engine, its type, the design and the layout; otherwise
    ``get_engine`` and ``resolve_design`` decide."""
    if design_id is None:
        e, t = Engine.__table__, EngineType.__table__
        d, f = EstimatorDesign.__table__, FilterState.__table__
        row = session.connection().execute(
            select(e.c.operator_id, e.c.esn, t.c.name, d.c.id, d.c.name, f.c.layout)
            .join(t, t.c.id == e.c.engine_type_id)
            .outerjoin(d, and_(d.c.engine_type_id == e.c.engine_type_id, d.c.active.is_(True)))
            .outerjoin(f, and_(f.c.engine_id == e.c.id, f.c.design_id == d.c.id))
            .where(e.c.id == engine_id)
            .limit(1)
        ).first()
        if row is None or row[0] != operator_id:
            raise NotFound(f"engine {engine_id} not found")
        if row[3] is not None:
            return TrendTarget(engine_id, row[1], row[2], row[3], row[4], row[5])
    engine = get_engine(session, operator_id, engine_id)
    design = resolve_design(session, operator_id, engine, design_id)
    return TrendTarget(
        engine.id, engine.esn, engine.engine_type.name,
        None if design is None else design.id, None if design is None else design.name,
    )


def load_trend_data(
    session: Session,
    engine_id: int,
    design_id: int,
    start: datetime | None = None,
    end: datetime | None = None,
    layout_doc: dict[str, Any] | None = None,
) -> TrendData | None:
    """Estimates of one engine and design in ``[start, end)``; None when never estimated.

    ``layout_doc``: the filter state's layout when the caller has read it already.
    """
    if layout_doc is None:
        layout_doc = session.scalar(
            select(FilterState.layout).where(
                FilterState.engine_id == engine_id, FilterState.design_id == design_id
            )
        )
    if layout_doc is None:
        return None
    layout = EstimateLayout.from_dict(layout_doc)
    table = Estimate.__table__
    conditions = [table.c.engine_id == engine_id, table.c.design_id == design_id]
    if start is not None:
        conditions.append(table.c.recorded_at >= start)
    if end is not None:
        conditions.append(table.c.recorded_at < end)
    if session.get_bind().dialect.name == "postgresql":
        return _load_aggregated(session, layout, engine_id, design_id, start, end)
    # Core columns on the connection: no ORM row processing for ten thousand rows.
    query = (
        select(epoch_seconds(session), table.c.seq, table.c.packed)
        .where(*conditions)
        .order_by(table.c.seq)
    )
    rows = session.connection().execute(query).all()
    if not rows:
        return TrendData(layout, np.empty(0), np.empty(0, int), [], np.empty((0, layout.width)))
    recorded, seq, blobs = zip(*rows, strict=True)
    decoded = layout.decode(b"".join(blobs), len(blobs))
    return TrendData(
        layout=layout,
        epoch=np.asarray(recorded, dtype=float),
        seq=np.asarray(seq, dtype=np.int64),
        phase=_PHASE_NAMES[decoded.phase].tolist(),
        values=decoded.values,
    )


# PostgreSQL: the whole trend as one row of two values: each record's seq and time in their
# binary send formats (fixed width), and every blob (the phase is in it), each concatenated.
# The aggregates carry no ORDER BY: each would sort the rows again, while all aggregates of one
# query see the rows in the same order, so the two stay aligned and numpy puts them in seq
# order. (Arrays of seq and time cost twice as much: building and parsing arrays.)
_AGGREGATE_SQL = (
    "SELECT string_agg(int4send(seq) || timestamptz_send(recorded_at), ''::bytea), "
    "string_agg(packed, ''::bytea) FROM estimates "
    "WHERE engine_id = %(engine_id)s AND design_id = %(design_id)s"
)
_RECORD = np.dtype([("seq", ">i4"), ("micros", ">i8")])
_PHASE_NAMES = np.array(STORED_PHASES, dtype=object)


def _load_aggregated(
    session: Session, layout: EstimateLayout, engine_id: int, design_id: int,
    start: datetime | None, end: datetime | None,
) -> TrendData:
    """PostgreSQL: one row read in the binary protocol, two values parsed by numpy."""
    sql = _AGGREGATE_SQL
    params: dict[str, Any] = {"engine_id": engine_id, "design_id": design_id}
    if start is not None:
        sql += " AND recorded_at >= %(start)s"
        params["start"] = start
    if end is not None:
        sql += " AND recorded_at < %(end)s"
        params["end"] = end
    driver = session.connection().connection.driver_connection
    with driver.cursor(binary=True) as cursor:  # type: ignore[union-attr]
        cursor.execute(sql, params)
        keys, packed = cursor.fetchone()
    if not keys:
        return TrendData(layout, np.empty(0), np.empty(0, int), [], np.empty((0, layout.width)))
    records = np.frombuffer(keys, dtype=_RECORD)
    seq = records["seq"].astype(np.int64)
    epoch = (records["micros"].astype(np.int64) + PG_EPOCH_US) / 1e6
    decoded = layout.decode(bytes(packed), len(seq))
    values, codes = decoded.values, decoded.phase
    order = None if np.all(seq[1:] > seq[:-1]) else np.argsort(seq, kind="stable")
    if order is not None:
        seq, epoch, values, codes = seq[order], epoch[order], values[order], codes[order]
    return TrendData(
        layout=layout,
        epoch=epoch,
        seq=seq,
        phase=_PHASE_NAMES[codes].tolist(),
        values=values,
    )


def stream_records(session: Session, engine_id: int, epoch: np.ndarray) -> list[int | None]:
    """Per record (times ``epoch``, seconds since 1970 UTC): the recording whose steady
    window it summarises (``streams.steady``: its upload belongs to a recording), else None.
    One query over the engine's records in the time range, joined to their uploads."""
    out: list[int | None] = [None] * len(epoch)
    if not len(epoch):
        return out
    lo = datetime.fromtimestamp(float(np.min(epoch)) - 1.0, UTC)
    hi = datetime.fromtimestamp(float(np.max(epoch)) + 1.0, UTC)
    rows = session.execute(
        select(Snapshot.recorded_at, Upload.recording_id)
        .join(Upload, Upload.id == Snapshot.upload_id)
        .where(Snapshot.engine_id == engine_id, Snapshot.recorded_at >= lo,
               Snapshot.recorded_at <= hi, Upload.recording_id.is_not(None))
    ).all()
    if not rows:
        return out
    by_ms = {round(t.timestamp() * 1000.0): int(r) for t, r in rows}
    keys = np.round(np.asarray(epoch, float) * 1000.0).astype(np.int64).tolist()
    return [by_ms.get(k) for k in keys]


def bucket_recordings(recording: list[int | None], starts: np.ndarray | None) -> list[int | None]:
    """The recording of each point: a bucket keeps it when all its records share it."""
    if starts is None:
        return recording
    ends = np.append(starts[1:], len(recording)).tolist()
    out = []
    for a, b in zip(starts.tolist(), ends, strict=True):
        first = recording[a]
        out.append(first if all(r == first for r in recording[a:b]) else None)
    return out


def decimate(n: int, max_points: int) -> np.ndarray | None:
    """Start indices of at most ``max_points`` equal-count buckets of n records (None: keep
    every record)."""
    if max_points <= 0 or n <= max_points:
        return None
    return np.unique(np.floor(np.arange(max_points) * (n / max_points)).astype(np.int64))


def _series_columns(
    data: TrendData, starts: np.ndarray | None
) -> tuple[dict[str, Any], np.ndarray | None, np.ndarray | None]:
    """Per-point time/seq/phase columns and the bucket mean, min and max of every value."""
    if starts is None:
        columns = {
            "time": _iso_list(data.epoch),
            "seq": data.seq.tolist(),
            "phase": data.phase,
        }
        return columns, None, None
    counts = np.diff(np.append(starts, len(data.epoch)))
    mean_epoch = np.add.reduceat(data.epoch, starts) / counts
    mean_seq = np.add.reduceat(data.seq.astype(float), starts) / counts
    # A bucket keeps its phase when all its records share it: no phase change inside it.
    phase = np.asarray(data.phase)
    changes = np.concatenate(([0], np.cumsum(phase[1:] != phase[:-1])))
    ends = np.append(starts[1:], len(phase)) - 1
    same = (changes[starts] == changes[ends]).tolist()
    phases = [data.phase[i] if one else None for i, one in zip(starts.tolist(), same,
                                                                strict=True)]
    columns = {
        "time": _iso_list(mean_epoch),
        "seq": np.round(mean_seq, 1).tolist(),
        "phase": phases,
    }
    lo = np.minimum.reduceat(data.values, starts, axis=0)
    hi = np.maximum.reduceat(data.values, starts, axis=0)
    return columns, lo, hi


def _lists(matrix: np.ndarray) -> list[Any]:
    """Each row of ``matrix`` as a list of JSON numbers (the dict a caller reads)."""
    return [json_numbers_or_null(row) for row in matrix]


def _encoded(matrix: np.ndarray) -> list[Any]:
    """Each row of ``matrix`` as pre-encoded JSON text, equal to ``_lists`` once encoded."""
    return [RawJSON(text) for text in json_numbers.float_rows(matrix, 4)]


def band_state(calib: uncertainty.Calibration | None, group: str) -> str:
    """What the bands of a tuners, aux or performance group are (``TrendGroup.uncertainty``):
    calibrated, uncalibrated (no calibration), or recalibrate (a calibration stored before
    the group's figures were calibrated)."""
    if calib is None:
        return "uncalibrated"
    held = {"tuners": calib.tuner_names,
            # the aux outputs: their sigma and their calibrated values
            "aux": calib.aux_names if calib.aux_correction is not None else (),
            "performance": calib.delta_names}[group]
    return "calibrated" if held else "recalibrate"


def trend_groups(
    data: TrendData, starts: np.ndarray | None, columns_of: Any = _lists
) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """Columns shared by all series, and the groups of series (mean, sigma, min, max).

    ``columns_of`` turns a (k, points) matrix into k series columns: lists (``_lists``) or
    JSON text for the routes (``_encoded``).
    """
    columns, lo, hi = _series_columns(data, starts)
    if starts is None:
        values = data.values
    else:
        counts = np.diff(np.append(starts, len(data.epoch)))
        with np.errstate(invalid="ignore"):
            values = (
                np.add.reduceat(data.values, starts, axis=0, dtype=np.float64) / counts[:, None]
            )
    slices = data.layout.slices()
    # Every column that goes out, encoded in one call: row r of ``wanted`` is column r.
    picks: list[np.ndarray] = []
    n_rows = 0

    def take(matrix: np.ndarray, cols: list[int]) -> int:
        nonlocal n_rows
        picks.append(matrix[:, cols].T)
        n_rows += len(cols)
        return n_rows - len(cols)

    layout_groups = []
    for key, block, sigma_block, names_group, label in GROUPS:
        names = data.layout.names(names_group)
        units = data.layout.units.get(names_group) or [DEFAULT_UNITS[names_group]] * len(names)
        cols = [slices[block].start + j for j in range(len(names))]
        rows = {"value": take(values, cols)}
        if sigma_block is not None:
            rows["sigma"] = take(values, [slices[sigma_block].start + j for j in range(len(names))])
        if lo is not None and hi is not None:
            rows["min"] = take(lo, cols)
            rows["max"] = take(hi, cols)
        layout_groups.append((key, label, names, units, rows))
    wanted = np.concatenate(picks, axis=0, dtype=np.float64) if picks else np.empty((0, 0))
    encoded = columns_of(wanted)
    groups = []
    for key, label, names, units, rows in layout_groups:
        series = []
        for j, name in enumerate(names):
            item: dict[str, Any] = {
                "name": name, "unit": units[j], "value": None, "sigma": None, "min": None,
                "max": None,
            }
            for field_name, first_row in rows.items():
                item[field_name] = encoded[first_row + j]
            series.append(item)
        groups.append({"key": key, "label": label, "series": series})
    return columns, groups


def _markers(
    session: Session, engine_id: int, design_id: int | None
) -> dict[str, list[dict[str, Any]]]:
    """Installations, maintenance actions and events of the engine, each in time order, read
    with one UNION ALL (one round trip instead of three); ``tag`` says which is which."""
    text_null = type_coerce(null(), String())
    int_null = type_coerce(null(), Integer())
    installs = (
        select(
            literal(0, Integer()).label("tag"), Aircraft.id.label("id"),
            Installation.installed_at.label("t1"), Installation.removed_at.label("t2"),
            Installation.position.label("n"), Aircraft.tail.label("s1"),
            text_null.label("s2"), text_null.label("s3"),
        )
        .join(Aircraft, Aircraft.id == Installation.aircraft_id)
        .where(Installation.engine_id == engine_id)
    )
    maintenance = select(
        literal(1, Integer()), MaintenanceAction.id, MaintenanceAction.performed_at, null(),
        int_null, MaintenanceAction.kind, MaintenanceAction.notes, text_null,
    ).where(MaintenanceAction.engine_id == engine_id)
    events = select(
        literal(2, Integer()), Event.id, Event.detected_at, null(), Event.seq, Event.kind,
        Event.fault, Event.status,
    ).where(Event.engine_id == engine_id)
    if design_id is not None:
        events = events.where(Event.design_id == design_id)
    query: Any = union_all(installs, maintenance, events).order_by(
        literal_column("tag"), literal_column("t1"), literal_column("id")
    )
    out: dict[str, list[dict[str, Any]]] = {"installations": [], "maintenance": [], "events": []}
    for tag, row_id, t1, t2, n, s1, s2, s3 in session.execute(query).all():
        if tag == 0:
            out["installations"].append(
                {"aircraft_id": row_id, "tail": s1, "position": n, "installed_at": t1,
                 "removed_at": t2}
            )
        elif tag == 1:
            out["maintenance"].append(
                {"id": row_id, "kind": s1, "performed_at": t1, "notes": s2}
            )
        else:
            out["events"].append(
                {"id": row_id, "detected_at": t1, "kind": s1, "fault": s2, "status": s3,
                 "seq": n}
            )
    return out


def _check_range(start: datetime | None, end: datetime | None) -> None:
    for name, value in (("start", start), ("end", end)):
        if value is not None and value.tzinfo is None:
            raise InvalidInput(
                f"{name} must carry a time zone",
                details=[{"row": None, "column": name, "reason": "naive timestamp"}],
            )
    if start is not None and end is not None and end <= start:
        raise InvalidInput(
            "end must be after start",
            details=[{"row": None, "column": "end", "reason": "end <= start"}],
        )


def engine_trend(
    session: Session,
    operator_id: int,
    engine_id: int,
    *,
    design_id: int | None = None,
    start: datetime | None = None,
    end: datetime | None = None,
    max_points: int = DEFAULT_MAX_POINTS,
    markers: bool = True,
    columns_of: Any = _lists,
    health: str = "level",
    settle: int = health_view.BASELINE_SETTLE_RECORDS,
) -> dict[str, Any]:
    """The trend of one engine as a dict shaped like ``app.schemas.estimates.EngineTrend``.

    ``columns_of=_encoded`` (``engine_trend_json``) leaves the series as JSON text.
    ``health``: the health group as levels with their honest sigma ("level") or as the change
    since the engine's baseline ("change"; ``settle`` records after a reset), see
    ``trends.health``.
    """
    _check_range(start, end)
    if health not in health_view.HEALTH_VIEWS:
        raise InvalidInput(
            f"health must be one of {', '.join(health_view.HEALTH_VIEWS)}",
            details=[{"row": None, "column": "health", "reason": f"unknown view {health!r}"}],
        )
    target = trend_target(session, operator_id, engine_id, design_id)
    data = None
    meta = None
    if target.design_id is not None:
        # A change needs its baseline, which may lie before ``start``: read from the first
        # record and cut afterwards.
        data = load_trend_data(
            session, target.engine_id, target.design_id,
            start if health == "level" else None, end, target.layout,
        )
    calib = None
    if data is not None and len(data.epoch) and target.design_id is not None:
        calib = calibration.design_calibration(session, target.design_id)
        resets = (health_view.baseline_resets(session, target.engine_id)
                  if health == "change" else None)
        values, meta = health_view.apply(
            data.values, data.layout.slices(), data.layout.names("health"), calib,
            "change" if health == "change" else "level", data.epoch, data.phase, resets,
            settle, data.layout.names("aux"), data.layout.names("tuners"),
        )
        data = replace(data, values=values)
        if health == "change" and start is not None:
            keep = data.epoch >= start.timestamp()
            data = replace(data, epoch=data.epoch[keep], seq=data.seq[keep],
                           phase=[p for p, k in zip(data.phase, keep, strict=True) if k],
                           values=data.values[keep])
    out: dict[str, Any] = {
        "engine_id": target.engine_id,
        "esn": target.esn,
        "engine_type": target.engine_type,
        "design_id": target.design_id,
        "design_name": target.design_name,
        "start": start,
        "end": end,
        "n_records": 0,
        "n_points": 0,
        "decimated": False,
        "time": [],
        "seq": [],
        "phase": [],
        "recording": [],
        "groups": [],
        "performance_note": None,
    }
    if data is not None and len(data.epoch):
        starts = decimate(len(data.epoch), max_points)
        columns, groups = trend_groups(data, starts, columns_of)
        columns["recording"] = bucket_recordings(
            stream_records(session, target.engine_id, data.epoch), starts)
        if meta is not None:
            for group in groups:
                if group["key"] == "health":
                    group.update(meta.to_dict())
                elif group["key"] in ("tuners", "aux"):
                    group["uncertainty"] = band_state(calib, group["key"])
                if group["key"] == "aux":
                    group["calibrated_series"] = [] if calib is None else calib.aux_corrected
                if group["key"] == "tuners":
                    group["unobservable"] = list(meta.tuners_unobservable)
                    group["calibrated_series"] = list(meta.tuners_calibrated)
        assert target.design_id is not None
        extra = performance_group(
            session, target.engine_id, target.design_id, data.layout, data.epoch, data.values,
            starts, columns_of, calib,
        )
        if extra is not None:
            extra["uncertainty"] = band_state(calib, "performance")
            extra["calibrated_series"] = [
                series for name in ([] if calib is None else calib.aux_corrected)
                for series in SERIES_OF_AUX.get(name, ())]
            groups.append(extra)
        elif estimator.builtin_schedule_for_design(session, target.design_id) is None:
            out["performance_note"] = PERFORMANCE_NOTE
        out.update(columns)
        out.update(
            n_records=len(data.epoch),
            n_points=len(columns["time"]),
            decimated=starts is not None,
            groups=groups,
        )
    if markers:
        out.update(_markers(session, target.engine_id, target.design_id))
    else:
        out.update(installations=[], maintenance=[], events=[])
    return out


def aircraft_trend(
    session: Session,
    operator_id: int,
    aircraft_id: int,
    *,
    start: datetime | None = None,
    end: datetime | None = None,
    max_points: int = DEFAULT_MAX_POINTS,
    columns_of: Any = _lists,
) -> dict[str, Any]:
    """The union over a tail's installations: each engine's trend cut to its time there."""
    _check_range(start, end)
    aircraft = session.get(Aircraft, aircraft_id)
    if aircraft is None or aircraft.operator_id != operator_id:
        raise NotFound(f"aircraft {aircraft_id} not found")
    installs = session.scalars(
        select(Installation)
        .where(Installation.aircraft_id == aircraft.id)
        .order_by(Installation.position, Installation.installed_at)
    ).all()
    segments = []
    for inst in installs:
        seg_start = max(filter(None, (start, inst.installed_at)))
        ends = [t for t in (end, inst.removed_at) if t is not None]
        seg_end = min(ends) if ends else None
        if seg_end is not None and seg_end <= seg_start:
            continue
        trend = engine_trend(
            session, operator_id, inst.engine_id, start=seg_start, end=seg_end,
            max_points=max_points, markers=False, columns_of=columns_of,
        )
        segments.append(
            {
                "position": inst.position,
                "installed_at": inst.installed_at,
                "removed_at": inst.removed_at,
                "trend": trend,
            }
        )
    return {"aircraft_id": aircraft.id, "tail": aircraft.tail, "start": start, "end": end,
            "segments": segments}


def engine_trend_json(
    session: Session, operator_id: int, engine_id: int, **options: Any
) -> bytes:
    """``to_json(engine_trend(...))`` with the series numbers written by numpy."""
    return to_json(engine_trend(session, operator_id, engine_id, columns_of=_encoded, **options))


def aircraft_trend_json(
    session: Session, operator_id: int, aircraft_id: int, **options: Any
) -> bytes:
    """``to_json(aircraft_trend(...))`` with the series numbers written by numpy."""
    return to_json(
        aircraft_trend(session, operator_id, aircraft_id, columns_of=_encoded, **options)
    )


def _csv_header(trend: dict[str, Any]) -> list[str]:
    header = []
    for group in trend["groups"]:
        for series in group["series"]:
            base = f"{group['key']}.{series['name']}[{series['unit']}]"
            header.append(base)
            if series["sigma"] is not None:
                header.append(f"{group['key']}.{series['name']}.sigma[{series['unit']}]")
            if series["min"] is not None:
                header += [f"{base}.min", f"{base}.max"]
    return header


def _csv_rows(trend: dict[str, Any], prefix: list[Any]) -> list[list[Any]]:
    columns: list[list[Any]] = [trend["time"], trend["seq"], trend["phase"],
                                trend["recording"]]
    for group in trend["groups"]:
        for series in group["series"]:
            columns.append(series["value"])
            if series["sigma"] is not None:
                columns.append(series["sigma"])
            if series["min"] is not None:
                columns += [series["min"], series["max"]]
    return [prefix + ["" if v is None else v for v in row] for row in zip(*columns, strict=True)]


def engine_trend_csv(trend: dict[str, Any]) -> str:
    """The trend as CSV: one row per point, one column per signal, sigma and envelope."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["esn", "recorded_at", "seq", "phase", "recording_id", *_csv_header(trend)])
    writer.writerows(_csv_rows(trend, [trend["esn"]]))
    return out.getvalue()


def aircraft_trend_csv(trend: dict[str, Any]) -> str:
    """The tail's trend as CSV: segments one after the other, with position and ESN."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    header_written = False
    for segment in trend["segments"]:
        engine = segment["trend"]
        if not engine["groups"]:
            continue
        if not header_written:
            writer.writerow(
                ["tail", "position", "esn", "recorded_at", "seq", "phase", "recording_id",
                 *_csv_header(engine)]
            )
            header_written = True
        writer.writerows(_csv_rows(engine, [trend["tail"], segment["position"], engine["esn"]]))
    if not header_written:
        writer.writerow(["tail", "position", "esn", "recorded_at", "seq", "phase", "recording_id"])
    return out.getvalue()


__all__ = [
    "BLOCKS",
    "TrendData",
    "aircraft_trend",
    "aircraft_trend_csv",
    "aircraft_trend_json",
    "decimate",
    "engine_trend",
    "engine_trend_csv",
    "engine_trend_json",
    "load_trend_data",
]
