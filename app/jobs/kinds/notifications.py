"""Sending alert notifications: the deliveries the pipeline queued, after its commit."""

from __future__ import annotations

import time
from typing import Any

from pydantic import BaseModel, ConfigDict, Field
from sqlalchemy.orm import Session

from app.models.base import utcnow
from app.services.jobs.registry import Progress, registry
from app.services.notifications import sender

# The longest single wait for a retry that falls due (seconds); progress is reported between.
WAIT_SLICE = 1.0


class SendNotifications(BaseModel):
    model_config = ConfigDict(extra="forbid")

    backoff_seconds: float = Field(
        30.0, gt=0, le=3600, description="Wait before the first retry; doubled each retry."
    )
    max_attempts: int = Field(5, ge=1, le=20, description="Attempts before giving up.")
    follow_up: bool = Field(
        default=False, description="queued while another sending runs: it starts when that ends"
    )


@registry.job(
    "send_notifications",
    parameters=SendNotifications,
    description="Send pending webhook and e-mail notifications, retrying with backoff.",
    role="admin",
    submittable=False,
    serial=True,
)
def send_notifications(
    session: Session, parameters: SendNotifications, progress: Progress, *, operator_id: int
) -> dict[str, Any]:
    """Send what is due, then wait for retries falling due until nothing is pending (each
    delivery gives up after ``max_attempts``, so the job ends)."""
    policy = sender.RetryPolicy(parameters.backoff_seconds, parameters.max_attempts)
    totals = sender.SendCounts()
    while True:
        counts = sender.send_due(session, operator_id, policy, session.commit)
        totals.sent += counts.sent
        totals.failed += counts.failed
        totals.retrying += counts.retrying
        due = sender.next_due(session, operator_id)
        session.commit()  # end the read: the wait holds no transaction open
        if due is None:
            break
        progress(0.5, f"sent {totals.sent}, failed {totals.failed}; next retry at "
                      f"{due:%H:%M:%S} UTC")
        time.sleep(max(0.0, min(WAIT_SLICE, (due - utcnow()).total_seconds())))
    return {"sent": totals.sent, "failed": totals.failed, "retries": totals.retrying}

