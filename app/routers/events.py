"""Events: list, show, assign, acknowledge, comment, close; who they can be assigned to."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query

from app.schemas.estimates import (
    Assignee,
    AssignIn,
    CommentIn,
    EventAction,
    EventKind,
    EventOut,
    EventPage,
    EventStatusFilter,
)
from app.schemas.fleet import IsoDatetime
from app.security import Analyst, CurrentPrincipal, DbSession
from app.services.events import service as events

router = APIRouter(prefix="/api/v1/events", tags=["events"])


@router.get("", response_model=EventPage)
def list_events(
    session: DbSession,
    principal: CurrentPrincipal,
    status: Annotated[
        EventStatusFilter | None,
        Query(description='"active": open or acknowledged (not closed), as the fleet page counts'),
    ] = None,
    engine_id: int | None = None,
    kind: EventKind | None = None,
    since: Annotated[IsoDatetime | None, Query(description="at or after, ISO 8601")] = None,
    until: Annotated[IsoDatetime | None, Query(description="detected before")] = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
    offset: Annotated[int, Query(ge=0)] = 0,
) -> object:
    """Detected shifts and isolated faults, newest first."""
    return events.list_events(
        session, principal.operator_id, status=status, engine_id=engine_id, kind=kind,
        since=since, until=until, limit=limit, offset=offset,
    )


@router.get("/assignees", response_model=list[Assignee])
def list_assignees(session: DbSession, principal: CurrentPrincipal) -> object:
    """Who an event can be assigned to: the operator's active analyst and admin keys."""
    return events.assignees(session, principal.operator_id)


@router.get("/{event_id}", response_model=EventOut)
def show_event(event_id: int, session: DbSession, principal: CurrentPrincipal) -> object:
    """One event with the WSSR of every fault hypothesis and its comments."""
    return events.show_event(session, principal.operator_id, event_id)


@router.post("/{event_id}/assign", response_model=EventOut)
def assign(event_id: int, body: AssignIn, session: DbSession, principal: Analyst) -> object:
    """Assign the event to an analyst or admin key of the operator (null: to no one)."""
    return events.assign(session, principal, event_id, body.assignee_key_id)


@router.post("/{event_id}/ack", response_model=EventOut)
def acknowledge(event_id: int, body: EventAction, session: DbSession, principal: Analyst) -> object:
    """Acknowledge an open event with a reason (a repeat is a no-op)."""
    return events.acknowledge(session, principal, event_id, body.reason)


@router.post("/{event_id}/comments", response_model=EventOut, status_code=201)
def comment(event_id: int, body: CommentIn, session: DbSession, principal: Analyst) -> object:
    """Add a comment to an event."""
    return events.add_comment(session, principal, event_id, body.body)


@router.post("/{event_id}/close", response_model=EventOut)
def close(event_id: int, body: EventAction, session: DbSession, principal: Analyst) -> object:
    """Close an event with a reason (closing a closed event is a no-op)."""
    return events.close(session, principal, event_id, body.reason)
