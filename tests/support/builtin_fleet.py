"""A small demo fleet of the built-in engine estimated through the upload path, on a coarse
schedule (two nodes per axis keep tests fast; the service uses the full default grid)."""

from __future__ import annotations

import functools
import io
from dataclasses import replace
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
from sqlalchemy.orm import Session

from app.services.demo import fleet as demo
from app.services.demo.simulation_files import snapshot_table
from app.services.snapshots import store
from app.services.tenancy import service as tenancy
from app.services.uploads.store import ingest_snapshots
from estimation.engine.fleet import fleet_snapshots, plan_fleet
from estimation.engine.schedule import EngineSchedule, build_schedule

SIZE = demo.DemoSize(aircraft=2, flights=70, fault_rate=0.0, calibrate=False)


@functools.lru_cache(maxsize=1)
def coarse_schedule() -> EngineSchedule:
    """The built-in engine's schedule on two nodes per axis (for ``estimator.builtin_schedule``)."""
    return build_schedule({"alt": (0.0, 40000.0), "mach": (0.0, 0.85), "power": (40.0, 100.0)})


def demo_records(seed: int = 7) -> tuple[Any, pa.Table]:
    """A small demo fleet's plan and its take-off and cruise records, by time."""
    config = replace(demo.fleet_config(SIZE), start_epoch_s=demo.demo_start_epoch(SIZE))
    plan_rng, snap_rng = np.random.default_rng(seed).spawn(2)
    plan = plan_fleet(config, plan_rng)
    table = snapshot_table(fleet_snapshots(plan, snap_rng))
    table = table.filter(pc.is_in(table["phase"], value_set=pa.array(["takeoff", "cruise"])))
    return plan, table.sort_by("recorded_at")


def seed_fleet(session: Session, name: str) -> tuple[int, pa.Table]:
    """An operator with the demo's engine type, designs and fleet (no records yet); its id and
    the fleet's records."""
    operator = tenancy.create_operator(session, name=name)
    type_id, _design_id = demo._designs(session, operator.id, lambda _m: None)
    plan, table = demo_records()
    demo._fleet(session, operator.id, type_id, plan)
    return operator.id, table


def upload(session: Session, operator_id: int, table: pa.Table) -> dict[str, Any]:
    """Records stored as an upload stores them, then estimated; the estimation's counts."""
    sink = io.BytesIO()
    pq.write_table(table, sink)
    ingest_snapshots(session, operator_id=operator_id, api_key_id=None, body=sink.getvalue(),
                     content_format="parquet")
    return store.catch_up(session, operator_id)
