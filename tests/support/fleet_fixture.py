"""A small fleet for upload tests: two tails, five engines (one swap), and a second operator."""

from __future__ import annotations

import io
import uuid
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq
from sqlalchemy import func, select, text
from sqlalchemy.orm import Session

from app.db import make_engine, make_sessionmaker, transaction
from app.models import EngineModel, EstimatorDesign, Snapshot, Upload
from app.services.fleet import service as fleet
from app.services.tenancy import service as tenancy
from estimation.tuners import svd_vstar
from tests.estimation.models import reference_model

T0 = datetime(2026, 3, 1, tzinfo=UTC)


SWAP_AT = T0 + timedelta(days=3)


@dataclass(frozen=True)
class Fleet:
    operator_id: int
    analyst: dict[str, str]
    viewer: dict[str, str]
    other: dict[str, str]
    engines: dict[str, int]  # ESN -> engine id
    other_tail: str

    def engine_at(self, tail: str, position: int, when: datetime) -> int:
        """Which engine sat there: written out by hand from the installations below."""
        if tail == "N101" and position == 1:
            return self.engines["ESN-1" if when < SWAP_AT else "ESN-5"]
        names = {("N101", 2): "ESN-2", ("N102", 1): "ESN-3", ("N102", 2): "ESN-4"}
        return self.engines[names[(tail, position)]]


def make_fleet(session: Session) -> Fleet:
    # Unique names: the fleet must not depend on earlier tests having rolled back.
    suffix = uuid.uuid4().hex[:8]
    operator = tenancy.create_operator(session, name=f"North Air {suffix}")
    _r, analyst = tenancy.issue_api_key(session, operator=operator, role="analyst", name="eng")
    _r, viewer = tenancy.issue_api_key(session, operator=operator, role="viewer", name="view")
    engine_type = fleet.create_engine_type(session, operator_id=operator.id, name="generic")
    engines: dict[str, int] = {}
    for i in range(1, 6):
        row = fleet.create_engine(
            session, operator_id=operator.id, esn=f"ESN-{i}", engine_type_id=engine_type.id
        )
        engines[row.esn] = row.id
    since = T0 - timedelta(days=365)
    tails = {}
    for tail in ("N101", "N102"):
        tails[tail] = fleet.create_aircraft(session, operator_id=operator.id, tail=tail).id
    plan = [
        ("ESN-1", "N101", 1, since, SWAP_AT),
        ("ESN-5", "N101", 1, SWAP_AT, None),
        ("ESN-2", "N101", 2, since, None),
        ("ESN-3", "N102", 1, since, None),
        ("ESN-4", "N102", 2, since, None),
    ]
    for esn, tail, position, start, end in plan:
        fleet.install(
            session,
            operator_id=operator.id,
            engine_id=engines[esn],
            aircraft_id=tails[tail],
            position=position,
            installed_at=start,
            removed_at=end,
        )
    other = tenancy.create_operator(session, name=f"South Air {suffix}")
    _r, other_key = tenancy.issue_api_key(session, operator=other, role="analyst", name="x")
    other_type = fleet.create_engine_type(session, operator_id=other.id, name="generic")
    other_engine = fleet.create_engine(
        session, operator_id=other.id, esn="ESN-900", engine_type_id=other_type.id
    )
    other_aircraft = fleet.create_aircraft(session, operator_id=other.id, tail="N900")
    fleet.install(
        session,
        operator_id=other.id,
        engine_id=other_engine.id,
        aircraft_id=other_aircraft.id,
        position=1,
        installed_at=since,
    )
    session.commit()
    return Fleet(
        operator_id=operator.id,
        analyst={"X-API-Key": analyst},
        viewer={"X-API-Key": viewer},
        other={"X-API-Key": other_key},
        engines=engines,
        other_tail="N900",
    )


