"""Estimation kinds: bring engines' estimates up to date after uploads, and the scheduled
fleet-wide diagnostic run."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field
from sqlalchemy.orm import Session

from app.services.fleet import diagnostic_report, diagnostics, red_alerts
from app.services.jobs.registry import Progress, registry
from app.services.jobs.store import queue_estimation, queue_sending
from app.services.notifications import outbox
from app.services.snapshots import store as snapshots_store

# The default schedule of the fleet-wide diagnostic job (seconds): once a day.
FLEET_DIAGNOSTICS_INTERVAL = 24 * 3600


class EstimateEngines(BaseModel):
    """The job finds every snapshot without an estimate and estimates it."""

    model_config = ConfigDict(extra="forbid")
    follow_up: bool = Field(
        default=False,
        description="queued while another estimation runs: it starts when that one ends",
    )


@registry.job(
    "estimate_engines",
    parameters=EstimateEngines,
    description="Run the snapshot filter, shift detection and isolation over new snapshots.",
    role="analyst",
    submittable=False,
    serial=True,
)
def estimate_engines(
    session: Session, parameters: EstimateEngines, progress: Progress, *, operator_id: int
) -> dict[str, Any]:
    """Notifications of the events raised were queued with them, those of engines whose limits
    turned red are queued here; their sending is queued too, committed with the job's result
    and dispatched after."""
    summary = snapshots_store.catch_up(
        session, operator_id, progress=progress, commit=session.commit
    )
    summary["engines_turned_red"] = red_alerts.queue_turned_red(
        session, operator_id, reads_apart=True
    )
    if outbox.has_pending(session, operator_id):
        summary["notifications_job_id"] = queue_sending(
            session, operator_id=operator_id, job_registry=registry
        ).id
    return summary


class FleetDiagnostics(BaseModel):
    model_config = ConfigDict(extra="forbid")


@registry.job(
    "fleet_diagnostics",
    parameters=FleetDiagnostics,
    description="Summarise shift detection and fault isolation over every engine of the fleet.",
    role="analyst",
)
def fleet_diagnostics(
    session: Session, parameters: FleetDiagnostics, progress: Progress, *, operator_id: int
) -> dict[str, Any]:
    """The summary and the report (engines whose state changed and events raised since the
    previous run, ``diagnostic_report``); snapshots left unestimated are marked and get an
    estimation job queued, and notifications left pending (an estimation job that failed after
    committing some batches queued no sending) get their sending queued."""
    summary = diagnostics.fleet_diagnostics(session, operator_id, progress=progress)
    progress(0.9, "comparing engine states with the previous run")
    report = diagnostic_report.diagnostic_report(session, operator_id)
    summary.update(report.model_dump(mode="json"))
    if summary["n_engines_waiting"]:
        job = queue_estimation(session, operator_id=operator_id, job_registry=registry)
        summary["estimation_job_id"] = job.id
    if outbox.has_pending(session, operator_id):
        summary["notifications_job_id"] = queue_sending(
            session, operator_id=operator_id, job_registry=registry
        ).id
    return summary
