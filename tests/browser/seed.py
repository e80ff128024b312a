"""A small seeded fleet for the browser tests, made through the services the API uses.

Two operators: "Browser Air" with the built-in engine's model, two estimator designs (one
active, one with a Monte Carlo evaluation), a simulated fleet of two aircraft with an engine
swap and abrupt faults uploaded through the ingest service and estimated by the pipeline; and
"Other Air" with one engine, so the tenant rule can be checked from the browser.
"""

from __future__ import annotations

import io
from dataclasses import dataclass, field
from datetime import UTC, datetime

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from app.db import transaction
from app.jobs.kinds import load_kinds
from app.jobs.runner import run_pending
from app.models.estimates import Event
from app.services.demo.simulation_files import snapshot_table
from app.services.designs import engine_models
from app.services.designs import service as designs
from app.services.fleet import maintenance
from app.services.fleet import service as fleet
from app.services.jobs import store
from app.services.snapshots import estimator
from app.services.snapshots import store as snapshots_store
from app.services.tenancy import service as tenancy
from app.services.uploads import store as uploads_store
from estimation.engine.fleet import FleetConfig, fleet_snapshots, plan_fleet

HEALTH = ("fan_eff", "fan_flow", "lpc_eff", "lpc_flow", "hpc_eff", "hpc_flow", "hpt_eff",
          "hpt_flow", "lpt_eff", "lpt_flow")
DESIGN_POINT = (35000.0, 0.8, 80.0)
PLAN_SEED = 4


@dataclass
class Seeded:
    key: str
    viewer_key: str
    other_key: str
    other_engine_id: int
    engine_ids: dict[str, int] = field(default_factory=dict)
    design_ids: list[int] = field(default_factory=list)
    engine_model_id: int = 0
    event_id: int | None = None
    engine_with_event: int | None = None
    # Snapshots one day after the seeded ones, for an upload from the browser.
    next_day: pa.Table | None = None


def _designs(session: Session, operator_id: int, type_id: int) -> tuple[int, list[int]]:
    model = estimator.builtin_schedule().model_at(*DESIGN_POINT)
    row, _ = engine_models.register_builtin_model(
        session, operator_id=operator_id, engine_type_id=type_id, name="built-in cruise",
        model=model,
    )
    base = {
        "format": "fleethealth.design-spec/1",
        "sensors": [n for n in model.sensor_names if n != "Wf"],
        "health": list(HEALTH),
        "noise": {"Q": 1e-4, "Qh": 1e-4, "Ph": 4.0},
    }
    ids = []
    for name, method, m in (("subset m = 8", "subset", 8), ("SVD m = 6", "svd", 6)):
        design = designs.create_design(
            session, operator_id=operator_id, engine_model_id=row.id, name=name,
            spec=dict(base, method=method, tuners=m),
        )
        designs.run_design(session, design, designs.design_step)
        ids.append(design.id)
    designs.activate_design(session, operator_id=operator_id, design_id=ids[0])
    return row.id, ids