def snapshot_rows(n: int, seed: int = 0, start: datetime = T0) -> pa.Table:
    """``n`` snapshots over the four tail positions, one per position every 10 minutes."""
    rng = np.random.default_rng(seed)
    slot = np.arange(n)
    times = np.datetime64(start.replace(tzinfo=None), "us") + (slot // 4) * np.timedelta64(600, "s")
    tails = np.where((slot % 4) < 2, "N101", "N102")
    positions = 1 + slot % 2
    return pa.table(
        {
            "recorded_at": pa.array(times, pa.timestamp("us", tz="UTC")),
            "tail": pa.array(tails.tolist()),
            "position": pa.array(positions.astype(np.int64)),
            "phase": pa.array(np.array(["takeoff", "climb", "cruise"])[slot % 3].tolist()),
            "flight_id": pa.array([f"F{i // 12}" for i in range(n)]),
            "alt_ft": rng.uniform(0, 39000, n),
            "mach": rng.uniform(0, 0.85, n),
            "dtamb_k": rng.normal(0, 5, n),
            "power_pct": rng.uniform(60, 100, n),
            "Nf": rng.uniform(2000, 2400, n),
            "Nc": rng.uniform(8500, 9100, n),
            "T30": rng.uniform(1300, 1600, n),
            "P30": rng.uniform(300, 560, n),
            # Every seventh T50 is missing (null).
            "T50": pa.array(
                np.where(slot % 7 == 3, np.nan, rng.uniform(1300, 1450, n)), from_pandas=True
            ),
            "Wf": rng.uniform(0.5, 2.0, n),
        }
    )


def reference_rows(n: int, seed: int = 0) -> pa.Table:
    """``snapshot_rows`` in the reference model's parameters (the type of
    ``add_reference_design`` takes no other)."""
    rows = snapshot_rows(n, seed)
    return rows.select([c for c in rows.column_names if c not in ("P30", "T50")])


def csv_bytes(table: pa.Table) -> bytes:
    sink = io.BytesIO()
    pacsv.write_csv(table, sink)
    return sink.getvalue()


def parquet_bytes(table: pa.Table) -> bytes:
    sink = io.BytesIO()
    pq.write_table(table, sink)
    return sink.getvalue()


def json_body(table: pa.Table, **extra: Any) -> dict[str, Any]:
    records = table.to_pylist()
    for record in records:
        record["recorded_at"] = record["recorded_at"].isoformat()
    return {**extra, "snapshots": records}


def counts(session: Session, operator_id: int) -> tuple[int, int]:
    """(snapshots, stored uploads) of the operator: what a refused upload leaves unchanged."""
    snapshots = session.scalar(
        select(func.count()).select_from(Snapshot).where(Snapshot.operator_id == operator_id)
    )
    stored = session.scalar(
        select(func.count()).where(Upload.status == "stored", Upload.operator_id == operator_id)
    )
    return int(snapshots or 0), int(stored or 0)


def add_reference_design(url: str, operator_id: int, m: int = 6) -> dict[str, Any]:
    """The reference linear model and an active ``m``-tuner SVD design on the operator's one
    engine type, committed on ``url``; returns the design's result document."""
    model = reference_model()
    result = {"vstar": svd_vstar(model, m).tolist()}
    engine = make_engine(url)
    with transaction(make_sessionmaker(engine)) as session:
        kind = session.scalar(
            text("SELECT id FROM engine_types WHERE operator_id = :o").bindparams(o=operator_id)
        )
        row = EngineModel(
            operator_id=operator_id, engine_type_id=kind, name="reference", version=1,
            source="imported", format="fleethealth.linear-model/1", content=model.to_dict(),
            checksum="0" * 64, dt=model.dt, n_states=model.n_states,
            sensor_names=list(model.sensor_names), health_names=list(model.health_names),
            aux_names=list(model.aux_names),
        )
        session.add(row)
        session.flush()
        session.add(EstimatorDesign(
            operator_id=operator_id, engine_type_id=kind, engine_model_id=row.id,
            name="reference", spec={}, status="ready", active=True, result=result,
        ))
    engine.dispose()
    return result
