"""The estimation backlog: what marks an engine, how marks merge, that the job clears only what
it did, that a maintenance action or an activation redoes what it changes, that the audit finds
rows no mark covers, and that migration 0009 marks what an older database left unestimated."""

from __future__ import annotations

import io
from collections.abc import Iterable
from datetime import datetime, timedelta
from pathlib import Path
from typing import NamedTuple

import pyarrow as pa
import pyarrow.csv as pacsv
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import select, text
from sqlalchemy.orm import Session

from app.db import make_engine, make_sessionmaker, transaction
from app.migrate import downgrade, upgrade
from app.models import Snapshot
from app.models.estimates import EstimationBacklog
from app.services import fresh_records
from app.services.designs import service as designs
from app.services.fleet import maintenance
from app.services.fleet import service as fleet_service
from app.services.snapshots import backlog, store
from app.services.snapshots import rows as snapshots_rows
from app.services.uploads import store as uploads_store
from tests.app.services.snapshots import test_pipeline as pipeline_case
from tests.app.services.trends.test_trends import add_aircraft, add_engine
from tests.conftest import BACKENDS, fresh_database_url
from tests.support.fleet_fixture import T0, csv_bytes, snapshot_rows
from tests.support.fleet_fixture import make_fleet as make_upload_fleet


def marks(session: Session, operator_id: int) -> dict[int, list[tuple]]:
    """Each marked engine's marks, (earliest, rows), oldest first."""
    out: dict[int, list[tuple]] = {}
    for row in session.scalars(
        select(EstimationBacklog).where(EstimationBacklog.operator_id == operator_id)
        .order_by(EstimationBacklog.id)
    ):
        out.setdefault(row.engine_id, []).append((row.earliest, row.rows))
    return out


class Case(NamedTuple):
    """An operator with the pipeline tests' design, an aircraft, one engine and its records."""

    fleet: pipeline_case.Fleet
    aircraft_id: int
    engine_id: int
    times: list[datetime]
    y: pipeline_case.np.ndarray

    def store(self, session: Session, idx: range) -> None:
        pipeline_case._store(session, self.fleet, self.engine_id, self.aircraft_id, self.times,
                             self.y, idx)


def one_engine(session: Session, tail: str, seed: int) -> Case:
    fleet = pipeline_case._fleet_with_design(session)
    aircraft = add_aircraft(session, fleet, tail)
    times, y = pipeline_case._records(seed=seed)
    engine = add_engine(session, fleet, f"{tail}-1")
    return Case(fleet, aircraft.id, engine.id, times, y)


def test_an_upload_marks_its_engines_with_their_earliest_record_and_count(
    client: TestClient, session: Session
) -> None:
    fleet = make_upload_fleet(session)
    rows = snapshot_rows(60, seed=1)
    response = client.post("/api/v1/snapshots/file", content=csv_bytes(rows),
                           headers={**fleet.analyst, "Content-Type": "text/csv"})
    assert response.status_code == 201, response.text
    affected = response.json()["affected"]
    assert marks(session, fleet.operator_id) == {
        a["engine_id"]: [(datetime.fromisoformat(a["earliest"]), a["rows"])] for a in affected
    }
    # The same rows again store nothing and mark nothing more.
    again = client.post("/api/v1/snapshots/file", content=csv_bytes(rows),
                        headers={**fleet.analyst, "Content-Type": "text/csv"})
    assert again.status_code == 200 and again.json()["rows_stored"] == 60
    assert all(len(m) == 1 for m in marks(session, fleet.operator_id).values())


def test_marks_combine_earliest_first_and_unknown_counts_stay_unknown(
    session: Session,
) -> None:
    fleet = pipeline_case._fleet_with_design(session)
    a, b, c = (add_engine(session, fleet, esn).id for esn in ("MC1", "MC2", "MC3"))
    later, earlier = T0 + timedelta(days=2), T0 + timedelta(days=1)
    backlog.mark(session, fleet.operator_id, {a: (later, 5), b: (None, None), c: (None, 1)})
    backlog.mark(session, fleet.operator_id, {a: (earlier, 3), b: (later, 4)})
    backlog.mark(session, fleet.operator_id, {a: (None, 2)})
    combined = {e: (m.earliest, m.rows, len(m.ids))
                for e, m in backlog.pending(session, fleet.operator_id).items()}
    assert combined == {a: (earlier, 10, 3), b: (later, None, 2), c: (None, 1, 1)}


