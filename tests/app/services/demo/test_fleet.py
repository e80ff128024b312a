"""The demo fleet (small): seeded once through the ingest path and estimated; a second start
reuses it. Counts are checked against the simulator's plan."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest
from sqlalchemy import func, select
from sqlalchemy.orm import Session, sessionmaker

from app.models import Engine, EngineType, Installation, Snapshot
from app.models.estimates import Estimate
from app.models.jobs import JobSchedule
from app.services.demo import fleet
from app.services.demo.operator import ensure_demo_operator
from app.services.fleet import status as fleet_status
from app.services.snapshots import estimator, store
from estimation.engine.schedule import EngineSchedule, build_schedule

SMALL = fleet.DemoSize(aircraft=2, flights=40, fault_rate=0.0, calibrate=False)


@pytest.fixture(scope="module")
def coarse_schedule() -> EngineSchedule:
    # Two nodes per axis keep the test fast; the service uses the full default grid.
    return build_schedule({"alt": (0.0, 40000.0), "mach": (0.0, 0.85), "power": (40.0, 100.0)})


def test_demo_fleet_is_seeded_once_and_estimated(
    session_factory: sessionmaker[Session], session: Session, tmp_path: Path,
    coarse_schedule: EngineSchedule, monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(estimator, "builtin_schedule", lambda: coarse_schedule)
    with session_factory() as s:
        ensure_demo_operator(s, tmp_path)
        s.commit()
    messages: list[str] = []
    first = fleet.ensure_demo_fleet(session_factory, SMALL, echo=messages.append)
    operator_id = session.scalar(
        select(EngineType.operator_id).where(EngineType.name == fleet.ENGINE_TYPE)
    )
    assert operator_id is not None
    engines = session.scalar(
        select(func.count()).select_from(Engine).where(Engine.operator_id == operator_id)
    )
    snapshots = session.scalar(
        select(func.count()).select_from(Snapshot).where(Snapshot.operator_id == operator_id)
    )
    # Two snapshots (take-off, cruise) per installed engine and flight: 2 aircraft x 2 positions.
    assert snapshots == first["snapshots"] == SMALL.aircraft * 2 * SMALL.flights * 2
    # The simulated period ends today (UTC midnight), not in the future.
    first_at, last_at = session.execute(
        select(func.min(Snapshot.recorded_at), func.max(Snapshot.recorded_at)).where(
            Snapshot.operator_id == operator_id
        )
    ).one()
    now = datetime.now(UTC)
    midnight = datetime(now.year, now.month, now.day, tzinfo=UTC)
    assert midnight - timedelta(days=SMALL.flights / SMALL.flights_per_day + 1) <= first_at
    assert last_at <= midnight
    assert last_at > midnight - timedelta(days=2)
    assert engines == first["engines"]
    estimates = session.scalar(
        select(func.count()).select_from(Estimate)
        .join(Engine, Engine.id == Estimate.engine_id).where(Engine.operator_id == operator_id)
    )
    assert estimates == snapshots
    assert store.pending_work(session, operator_id) == {}
    status = fleet_status.fleet_status(session, operator_id)
    installed = session.scalar(
        select(func.count()).select_from(Installation).where(
            Installation.operator_id == operator_id, Installation.removed_at.is_(None)
        )
    )
    assert sum(e["tail"] is not None for e in status["engines"]) == installed
    assert all(e["health"] is not None for e in status["engines"] if e["n_records"])
    schedule = session.scalars(
        select(JobSchedule).where(JobSchedule.operator_id == operator_id)
    ).one()
    assert (schedule.kind, schedule.cron, schedule.interval_seconds) == (
        "fleet_diagnostics", fleet.DIAGNOSTICS_CRON, None)
    assert any("demo fleet ready" in m for m in messages)

    again = fleet.ensure_demo_fleet(session_factory, SMALL, echo=messages.append)
    assert again == first
    assert session.scalar(
        select(func.count()).select_from(Estimate)
        .join(Engine, Engine.id == Estimate.engine_id).where(Engine.operator_id == operator_id)
    ) == estimates
