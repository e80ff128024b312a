"""One estimation at a time per operator: a job queued while one runs waits for it, and an
upload committed while one runs always has a job that starts after it."""

from __future__ import annotations

from sqlalchemy import update
from sqlalchemy.orm import Session, sessionmaker

from app.jobs.claim import claim_job, claim_next
from app.jobs.kinds import load_kinds
from app.models import Job
from app.services.jobs.store import queue_estimation
from app.services.tenancy import service as tenancy


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