def test_the_job_clears_only_marks_nobody_made_since_it_looked(session: Session) -> None:
    case = one_engine(session, "F-BL", seed=3)
    fleet, engine_id, times = case.fleet, case.engine_id, case.times
    case.store(session, range(0, 100))
    seen = backlog.pending(session, fleet.operator_id)
    assert [(m.earliest, m.rows, len(m.ids)) for m in seen.values()] == [(times[0], 100, 1)]
    # The job reads the batch's marks again once it took the kept rows: an upload committed
    # after that waits with its own mark.
    pending = backlog.pending

    def upload_meanwhile(
        session: Session, operator_id: int, engine_ids: Iterable[int] | None = None
    ) -> dict[int, backlog.Mark]:
        found = pending(session, operator_id, engine_ids)
        case.store(session, range(100, 150))
        return found

    backlog.pending = upload_meanwhile  # type: ignore[assignment]
    try:
        summary = store.estimate_engines(
            session, fleet.operator_id, {engine_id: times[0]}, from_backlog=True
        )
    finally:
        backlog.pending = pending  # type: ignore[assignment]
    left = backlog.pending(session, fleet.operator_id)
    assert [(m.earliest, m.rows, len(m.ids)) for m in left.values()] == [(times[100], 50, 1)]
    # Its rows were read after the marks, so this pass did them too; the next pass redoes
    # them from the mark's time (a re-run, never a gap) and the rows end as one run's.
    second = store.catch_up(session, fleet.operator_id)
    assert summary["records"] == 150 and second["records"] == 150 and second["reruns"] == 1
    assert backlog.pending(session, fleet.operator_id) == {}
    assert [r[0] for r in pipeline_case._rows(session, engine_id)] == list(range(150))


def _upload(session: Session, fleet: pipeline_case.Fleet, aircraft_id: int, times: list,
            y: pipeline_case.np.ndarray, idx: range) -> None:
    """Records idx through the upload service (CSV), committed: their rows are kept."""
    columns = [s.name for s in pipeline_case._model().sensors]  # as uploads name them
    table = pa.table({
        "recorded_at": pa.array([times[i] for i in idx], pa.timestamp("us", tz="UTC")),
        "tail": ["F-KC"] * len(idx), "position": [1] * len(idx),
        "phase": ["takeoff" if i % 2 == 0 else "cruise" for i in idx],
        "alt_ft": [0.0] * len(idx), "mach": [0.0] * len(idx), "dtamb_k": [0.0] * len(idx),
        "power_pct": [100.0] * len(idx),
        **{c: y[list(idx), k] for k, c in enumerate(columns)},
    })
    sink = io.BytesIO()
    pacsv.write_csv(table, sink)
    uploads_store.ingest_snapshots(session, operator_id=fleet.operator_id, api_key_id=None,
                            body=sink.getvalue(), content_format="csv")
    session.commit()


def installed_engine(session: Session) -> Case:
    """``one_engine`` installed on its aircraft a day before the first of its records."""
    case = one_engine(session, "F-KC", seed=4)
    fleet_service.install(session, operator_id=case.fleet.operator_id, engine_id=case.engine_id,
                          aircraft_id=case.aircraft_id, position=1,
                          installed_at=case.times[0] - timedelta(days=1))
    return case


