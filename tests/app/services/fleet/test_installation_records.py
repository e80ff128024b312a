"""Stored snapshots follow corrections of the installation history (``installation_records``):
they move to the engine the corrected history puts at their tail position and time, both
engines are marked for estimation, a move onto an engine's own records is refused, and records
no installation covers any more stay where they were."""

from __future__ import annotations

from datetime import timedelta

from fastapi.testclient import TestClient
from sqlalchemy import delete, func, select
from sqlalchemy.orm import Session

from app.models import Installation, Job, Snapshot
from app.models.estimates import EstimationBacklog
from tests.support.fleet_fixture import SWAP_AT, T0, Fleet, csv_bytes, make_fleet, snapshot_rows

# Two days of records (four tail positions every 10 minutes) around the swap on N101 pos 1.
ROWS = 4 * 6 * 24 * 2
START = T0 + timedelta(days=2)


def upload(client: TestClient, fleet: Fleet) -> None:
    response = client.post(
        "/api/v1/snapshots/file", content=csv_bytes(snapshot_rows(ROWS, seed=11, start=START)),
        headers={**fleet.analyst, "Content-Type": "text/csv"},
    )
    assert response.status_code == 201, response.text


def counts(session: Session, fleet: Fleet) -> dict[str, int]:
    esn_of = {engine_id: esn for esn, engine_id in fleet.engines.items()}
    return {
        esn_of[engine_id]: int(n)
        for engine_id, n in session.execute(
            select(Snapshot.engine_id, func.count()).where(
                Snapshot.engine_id.in_(list(esn_of))
            ).group_by(Snapshot.engine_id)
        )
    }


def installation_of(session: Session, fleet: Fleet, esn: str) -> int:
    return int(session.scalars(
        select(Installation.id).where(Installation.engine_id == fleet.engines[esn])
    ).one())


def patch(client: TestClient, fleet: Fleet, installation_id: int, body: dict) -> int:
    response = client.patch(f"/api/v1/installations/{installation_id}", json=body,
                            headers=fleet.analyst)
    return response.status_code


def test_a_corrected_swap_moves_the_records_between_the_engines(
    client: TestClient, session: Session
) -> None:
    fleet = make_fleet(session)
    upload(client, fleet)
    before = counts(session, fleet)
    per_position = ROWS // 4
    assert before["ESN-1"] + before["ESN-5"] == per_position
    assert before["ESN-1"] == per_position // 2  # the swap is half way through the records
    # As if the upload's estimation had run: no marks, no job.
    session.execute(delete(EstimationBacklog).where(
        EstimationBacklog.operator_id == fleet.operator_id))
    session.execute(delete(Job).where(Job.operator_id == fleet.operator_id))
    session.commit()

    # The swap really happened 12 hours later: move ESN-5 in later, then ESN-1 out later.
    later = SWAP_AT + timedelta(hours=12)
    assert patch(client, fleet, installation_of(session, fleet, "ESN-5"),
                 {"installed_at": later.isoformat()}) == 200
    assert counts(session, fleet) == before  # uncovered for now: they stay with ESN-5
    assert patch(client, fleet, installation_of(session, fleet, "ESN-1"),
                 {"removed_at": later.isoformat()}) == 200
    after = counts(session, fleet)
    moved = 12 * 6
    assert after["ESN-1"] == before["ESN-1"] + moved
    assert after["ESN-5"] == before["ESN-5"] - moved
    assert {k: v for k, v in after.items() if k not in ("ESN-1", "ESN-5")} == {
        k: v for k, v in before.items() if k not in ("ESN-1", "ESN-5")
    }
    # Every record of N101 position 1 now sits with the engine the corrected history names.
    for engine_id, recorded_at in session.execute(
        select(Snapshot.engine_id, Snapshot.recorded_at).join(
            Installation, Installation.engine_id == Snapshot.engine_id
        ).where(Installation.engine_id.in_([fleet.engines["ESN-1"], fleet.engines["ESN-5"]]))
    ):
        assert engine_id == fleet.engines["ESN-1" if recorded_at < later else "ESN-5"]
    # Both engines are marked for estimation from the first record moved, and a job is queued.
    marks = {
        (m.engine_id, m.earliest) for m in session.scalars(
            select(EstimationBacklog).where(EstimationBacklog.operator_id == fleet.operator_id)
        )
    }
    assert marks == {(fleet.engines["ESN-1"], SWAP_AT), (fleet.engines["ESN-5"], SWAP_AT)}
    assert session.scalar(select(func.count()).select_from(Job).where(
        Job.operator_id == fleet.operator_id, Job.kind == "estimate_engines")) == 1


def test_a_move_onto_an_engines_own_records_is_refused_and_changes_nothing(
    client: TestClient, session: Session
) -> None:
    fleet = make_fleet(session)
    upload(client, fleet)
    # ESN-3 leaves N102 at the swap (its later records stay with it, uncovered) and ESN-2
    # leaves N101 position 2 at the same time.
    assert patch(client, fleet, installation_of(session, fleet, "ESN-3"),
                 {"removed_at": SWAP_AT.isoformat()}) == 200
    assert patch(client, fleet, installation_of(session, fleet, "ESN-2"),
                 {"removed_at": SWAP_AT.isoformat()}) == 200
    before = counts(session, fleet)
    # Installing ESN-3 at N101 position 2 from the swap would give it ESN-2's records at the
    # times it has records of its own.
    response = client.post("/api/v1/installations", headers=fleet.analyst, json={
        "engine_id": fleet.engines["ESN-3"], "aircraft_id": session.scalar(
            select(Installation.aircraft_id).where(
                Installation.engine_id == fleet.engines["ESN-2"])),
        "position": 2, "installed_at": SWAP_AT.isoformat(),
    })
    assert response.status_code == 409, response.text
    assert "snapshots of its own" in response.json()["error"]["message"]
    assert counts(session, fleet) == before
    assert session.scalar(select(func.count()).select_from(Installation).where(
        Installation.engine_id == fleet.engines["ESN-3"])) == 1


def test_deleting_an_installation_keeps_its_records_with_the_engine(
    client: TestClient, session: Session
) -> None:
    fleet = make_fleet(session)
    upload(client, fleet)
    before = counts(session, fleet)
    response = client.delete(f"/api/v1/installations/{installation_of(session, fleet, 'ESN-4')}",
                             headers=fleet.analyst)
    assert response.status_code == 200, response.text
    assert counts(session, fleet) == before
