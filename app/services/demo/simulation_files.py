"""Writing a simulated fleet to files in the upload formats (docs/upload-format.md), plus its
ground truth.

Layout under the output directory:

- ``snapshots.csv`` / ``snapshots.parquet``: snapshot records, upload columns
  (``recorded_at, tail, position, phase, flight_id``, operating condition,
  actuators, sensors), sensor and actuator columns named with their unit
  (``T30[degR]``), timestamps ISO 8601 in UTC (``...Z``).
- ``streams/<flight_id>_<position>.csv`` (or ``.parquet``): one whole-flight
  recording per engine and flight (``time_s``, operating condition, actuators,
  sensors), and ``streams/manifest.json`` with each file's ``tail``,
  ``position``, ``started_at`` and ``flight_id`` (what an upload passes as
  query parameters), the rate and the units.
- ``truth.json``: ground truth, never uploaded: per ESN and flight the true
  health parameters (percent) and the installed tail/position, the
  installations, injected faults, swaps and water washes; ``truth_health.csv``
  holds the same health table flat.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from estimation.engine.fleet import FleetPlan, Snapshots, StreamFlight
from estimation.engine.health import HEALTH_NAMES
from estimation.engine.sensors import SENSOR_NAMES, SENSOR_UNITS

ACTUATOR_NAMES = ("Wf", "VSV", "VBV")
ACTUATOR_UNITS = ("pps", "%", "%")
CONDITION_NAMES = ("alt_ft", "mach", "dtamb_k", "power_pct")
FORMATS = ("csv", "parquet")
UTC_TS = pa.timestamp("s", tz="UTC")


def _signal_columns() -> list[tuple[str, str]]:
    """(column header, unit) of actuators and sensors; Wf once, as an actuator."""
    cols = [(f"{n}[{u}]", n) for n, u in zip(ACTUATOR_NAMES, ACTUATOR_UNITS, strict=True)]
    cols += [
        (f"{n}[{u}]", n)
        for n, u in zip(SENSOR_NAMES, SENSOR_UNITS, strict=True)
        if n not in ACTUATOR_NAMES
    ]
    return cols


def _signals(actuators: np.ndarray, sensors: np.ndarray) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    for header, name in _signal_columns():
        if name in ACTUATOR_NAMES:
            out[header] = actuators[:, ACTUATOR_NAMES.index(name)]
        else:
            out[header] = sensors[:, SENSOR_NAMES.index(name)]
    return out


def iso_utc(epoch_s: float) -> str:
    """ISO 8601 with a Z: 2026-03-01T08:15:00Z."""
    return datetime.fromtimestamp(float(epoch_s), tz=UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def snapshot_table(snaps: Snapshots) -> pa.Table:
    """The snapshot records as an Arrow table with the upload columns (no ESN)."""
    cols: dict[str, Any] = {
        "recorded_at": pa.array(np.round(snaps.recorded_at).astype("int64"), pa.int64()).cast(
            UTC_TS
        ),
        "tail": pa.array(snaps.tail.astype(str)),
        "position": pa.array(snaps.position.astype("int64")),
        "phase": pa.array(snaps.phase.astype(str)),
        "flight_id": pa.array(snaps.flight_id.astype(str)),
    }
    for name in CONDITION_NAMES:
        cols[name] = pa.array(np.asarray(getattr(snaps, name), dtype=float))
    for header, values in _signals(snaps.actuators, snaps.sensors).items():
        cols[header] = pa.array(np.asarray(values, dtype=float))
    return pa.table(cols)


def _write_csv(table: pa.Table, path: Path) -> None:
    # Timestamps as ISO 8601 text with Z, exactly as docs/upload-format.md shows them.
    if "recorded_at" in table.column_names:
        text = [iso_utc(t.timestamp()) for t in table["recorded_at"].to_pylist()]
        table = table.set_column(
            table.column_names.index("recorded_at"), "recorded_at", pa.array(text)
        )
    pacsv.write_csv(table, path, pacsv.WriteOptions(quoting_style="needed"))


def write_table(table: pa.Table, stem: Path, formats: Iterable[str]) -> list[Path]:
    """Write ``table`` as stem.csv and/or stem.parquet; returns the paths."""
    paths = []
    for fmt in formats:
        if fmt not in FORMATS:
            raise ValueError(f"unknown format {fmt!r}; known: {FORMATS}")
        path = stem.with_suffix(f".{fmt}")
        path.parent.mkdir(parents=True, exist_ok=True)
        if fmt == "csv":
            _write_csv(table, path)
        else:
            pq.write_table(table, path)
        paths.append(path)
    return paths


def write_snapshots(snaps: Snapshots, out_dir: Path, formats: Iterable[str] = FORMATS
                    ) -> list[Path]:
    """snapshots.csv / snapshots.parquet in the upload format."""
    return write_table(snapshot_table(snaps), Path(out_dir) / "snapshots", formats)


def stream_table(flight: StreamFlight) -> pa.Table:
    """One engine's flight as an Arrow table: time_s, operating condition, signals."""
    cols: dict[str, Any] = {"time_s": pa.array(np.asarray(flight.time_s, dtype=float))}
    for name in CONDITION_NAMES:
        cols[name] = pa.array(np.asarray(getattr(flight, name), dtype=float))
    for header, values in _signals(flight.actuators, flight.sensors).items():
        cols[header] = pa.array(np.asarray(values, dtype=float))
    return pa.table(cols)