def test_after_an_upload_the_job_takes_its_rows_without_counting_the_database(
    session: Session, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The rows an upload kept are complete by its backlog count, so no count query runs; a
    mark of unknown count (an activation) makes the job count again."""
    fleet, aircraft_id, engine_id, times, y = installed_engine(session)
    _upload(session, fleet, aircraft_id, times, y, range(0, 50))
    store.catch_up(session, fleet.operator_id)
    counted: list[object] = []
    count_after = snapshots_rows._count_after

    def counting(session: Session, wants: list) -> dict[int, int]:
        counted.extend(wants)
        return count_after(session, wants)

    monkeypatch.setattr(snapshots_rows, "_count_after", counting)
    _upload(session, fleet, aircraft_id, times, y, range(50, 80))
    assert fresh_records.kept_rows(session) == 30
    assert store.catch_up(session, fleet.operator_id)["records"] == 30
    assert counted == [] and fresh_records.kept_rows(session) == 0

    _upload(session, fleet, aircraft_id, times, y, range(80, 90))
    backlog.mark_from_start(session, fleet.operator_id, [engine_id])
    assert store.catch_up(session, fleet.operator_id)["records"] == 10
    assert len(counted) == 1
    reference = add_engine(session, fleet, "KC0")
    pipeline_case._store(session, fleet, reference.id, aircraft_id, times, y, range(0, 90))
    store.catch_up(session, fleet.operator_id)
    assert [r[2] for r in pipeline_case._rows(session, engine_id)] == [
        r[2] for r in pipeline_case._rows(session, reference.id)
    ]


def test_rows_of_an_engine_marked_after_the_jobs_last_pass_stay_for_the_next_job(
    session: Session,
) -> None:
    """A job leaves the kept rows of engines whose marks it did not settle (an upload that
    committed after its last pass read the backlog: here no pass at all) for the job that
    upload queued; the rows of engines it estimated go."""
    fleet, aircraft_id, engine_id, times, y = installed_engine(session)
    _upload(session, fleet, aircraft_id, times, y, range(0, 40))
    store.catch_up(session, fleet.operator_id, max_passes=0)
    assert fresh_records.kept_rows(session) == 40
    assert store.catch_up(session, fleet.operator_id)["records"] == 40
    assert fresh_records.kept_rows(session) == 0


def test_a_maintenance_action_recorded_later_redoes_the_estimates_from_it(
    session: Session,
) -> None:
    """Recorded after its engine was estimated, a shop visit re-runs the engine from it: the
    rows and events equal those of an engine whose action was there from the start."""
    fleet = pipeline_case._fleet_with_design(session)
    aircraft = add_aircraft(session, fleet, "F-MXL")
    model = pipeline_case._model()
    jump = pipeline_case.np.zeros(model.n_health)
    jump[model.health_index(["hpc_eff", "hpc_flow"])] = 2.0
    times, y = pipeline_case._records(seed=21, jump=jump, jump_at=600)
    early, late = add_engine(session, fleet, "MXE"), add_engine(session, fleet, "MXL")
    visit = times[599] + timedelta(hours=1)
    maintenance.record_action(session, operator_id=fleet.operator_id, engine_id=early.id,
                              kind="shop_visit", performed_at=visit)
    for engine in (early, late):
        pipeline_case._store(session, fleet, engine.id, aircraft.id, times, y,
                             range(pipeline_case.N))
    store.catch_up(session, fleet.operator_id)
    assert [e[0] >= 600 for e in pipeline_case._shift_events(session, late.id)] == [True]

    maintenance.record_action(session, operator_id=fleet.operator_id, engine_id=late.id,
                              kind="shop_visit", performed_at=visit)
    assert [(e, m.earliest, m.rows) for e, m in backlog.pending(session, fleet.operator_id).items()
            ] == [(late.id, visit, 0)]
    summary = store.catch_up(session, fleet.operator_id)
    assert summary["reruns"] == 1  # from the start: no checkpoint before record 600
    assert pipeline_case._shift_events(session, late.id) == []
    assert pipeline_case._events(session, late.id) == pipeline_case._events(session, early.id)
    assert [r[2] for r in pipeline_case._rows(session, late.id)] == [
        r[2] for r in pipeline_case._rows(session, early.id)
    ]


def test_activating_a_design_marks_the_engines_of_its_type_that_have_data(
    session: Session,
) -> None:
    fleet = pipeline_case._fleet_with_design(session)
    aircraft = add_aircraft(session, fleet, "F-ACT")
    times, y = pipeline_case._records(seed=5)
    with_data, without = add_engine(session, fleet, "AC1"), add_engine(session, fleet, "AC2")
    pipeline_case._store(session, fleet, with_data.id, aircraft.id, times, y, range(0, 40))
    store.catch_up(session, fleet.operator_id)
    assert marks(session, fleet.operator_id) == {}
    designs.activate_design(session, operator_id=fleet.operator_id,
                                   design_id=fleet.design.id)
    assert marks(session, fleet.operator_id) == {}  # already active: nothing changes
    fleet.design.active = False
    session.flush()
    designs.activate_design(session, operator_id=fleet.operator_id,
                                   design_id=fleet.design.id)
    assert marks(session, fleet.operator_id) == {with_data.id: [(None, None)]}
    assert without.id not in marks(session, fleet.operator_id)


def test_the_audit_marks_rows_stored_without_a_mark(session: Session) -> None:
    case = one_engine(session, "F-AUD", seed=6)
    fleet, engine_id, times = case.fleet, case.engine_id, case.times
    case.store(session, range(0, 30))
    store.catch_up(session, fleet.operator_id)
    # Rows that reached the table by a path that marked nothing.
    session.add_all(
        Snapshot(operator_id=fleet.operator_id, engine_id=engine_id, aircraft_id=case.aircraft_id,
                 position=1, upload_id=fleet.upload.id, recorded_at=times[i], phase="cruise",
                 alt_ft=0.0, mach=0.0, dtamb_k=0.0, power_pct=100.0)
        for i in range(30, 35)
    )
    session.flush()
    assert store.catch_up(session, fleet.operator_id)["records"] == 0
    assert store.audit(session, fleet.operator_id) == {engine_id: times[30]}
    assert store.catch_up(session, fleet.operator_id)["records"] == 5
    assert store.audit(session, fleet.operator_id) == {}


@pytest.mark.parametrize("backend", BACKENDS)
def test_migration_0009_marks_what_was_left_unestimated(backend: str, tmp_path: Path) -> None:
    urls = fresh_database_url(backend, tmp_path)
    url = next(urls)
    try:
        # The rows are written with today's tables, then the database goes back to 0008 (the
        # backlog table and every later change dropped) and forward again.
        upgrade(url)
        engine = make_engine(url)
        with transaction(make_sessionmaker(engine)) as session:
            fleet = pipeline_case._fleet_with_design(session)
            aircraft = add_aircraft(session, fleet, "F-MIG")
            times, y = pipeline_case._records(seed=8)
            done, behind = add_engine(session, fleet, "MG1"), add_engine(session, fleet, "MG2")
            for e in (done, behind):
                pipeline_case._store_rows(session, fleet, e.id, aircraft.id, times, y,
                                          range(0, 20))
            store.estimate_engines(session, fleet.operator_id,
                                             {done.id: times[0], behind.id: times[0]})
            pipeline_case._store_rows(session, fleet, behind.id, aircraft.id, times, y,
                                      range(20, 25))
            operator_id, behind_id = fleet.operator_id, behind.id
        engine.dispose()
        downgrade(url, "0008")
        upgrade(url)
        with engine.connect() as connection:
            rows = connection.execute(text(
                "SELECT engine_id, operator_id, earliest, rows FROM estimation_backlog"
            )).all()
        assert [(r[0], r[1], r[3]) for r in rows] == [(behind_id, operator_id, None)]
        earliest = rows[0][2]
        earliest = earliest if isinstance(earliest, str) else earliest.isoformat()
        assert earliest.replace("T", " ").startswith(str(times[20].replace(tzinfo=None)))
        engine.dispose()
    finally:
        urls.close()


def test_a_change_of_engine_type_marks_the_engine(session: Session) -> None:
    """Its records are to be estimated under the new type's design (unknown count); the same
    type again marks nothing."""
    case = one_engine(session, "F-TYP", seed=9)
    fleet = case.fleet
    case.store(session, range(0, 10))
    store.catch_up(session, fleet.operator_id)
    fleet_service.update_engine(session, operator_id=fleet.operator_id, engine_id=case.engine_id,
                                changes={"engine_type_id": fleet.engine_type.id})
    assert marks(session, fleet.operator_id) == {}
    other = fleet_service.create_engine_type(session, operator_id=fleet.operator_id, name="b")
    fleet_service.update_engine(session, operator_id=fleet.operator_id, engine_id=case.engine_id,
                                changes={"engine_type_id": other.id})
    assert marks(session, fleet.operator_id) == {case.engine_id: [(None, None)]}


def test_marks_of_engines_without_a_design_go_and_an_activation_brings_them_back(
    session: Session,
) -> None:
    case = one_engine(session, "F-NOD", seed=10)
    fleet = case.fleet
    fleet.design.active = False
    session.flush()
    case.store(session, range(0, 20))
    assert store.catch_up(session, fleet.operator_id)["records"] == 0
    assert marks(session, fleet.operator_id) == {}
    designs.activate_design(session, operator_id=fleet.operator_id,
                                   design_id=fleet.design.id)
    assert store.catch_up(session, fleet.operator_id)["records"] == 20
    assert marks(session, fleet.operator_id) == {}
