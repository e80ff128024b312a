"""The deterioration periods as stored, and the same periods computed directly from an
engine's stored estimates: the reference the pipeline's and the migration's periods are held to."""

from __future__ import annotations

from datetime import UTC, datetime

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.models.estimates import DeteriorationBucket, Estimate, EstimateLayout
from app.services.snapshots import buckets


def stored_periods(
    session: Session, engine_id: int
) -> dict[tuple[str, datetime], tuple[int, bytes]]:
    """The engine's deterioration periods: (period, start) -> (count, sums)."""
    return {
        (b.period, b.start): (b.n, bytes(b.sums))
        for b in session.scalars(
            select(DeteriorationBucket).where(DeteriorationBucket.engine_id == engine_id)
        )
    }


def periods_from_estimates(session: Session, engine_id: int, layout: EstimateLayout
                           ) -> dict[tuple[str, datetime], tuple[int, np.ndarray]]:
    """(period, start) -> (count, sums of the health and aux values) of the engine's stored
    estimates, by calendar arithmetic of its own (numpy datetime64 weeks from a Monday,
    calendar months)."""
    rows = session.execute(
        select(Estimate.recorded_at, Estimate.packed).where(Estimate.engine_id == engine_id)
    ).all()
    days = np.array([r[0].replace(tzinfo=None) for r in rows], dtype="datetime64[us]"
                    ).astype("datetime64[D]")
    values = layout.decode_blobs([r[1] for r in rows])[:, buckets.value_columns(layout)]
    monday = np.datetime64("2024-01-01")  # a Monday
    starts = {
        "week": monday + ((days - monday).astype(np.int64) // 7) * 7,
        "month": days.astype("datetime64[M]").astype("datetime64[D]"),
    }
    out = {}
    for period, start_of in starts.items():
        for start in np.unique(start_of):
            mine = start_of == start
            when = datetime.fromisoformat(str(start)).replace(tzinfo=UTC)
            out[(period, when)] = (int(mine.sum()), values[mine].sum(axis=0))
    return out