def seed(factory: sessionmaker[Session]) -> Seeded:
    with transaction(factory) as session:
        op = tenancy.create_operator(session, name="Browser Air")
        _, key = tenancy.issue_api_key(session, operator=op, role="admin", name="admin")
        _, viewer = tenancy.issue_api_key(session, operator=op, role="viewer", name="viewer")
        other = tenancy.create_operator(session, name="Other Air")
        _, other_key = tenancy.issue_api_key(session, operator=other, role="admin", name="o")
        other_type = fleet.create_engine_type(session, operator_id=other.id, name="other type")
        other_engine = fleet.create_engine(
            session, operator_id=other.id, esn="OTHER-1", engine_type_id=other_type.id
        )
        engine_type = fleet.create_engine_type(
            session, operator_id=op.id, name="Generic two-spool turbofan"
        )
        model_id, design_ids = _designs(session, op.id, engine_type.id)
        out = Seeded(key, viewer, other_key, other_engine.id, design_ids=design_ids,
                     engine_model_id=model_id)
        op_id, type_id = op.id, engine_type.id
    config = FleetConfig(
        n_aircraft=2, n_flights=160, positions=2, flights_per_day=2.0, fault_rate=1.0 / 200,
        faulted_removal=0.0, removal_rate=1.0 / 300, wash_interval=1e5,
        # No scheduled wash in the 160 flights: a young fleet, so that the fouling of engines
        # never washed stays in the range of the demo's (a few percent, not 10-20 %).
        initial_cycles_max=2000.0,
    )
    plan = plan_fleet(config, np.random.default_rng(PLAN_SEED))
    snaps = snapshot_table(fleet_snapshots(plan, np.random.default_rng(PLAN_SEED + 100)))
    snaps = snaps.filter(pc.is_in(snaps["phase"], value_set=pa.array(["takeoff", "cruise"])))
    # Fifteen days without data from one engine (recorder unserviceable): a gap in its trend.
    def day(n: int) -> pa.Scalar:
        return pa.scalar(int(config.start_epoch_s + n * 86400), snaps["recorded_at"].type)

    lost = pc.and_(
        pc.and_(pc.equal(snaps["tail"], plan.tails[0]), pc.equal(snaps["position"], 1)),
        pc.and_(
            pc.greater_equal(snaps["recorded_at"], day(50)), pc.less(snaps["recorded_at"], day(65))
        ),
    )
    snaps = snaps.filter(pc.invert(lost))
    with transaction(factory) as session:
        tails = {t: fleet.create_aircraft(session, operator_id=op_id, tail=t).id
                 for t in plan.tails}
        for esn in plan.esns:
            out.engine_ids[esn] = fleet.create_engine(
                session, operator_id=op_id, esn=esn, engine_type_id=type_id
            ).id
        for inst in sorted(plan.installations, key=lambda i: i.installed_at):
            fleet.install(
                session, operator_id=op_id, engine_id=out.engine_ids[inst.esn],
                aircraft_id=tails[inst.tail], position=inst.position,
                installed_at=datetime.fromtimestamp(inst.installed_at, UTC),
                removed_at=None if inst.removed_at is None
                else datetime.fromtimestamp(inst.removed_at, UTC),
            )
        # A water wash on an engine without faults, so the trend shows a maintenance marker.
        maintenance.record_action(
            session, operator_id=op_id, engine_id=out.engine_ids[plan.esns[0]],
            kind="water_wash", performed_at=datetime.fromtimestamp(
                config.start_epoch_s + 20 * 86400, UTC),
            notes="water wash after a sand storm",
        )
        for wash in plan.washes:
            maintenance.record_action(
                session, operator_id=op_id, engine_id=out.engine_ids[wash.esn],
                kind="water_wash", performed_at=datetime.fromtimestamp(wash.at, UTC),
                notes="scheduled water wash",
            )
    last = pc.max(snaps["recorded_at"])
    tail_rows = snaps.filter(pc.equal(snaps["recorded_at"], last))
    shifted = pc.add(tail_rows["recorded_at"], pa.scalar(86400, pa.duration("s")))
    out.next_day = tail_rows.set_column(0, "recorded_at", shifted.cast(snaps["recorded_at"].type))
    sink = io.BytesIO()
    pq.write_table(snaps, sink)
    with transaction(factory) as session:
        uploads_store.ingest_snapshots(
            session, operator_id=op_id, api_key_id=None, body=sink.getvalue(),
            content_format="parquet",
        )
    with transaction(factory) as session:
        snapshots_store.catch_up(session, op_id)
    _evaluate(factory, op_id, out.design_ids[0])
    with transaction(factory) as session:
        event = session.scalars(
            select(Event).where(Event.operator_id == op_id).order_by(Event.id)
        ).first()
        if event is not None:
            out.event_id, out.engine_with_event = event.id, event.engine_id
    return out


def _evaluate(factory: sessionmaker[Session], operator_id: int, design_id: int) -> None:
    """A short Monte Carlo evaluation of the active design, run as the dashboard runs it."""
    with transaction(factory) as session:
        store.submit(
            session, operator_id=operator_id, kind="evaluate_design",
            parameters={"design_id": design_id, "n_cases": 40, "duration_s": 10.0,
                        "window_s": 5.0, "fault_duration_s": 20.0, "seed": 1},
            registry=load_kinds(),
        )
    run_pending(factory)
