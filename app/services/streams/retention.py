"""Retention of raw stream samples: the Parquet files of closed recordings older than
``stream_retention_days`` (app/config.py) are deleted; what was derived from them stays.

A recording keeps its row, its chunk rows, its stream estimates and the snapshot records of its
steady windows (hence their estimates, events and trend points); ``samples_removed_at`` says
when its files went, and the pages and the API say so instead of showing samples. A recording
whose samples are gone is not estimated again (a new design estimates recordings that still
have theirs). The purge runs as the ``purge_stream_samples`` job (app/jobs/kinds/maintenance.py),
which an operator schedules (daily, say) through the job schedules.

Files go before the row is marked, in the row's transaction: a crash in between leaves a
recording marked as still having samples whose files are gone, and the next purge marks it.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from datetime import datetime, timedelta
from pathlib import Path
from typing import NamedTuple

from sqlalchemy import select
from sqlalchemy.orm import Session

from app.errors import ServiceError
from app.models import StreamRecording
from app.models.base import utcnow


class SamplesRemoved(ServiceError):
    """The samples of a recording were deleted by the retention setting."""

    status_code = 410
    code = "samples_removed"


def check_kept(recording: StreamRecording) -> None:
    """Raise ``SamplesRemoved`` when the recording's sample files are gone."""
    if recording.samples_removed_at is not None:
        raise SamplesRemoved(
            f"the samples of recording {recording.id} were removed on "
            f"{recording.samples_removed_at.isoformat()} (stream sample retention); its "
            "estimates and steady-window records are kept"
        )


class Purged(NamedTuple):
    recordings: int
    files: int
    bytes: int


def due(session: Session, *, operator_id: int, older_than: timedelta,
        now: datetime | None = None) -> list[StreamRecording]:
    """Closed recordings of the operator, closed before ``now - older_than``, that still have
    their samples; oldest first."""
    cutoff = (now or utcnow()) - older_than
    return list(session.scalars(
        select(StreamRecording)
        .where(StreamRecording.operator_id == operator_id,
               StreamRecording.status == "closed",
               StreamRecording.closed_at < cutoff,
               StreamRecording.samples_removed_at.is_(None))
        .order_by(StreamRecording.closed_at, StreamRecording.id)
    ).all())


def purge(
    session: Session, *, operator_id: int, data_dir: Path, older_than: timedelta,
    now: datetime | None = None, commit: Callable[[], None] | None = None,
) -> Purged:
    """Delete the sample files of the operator's recordings ``due`` and mark them; ``commit``
    (a job's) after each recording, so a restart goes on with the rest."""
    now = now or utcnow()
    recordings = files = size = 0
    for recording in due(session, operator_id=operator_id, older_than=older_than, now=now):
        folder = data_dir / recording.path
        if folder.is_dir():
            found = [p for p in folder.iterdir() if p.is_file()]
            files += len(found)
            size += sum(p.stat().st_size for p in found)
            shutil.rmtree(folder)
        recording.samples_removed_at = now
        recordings += 1
        if commit is not None:
            commit()
    session.flush()
    return Purged(recordings, files, size)