def stream_file_stem(flight: StreamFlight) -> str:
    return f"{flight.flight_id}_{flight.position}"


def write_stream_flight(
    flight: StreamFlight, out_dir: Path, formats: Iterable[str] = ("csv",)
) -> dict[str, Any]:
    """Write one flight under out_dir/streams; returns its manifest entry."""
    stem = Path(out_dir) / "streams" / stream_file_stem(flight)
    paths = write_table(stream_table(flight), stem, formats)
    dt = float(flight.time_s[1] - flight.time_s[0]) if flight.time_s.size > 1 else None
    return {
        "files": [p.relative_to(Path(out_dir)).as_posix() for p in paths],
        "tail": flight.tail,
        "position": int(flight.position),
        "flight_id": flight.flight_id,
        "started_at": iso_utc(flight.started_at),
        "rate_hz": None if dt is None else round(1.0 / dt, 9),
        "samples": int(flight.time_s.size),
    }


def units() -> dict[str, str]:
    """Unit of every signal column, as the JSON upload's batch-level ``units``."""
    return {name: header[len(name) + 1:-1] for header, name in _signal_columns()}


def write_stream_manifest(entries: list[dict[str, Any]], out_dir: Path) -> Path:
    path = Path(out_dir) / "streams" / "manifest.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"units": units(), "flights": entries}, indent=1) + "\n")
    return path


def truth_document(plan: FleetPlan) -> dict[str, Any]:
    """Ground truth as JSON-able data: health per ESN and flight, events."""
    cfg = plan.config
    health = []
    for j, round_flights in enumerate(plan.flights):
        for a, rec in enumerate(round_flights):
            for p in range(cfg.positions):
                e = int(plan.installed[j, a, p])
                health.append({
                    "esn": plan.esns[e], "flight_id": rec.flight_id, "tail": rec.tail,
                    "position": p + 1, "started_at": iso_utc(rec.started_at),
                    "health": {n: float(v) for n, v in zip(HEALTH_NAMES, plan.health[j, e],
                                                           strict=True)},
                })
    return {
        "health_names": list(HEALTH_NAMES),
        "health_units": "%",
        "esns": list(plan.esns),
        "tails": list(plan.tails),
        "positions": cfg.positions,
        "health": health,
        "installations": [
            {"esn": i.esn, "tail": i.tail, "position": int(i.position),
             "installed_at": iso_utc(i.installed_at),
             "removed_at": None if i.removed_at is None else iso_utc(i.removed_at)}
            for i in plan.installations
        ],
        "faults": [
            {"esn": f.esn, "flight_id": f.flight_id, "tail": f.tail, "position": int(f.position),
             "occurred_at": iso_utc(f.occurred_at), "fault": f.fault, "scale": f.scale,
             "shifts": f.shifts}
            for f in plan.faults
        ],
        "swaps": [
            {"at": iso_utc(s.at), "tail": s.tail, "position": int(s.position),
             "esn_off": s.esn_off, "esn_on": s.esn_on, "reason": s.reason}
            for s in plan.swaps
        ],
        "washes": [
            {"esn": w.esn, "at": iso_utc(w.at), "recovered": w.recovered} for w in plan.washes
        ],
    }


def write_truth(plan: FleetPlan, out_dir: Path) -> list[Path]:
    """truth.json and truth_health.csv (one row per ESN and flight)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    doc = truth_document(plan)
    json_path = out / "truth.json"
    json_path.write_text(json.dumps(doc, indent=1) + "\n")
    rows = doc["health"]
    table = pa.table({
        "esn": [r["esn"] for r in rows], "flight_id": [r["flight_id"] for r in rows],
        "tail": [r["tail"] for r in rows], "position": [r["position"] for r in rows],
        "started_at": [r["started_at"] for r in rows],
        **{n: [r["health"][n] for r in rows] for n in HEALTH_NAMES},
    })
    csv_path = out / "truth_health.csv"
    pacsv.write_csv(table, csv_path, pacsv.WriteOptions(quoting_style="needed"))
    return [json_path, csv_path]


def write_streams(
    flights: Iterable[StreamFlight],
    out_dir: Path,
    formats: Iterable[str] = ("csv",),
    on_flight: Callable[[StreamFlight], None] | None = None,
) -> Path:
    """Write every stream flight as it comes, then the manifest; returns the manifest path."""
    fmts = tuple(formats)
    entries = []
    for flight in flights:
        entries.append(write_stream_flight(flight, out_dir, fmts))
        if on_flight is not None:
            on_flight(flight)
    return write_stream_manifest(entries, out_dir)


def read_snapshots(path: Path) -> pa.Table:
    """Read snapshots back (CSV or Parquet), recorded_at as UTC timestamps."""
    path = Path(path)
    if path.suffix == ".parquet":
        return pq.read_table(path)
    table = pacsv.read_csv(path, convert_options=pacsv.ConvertOptions(
        column_types={"recorded_at": UTC_TS, "tail": pa.string(), "flight_id": pa.string()}
    ))
    return table
