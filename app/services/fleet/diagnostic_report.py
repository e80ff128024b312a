"""The fleet diagnostic's report: which engines changed state and which alerts were raised
since the previous diagnostic run.

The baseline is the operator's newest succeeded ``fleet_diagnostics`` job: each engine's state
then (its result's ``states``) against the fleet status now, and the events stored after that
report was read (its ``as_of``). Without a previous run every engine is listed with no
``from`` state and every event stored so far counts as raised (the newest ``MAX_EVENTS``).
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

from pydantic import BaseModel, Field
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.models import Engine
from app.models.base import utcnow
from app.models.estimates import Event
from app.models.jobs import Job
from app.services.fleet.status import fleet_status

KIND = "fleet_diagnostics"
# Events listed in one report, newest first; ``n_events_raised`` counts them all.
MAX_EVENTS = 200


class StateChange(BaseModel):
    engine_id: int
    esn: str
    tail: str | None
    position: int | None
    from_state: str | None = Field(description="the state at the previous run; null if none")
    to_state: str
    reason: str | None = Field(description="why the engine is in its state now")


class RaisedEvent(BaseModel):
    event_id: int
    engine_id: int
    esn: str
    kind: str
    fault: str | None
    magnitude: float | None
    detected_at: datetime
    status: str


class DiagnosticReport(BaseModel):
    as_of: datetime = Field(description="when the states and events were read")
    since: datetime | None = Field(description="the previous report's as_of; null if none")
    baseline_job_id: int | None = Field(description="the previous fleet_diagnostics job")
    states: dict[str, str] = Field(description="engine id -> its state now")
    state_changes: list[StateChange]
    events_raised: list[RaisedEvent]
    n_events_raised: int


def _baseline(session: Session, operator_id: int) -> tuple[int, dict[str, Any]] | None:
    row = session.execute(
        select(Job.id, Job.result)
        .where(Job.operator_id == operator_id, Job.kind == KIND, Job.status == "succeeded")
        .order_by(Job.finished_at.desc(), Job.id.desc())
        .limit(1)
    ).first()
    if row is None or not isinstance(row.result, dict) or "as_of" not in row.result:
        return None  # none, or one stored before reports existed
    return row.id, row.result


def diagnostic_report(session: Session, operator_id: int) -> DiagnosticReport:
    as_of = utcnow()
    baseline = _baseline(session, operator_id)
    before: dict[str, str] = {} if baseline is None else dict(baseline[1].get("states") or {})
    since = None if baseline is None else datetime.fromisoformat(baseline[1]["as_of"])
    status = fleet_status(session, operator_id)
    states = {str(e["engine_id"]): e["state"] for e in status["engines"]}
    changes = [
        StateChange(
            engine_id=e["engine_id"], esn=e["esn"], tail=e["tail"], position=e["position"],
            from_state=before.get(str(e["engine_id"])), to_state=e["state"], reason=e["reason"],
        )
        for e in status["engines"]
        if before.get(str(e["engine_id"])) != e["state"]
    ]
    raised = select(Event, Engine.esn).join(Engine, Engine.id == Event.engine_id).where(
        Event.operator_id == operator_id, Event.created_at <= as_of
    )
    if since is not None:
        raised = raised.where(Event.created_at > since)
    rows = session.execute(raised.order_by(Event.created_at.desc(), Event.id.desc())).all()
    events = [
        RaisedEvent(
            event_id=event.id, engine_id=event.engine_id, esn=esn, kind=event.kind,
            fault=event.fault, magnitude=event.magnitude, detected_at=event.detected_at,
            status=event.status,
        )
        for event, esn in rows[:MAX_EVENTS]
    ]
    return DiagnosticReport(
        as_of=as_of, since=since, baseline_job_id=None if baseline is None else baseline[0],
        states=states, state_changes=changes, events_raised=events, n_events_raised=len(rows),
    )
