"""Records kept in memory (or in a job host's spool) from a committed upload are exactly what the
database holds, and are used only when complete (``app.services.fresh_records`` through
``estimate_rows``)."""

from __future__ import annotations

from collections.abc import Iterator
from datetime import timedelta
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import delete
from sqlalchemy.orm import Session

from app.models import Snapshot
from app.services import fresh_records
from app.services.snapshots import rows as snapshots_rows
from app.services.snapshots import store
from tests.support.fleet_fixture import T0, csv_bytes, make_fleet, snapshot_rows

SENSORS = ("nf", "nc", "t30", "p30", "t50", "t24")  # t24 is never uploaded: all NaN
INPUTS = ("wf", "")  # "" is a design signal snapshots do not store


def upload(client: TestClient, headers: dict[str, str], rows: object) -> None:
    response = client.post(
        "/api/v1/snapshots/file", content=csv_bytes(rows),
        headers={**headers, "Content-Type": "text/csv"},
    )
    assert response.status_code == 201, response.text


def assert_same(a: snapshots_rows.Records, b: snapshots_rows.Records) -> None:
    assert np.array_equal(a.epoch, b.epoch)
    assert a.phase == b.phase
    for x, y in ((a.conditions, b.conditions), (a.y, b.y), (a.u, b.u)):
        assert x.shape == y.shape
        assert np.array_equal(x, y, equal_nan=True)


def load(session: Session, wants: list) -> dict[int, snapshots_rows.Records]:
    """As the pipeline loads: what is kept for these engines, completed from the database."""
    kept = fresh_records.take(session, [engine_id for engine_id, _after in wants])
    return snapshots_rows.load_records(session, wants, SENSORS, INPUTS, kept=kept)


def test_kept_records_equal_the_stored_ones(client: TestClient, session: Session) -> None:
    fleet = make_fleet(session)
    # Two uploads, the second with rows before the first one's (out of order), and an
    # engine swap inside the range: every engine's kept rows come from both, sorted.
    upload(client, fleet.analyst, snapshot_rows(240, seed=1, start=T0 + timedelta(days=2)))
    upload(client, fleet.analyst, snapshot_rows(200, seed=2, start=T0))
    engines = sorted(fleet.engines.values())
    after = T0 + timedelta(days=2, hours=3)
    wants = [(e, None) for e in engines[:3]] + [(e, after) for e in engines[3:]]
    assert fresh_records.kept_rows(session) == 440
    from_memory = load(session, wants)
    assert fresh_records.kept_rows(session) == 0  # what a load takes is gone
    # ... and through the database alone.
    from_database = load(session, wants)
    assert set(from_memory) == set(from_database) == set(engines)
    assert sum(len(r.epoch) for r in from_database.values()) > 300
    for engine_id in engines:
        assert_same(from_memory[engine_id], from_database[engine_id])
        assert np.isnan(from_database[engine_id].y[:, SENSORS.index("t24")]).all()
    y = np.concatenate([r.y for r in from_database.values()])
    assert np.isnan(y[:, SENSORS.index("t50")]).any()
    assert not np.isnan(y[:, SENSORS.index("t50")]).all()


@pytest.mark.parametrize("kept_in", ["memory", "spool"])
def test_incomplete_kept_records_fall_back_to_the_database(
    client: TestClient, session: Session, request: pytest.FixtureRequest, kept_in: str
) -> None:
    if kept_in == "spool":
        request.getfixturevalue("spool")
    fleet = make_fleet(session)
    upload(client, fleet.analyst, snapshot_rows(120, seed=3))
    engine_id = fleet.engines["ESN-2"]
    # One of the engine's rows disappears behind the kept rows' back: the counts disagree and
    # the database is read instead.
    session.execute(delete(Snapshot).where(Snapshot.engine_id == engine_id,
                                           Snapshot.recorded_at == T0))
    records = load(session, [(engine_id, None)])[engine_id]
    assert len(records.epoch) == 29
    assert records.epoch[0] > T0.timestamp()


def test_a_rolled_back_upload_keeps_nothing(session: Session) -> None:
    fleet = make_fleet(session)
    rows = snapshot_rows(8, seed=4)
    rows = rows.append_column("engine_id", pa.array([fleet.engines["ESN-2"]] * 8))
    fresh_records.keep_after_commit(session, 10**9, rows)
    session.rollback()
    session.commit()  # a later transaction of the same session is not that upload's
    assert fresh_records.kept_rows(session) == 0
    fresh_records.keep_after_commit(session, 10**9, rows)
    session.commit()
    assert fresh_records.kept_rows(session) == 8


