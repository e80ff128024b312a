"""The fleet-wide diagnostic summary: where every engine's detector and isolation stand.

It reads stored state, so it runs beside the estimation job without racing it: per engine
under its type's active design, the CUSUM statistic and any alarm awaiting isolation (from the
filter state), the hypothesis with the smallest WSSR on the latest estimate and whether that
WSSR is small enough to name it, open events, and whether snapshots are waiting to be estimated.
Its one write is the backlog check (``estimation_runs.audit``): waiting snapshots that no mark
covers get one, for the estimation job it queues.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from typing import Any

import numpy as np
from sqlalchemy import and_, select
from sqlalchemy.orm import Session

from app.models import Engine, EstimatorDesign
from app.models.estimates import Estimate, EstimateLayout, FilterState
from app.services.events.service import open_event_counts
from app.services.snapshots.estimator import cusum_for
from app.services.snapshots.store import audit


def fleet_diagnostics(
    session: Session, operator_id: int, progress: Callable[..., None] | None = None
) -> dict[str, Any]:
    """Summary per engine and for the fleet (a job result: plain JSON)."""
    rows = session.execute(
        select(Engine.id, Engine.esn, FilterState.layout, FilterState.state,
               FilterState.n_records, FilterState.last_recorded_at, Estimate.packed)
        .join(FilterState, FilterState.engine_id == Engine.id)
        .join(
            EstimatorDesign,
            and_(EstimatorDesign.id == FilterState.design_id, EstimatorDesign.active.is_(True),
                 EstimatorDesign.engine_type_id == Engine.engine_type_id),
        )
        .outerjoin(
            Estimate,
            and_(Estimate.engine_id == FilterState.engine_id,
                 Estimate.design_id == FilterState.design_id,
                 Estimate.seq == FilterState.n_records - 1),
        )
        .where(Engine.operator_id == operator_id)
        .order_by(Engine.esn)
    ).all()
    behind = audit(session, operator_id)
    open_events = open_event_counts(session, operator_id)
    engines = []
    nearest_counts: Counter[str] = Counter()
    for i, (engine_id, esn, layout_doc, state, n_records, last, packed) in enumerate(rows):
        layout = EstimateLayout.from_dict(layout_doc)
        detector = (state or {}).get("detector") or {}
        m = len(layout.tuners)
        cusum = cusum_for(m) if m else None
        nearest = None
        nearest_wssr = None
        if packed is not None and layout.faults:
            wssr = layout.decode_blobs([packed])[0][layout.slices()["wssr"]]
            if np.isfinite(wssr).all():
                k = int(np.argmin(wssr))
                nearest, nearest_wssr = layout.faults[k], float(wssr[k])
                nearest_counts[nearest] += 1
        pending = detector.get("pending")
        engines.append(
            {
                "engine_id": engine_id,
                "esn": esn,
                "records": n_records,
                "last_data": None if last is None else last.isoformat(),
                "cusum": float(detector.get("S", 0.0)),
                "cusum_threshold": None if cusum is None else cusum.threshold,
                "alarm_pending_since_seq": None if pending is None else int(pending["seq"]),
                "nearest_fault": nearest,
                "nearest_wssr": nearest_wssr,
                "open_events": open_events.get(engine_id, 0),
                "snapshots_waiting": engine_id in behind,
            }
        )
        if progress is not None and (i + 1) % 100 == 0:
            progress((i + 1) / len(rows), f"summarised {i + 1} of {len(rows)} engines")
    return {
        "engines": engines,
        "n_engines": len(engines),
        "n_open_events": sum(open_events.values()),
        "n_alarms_pending": sum(e["alarm_pending_since_seq"] is not None for e in engines),
        "n_engines_waiting": len(behind),
        "nearest_fault_counts": dict(nearest_counts),
    }
