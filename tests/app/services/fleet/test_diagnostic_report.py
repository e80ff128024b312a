"""The fleet diagnostic job's report: engines whose state changed since the previous run
(from -> to) and the events raised since then, read back through the jobs API (SQLite and
PostgreSQL)."""

from __future__ import annotations

from fastapi.testclient import TestClient
from sqlalchemy import select
from sqlalchemy.orm import Session, sessionmaker

from app.jobs.kinds import load_kinds
from app.jobs.runner import run_pending
from app.models import Operator
from app.models.estimates import Event
from app.services.fleet.status import fleet_status
from app.services.jobs import store as jobs_store
from app.services.snapshots import store
from tests.app.services.snapshots.test_pipeline import (
    N,
    _fleet_with_design,
    _records,
    _store,
)
from tests.app.services.trends.test_trends import add_aircraft, add_engine
from tests.support.jobs import add_key


def run_diagnostics(
    client: TestClient, session: Session, factory: sessionmaker[Session], operator_id: int,
    key: str,
) -> dict:
    job, _created = jobs_store.submit(session, operator_id=operator_id, kind="fleet_diagnostics",
                                      parameters={}, registry=load_kinds())
    session.commit()
    assert job.id in run_pending(factory)
    out = client.get(f"/api/v1/jobs/{job.id}", headers={"X-API-Key": key}).json()
    assert out["status"] == "succeeded", out
    return {"id": job.id, **out["result"]}


def states(session: Session, operator_id: int) -> dict[str, str]:
    return {e["esn"]: e["state"] for e in fleet_status(session, operator_id)["engines"]}


def event_ids(session: Session, operator_id: int) -> set[int]:
    return set(session.scalars(select(Event.id).where(Event.operator_id == operator_id)))


def test_the_report_names_state_changes_and_events_since_the_previous_run(
    client: TestClient, session: Session, session_factory: sessionmaker[Session]
) -> None:
    fleet = _fleet_with_design(session)
    key = add_key(session, session.get(Operator, fleet.operator_id), "analyst")  # type: ignore[arg-type]
    aircraft = add_aircraft(session, fleet, "F-REP")
    quiet, faulty = add_engine(session, fleet, "REP-Q"), add_engine(session, fleet, "REP-F")
    q_times, q_y = _records(seed=13)
    f_times, f_y = _records(seed=41, fault="HPC", at=450)
    _store(session, fleet, quiet.id, aircraft.id, q_times, q_y, range(N))
    _store(session, fleet, faulty.id, aircraft.id, f_times, f_y, range(0, 400))  # before it
    store.catch_up(session, fleet.operator_id)
    first_states = states(session, fleet.operator_id)
    first_events = event_ids(session, fleet.operator_id)

    first = run_diagnostics(client, session, session_factory, fleet.operator_id, key)
    # No previous run: every engine is listed with no earlier state, every event as raised.
    assert (first["since"], first["baseline_job_id"]) == (None, None)
    assert {c["esn"]: (c["from_state"], c["to_state"]) for c in first["state_changes"]} == {
        esn: (None, state) for esn, state in first_states.items()}
    assert {e["event_id"] for e in first["events_raised"]} == first_events
    assert first["n_events_raised"] == len(first_events)

    # The fault arrives: the faulty engine's detector raises events and its state changes.
    _store(session, fleet, faulty.id, aircraft.id, f_times, f_y, range(400, N))
    store.catch_up(session, fleet.operator_id)
    second_states = states(session, fleet.operator_id)
    new_events = event_ids(session, fleet.operator_id) - first_events
    assert new_events, "the fault raised no event"
    assert second_states["REP-F"] != first_states["REP-F"]

    second = run_diagnostics(client, session, session_factory, fleet.operator_id, key)
    assert (second["baseline_job_id"], second["since"]) == (first["id"], first["as_of"])
    assert {c["esn"]: (c["from_state"], c["to_state"]) for c in second["state_changes"]} == {
        esn: (first_states[esn], state) for esn, state in second_states.items()
        if state != first_states[esn]}
    raised = {e["event_id"]: e for e in second["events_raised"]}
    assert set(raised) == new_events
    assert {e["esn"] for e in raised.values()} == {"REP-F"}
    assert all(e["engine_id"] == faulty.id for e in raised.values())

    # Nothing happened since: an empty report.
    third = run_diagnostics(client, session, session_factory, fleet.operator_id, key)
    assert (third["state_changes"], third["events_raised"], third["n_events_raised"]) == (
        [], [], 0)