def test_the_estimation_job_drops_what_it_cannot_use(client: TestClient, session: Session) -> None:
    """Engines without an active design: the job estimates nothing, and what their upload kept
    in memory goes rather than waiting to be evicted."""
    fleet = make_fleet(session)
    upload(client, fleet.analyst, snapshot_rows(40, seed=5))
    assert fresh_records.kept_rows(session) == 40
    totals = store.catch_up(session, fleet.operator_id)
    assert totals["records"] == 0
    assert fresh_records.kept_rows(session) == 0


@pytest.fixture
def spool(client: TestClient, tmp_path: Path) -> Iterator[Path]:
    """Uploads' rows kept in a spool directory, as for a server's job host (after the app
    factory configured memory)."""
    directory = tmp_path / "spool"
    fresh_records.configure(enabled=True, spool=directory, empty=True)
    yield directory
    fresh_records.configure(enabled=True)


def test_spooled_records_equal_the_stored_ones_and_stay_until_discarded(
    client: TestClient, session: Session, spool: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    fleet = make_fleet(session)
    upload(client, fleet.analyst, snapshot_rows(240, seed=1, start=T0 + timedelta(days=2)))
    upload(client, fleet.analyst, snapshot_rows(200, seed=2, start=T0))
    assert len(list(spool.glob("*.arrow"))) == 2 and not list(spool.glob("*.part"))
    engines = sorted(fleet.engines.values())
    after = T0 + timedelta(days=2, hours=3)
    wants = [(e, None) for e in engines[:3]] + [(e, after) for e in engines[3:]]
    read: list[int] = []  # records read from the database (an engine without any is asked)
    select, aggregated = snapshots_rows._select, snapshots_rows._aggregated

    def counted_select(*args: object) -> snapshots_rows.Columns:
        columns = select(*args)  # type: ignore[arg-type]
        read.append(len(columns[0]))
        return columns

    def counted_aggregated(*args: object) -> dict[int, snapshots_rows.Columns]:
        found = aggregated(*args)  # type: ignore[arg-type]
        read.extend(len(c[0]) for c in found.values())
        return found

    with monkeypatch.context() as patch:
        patch.setattr(snapshots_rows, "_select", counted_select)
        patch.setattr(snapshots_rows, "_aggregated", counted_aggregated)
        from_spool = load(session, wants)
    assert read and sum(read) == 0
    # Every process of the job host reads the files: taking leaves them.
    assert fresh_records.kept_rows(session) == 440
    fresh_records.configure(enabled=True)
    from_database = load(session, wants)
    assert set(from_spool) == set(from_database) == set(engines)
    for engine_id in engines:
        assert_same(from_spool[engine_id], from_database[engine_id])
    fresh_records.configure(enabled=True, spool=spool)
    fresh_records.discard(session, engines[:1])  # the other engines' rows are still wanted
    assert fresh_records.kept_rows(session) == 440
    fresh_records.discard(session, engines[:1], moved=True)  # its rows moved: both files go
    assert fresh_records.kept_rows(session) == 0 and not list(spool.iterdir())
    upload(client, fleet.analyst, snapshot_rows(40, seed=6, start=T0 + timedelta(days=9)))
    fresh_records.discard(session, engines)  # none of its engines left
    assert not list(spool.iterdir())


def test_a_rolled_back_upload_spools_nothing_and_the_spool_is_bounded(
    session: Session, spool: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    fleet = make_fleet(session)
    rows = snapshot_rows(8, seed=4)
    rows = rows.append_column("engine_id", pa.array([fleet.engines["ESN-2"]] * 8))
    fresh_records.keep_after_commit(session, 10**9, rows)
    session.rollback()
    session.commit()
    assert not list(spool.iterdir())
    monkeypatch.setattr(fresh_records, "SPOOL_RECORDS", 12)
    for upload_id in (10**9, 10**9 + 1):
        fresh_records.keep_after_commit(session, upload_id, rows)
        session.commit()
    # The older upload's file went to keep the spool within its bound.
    assert [p.name.split("-")[1] for p in spool.iterdir()] == [str(10**9 + 1)]
    assert fresh_records.kept_rows(session) == 8
