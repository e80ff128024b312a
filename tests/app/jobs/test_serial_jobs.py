"""One estimation at a time per operator: a job queued while one runs waits for it, and an
upload committed while one runs always has a job that starts after it."""

from __future__ import annotations

import threading

from sqlalchemy import delete, insert, update
from sqlalchemy.orm import Session, sessionmaker

from app.db import transaction
from app.jobs.claim import claim_job, claim_next
from app.jobs.kinds import load_kinds
from app.jobs.kinds.estimation import EstimateEngines
from app.models import Job
from app.services.jobs.registry import parameters_checksum
from app.services.jobs.store import queue_estimation
from app.services.tenancy import service as tenancy
from tests.support.jobs import Live, connection, live, live_module

# Fixtures from jobs_support: the isolating connection replaces the shared one here.
__all__ = ["connection", "live", "live_module"]


def test_an_estimation_queued_while_one_runs_starts_after_it(
    session: Session, session_factory: sessionmaker[Session]
) -> None:
    kinds = load_kinds()
    serial = kinds.serial_kinds()
    assert "estimate_engines" in serial and "evaluate_design" not in serial
    north = tenancy.create_operator(session, name="North Serial Air").id
    south = tenancy.create_operator(session, name="South Serial Air").id
    first = queue_estimation(session, operator_id=north, job_registry=kinds)
    assert queue_estimation(session, operator_id=north, job_registry=kinds).id == first.id
    session.commit()

    claim = claim_next(session_factory, worker="w1", serial_kinds=serial)
    assert claim is not None and claim.job_id == first.id
    session.expire_all()
    # Rows committed now might come after the running job's last look: a follow-up, once.
    follow = queue_estimation(session, operator_id=north, job_registry=kinds)
    assert follow.id != first.id and follow.status == "queued"
    assert follow.parameters == {"follow_up": True}
    assert queue_estimation(session, operator_id=north, job_registry=kinds).id == follow.id
    other = queue_estimation(session, operator_id=south, job_registry=kinds)
    session.commit()

    # The follow-up waits while the first runs, through the runner and through a message;
    # another operator's estimation does not.
    assert claim_job(session_factory, follow.id, worker="w2", serial_kinds=serial) is None
    claim = claim_next(session_factory, worker="w2", serial_kinds=serial)
    assert claim is not None and claim.job_id == other.id
    assert claim_next(session_factory, worker="w2", serial_kinds=serial) is None
    # The first one ends: the follow-up starts.
    session.execute(update(Job).where(Job.id == first.id).values(status="succeeded"))
    session.commit()
    claim = claim_next(session_factory, worker="w2", serial_kinds=serial)
    assert claim is not None and claim.job_id == follow.id


def test_two_queued_estimations_claimed_at_once_never_both_run(live: Live) -> None:
    """An estimation and its follow-up can both be queued (the follow-up was queued while one
    ran; that one ended; an upload then queued a new one). Two workers claiming them at the
    same instant must not both start: on PostgreSQL each claim's check for a running sibling
    would not see the other's uncommitted claim, and two estimations of one operator would
    write the same estimates."""
    _url, factory = live
    kinds = load_kinds()
    serial = kinds.serial_kinds()
    with transaction(factory) as session:
        operator_id = tenancy.create_operator(session, name="Racing Serial Air").id
    for _ in range(20):
        with transaction(factory) as session:
            ids = [
                session.execute(insert(Job).values(
                    operator_id=operator_id, kind="estimate_engines", parameters=p,
                    checksum=parameters_checksum("estimate_engines", EstimateEngines(**p)),
                    status="queued", progress=0.0, message="queued", attempts=0,
                ).returning(Job.id)).scalar_one()
                for p in ({}, {"follow_up": True})
            ]
        start = threading.Barrier(2)
        claims: list[object] = []

        def claim(job_id: int, start: threading.Barrier = start,
                  claims: list[object] = claims) -> None:
            start.wait()
            claims.append(claim_job(factory, job_id, worker="racer", serial_kinds=serial))

        threads = [threading.Thread(target=claim, args=(i,)) for i in ids]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert sum(c is not None for c in claims) == 1
        with transaction(factory) as session:
            session.execute(delete(Job).where(Job.id.in_(ids)))
