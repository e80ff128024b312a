"""The recovery measured after a maintenance action (a water wash above all): the change of the
engine's health parameters and EGT margin between the records before the action and those after.

Before is the mean of the last ``RECOVERY_RECORDS`` records in the ``WINDOW`` before the action,
after the mean of the next ``RECOVERY_RECORDS`` once the estimates have settled on the new level
(``settle`` records after the action, as the trend's change view waits after a shop visit: the
filter follows a step with a lag, and the EGT margin is smoothed over about ten flights);
neither side reaches past the engine's neighbouring maintenance actions, so an earlier or later
wash does not mix into this one's numbers. The change is after minus before (a positive
EGT-margin change and a positive efficiency change are a recovery), with its standard error
from the scatter of the records on each side, sqrt(s_b^2 / n_b + s_a^2 / n_a). The health
parameters are the stored levels of the design (``health=level`` of the trend), the EGT margin
the trend's performance group (designs of the built-in engine only).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.models import MaintenanceAction
from app.services.fleet import maintenance
from app.services.trends import health as health_view
from app.services.trends.service import engine_trend

RECOVERY_RECORDS = 20
WINDOW = timedelta(days=60)
# (trend group, series names: None for every series of the group)
MEASURED: tuple[tuple[str, tuple[str, ...] | None], ...] = (
    ("performance", ("egt_margin",)),
    ("health", None),
)


@dataclass(frozen=True)
class SeriesRecovery:
    group: str
    name: str
    unit: str
    before: float
    after: float
    change: float
    standard_error: float | None


@dataclass(frozen=True)
class Recovery:
    maintenance_action_id: int
    engine_id: int
    kind: str
    performed_at: datetime
    design_id: int | None
    n_before: int
    n_after: int
    series: tuple[SeriesRecovery, ...]
    note: str | None


def _neighbours(
    session: Session, action: MaintenanceAction
) -> tuple[datetime | None, datetime | None]:
    """The times of the engine's maintenance actions just before and just after ``action``."""
    base = select(MaintenanceAction.performed_at).where(
        MaintenanceAction.engine_id == action.engine_id, MaintenanceAction.id != action.id
    )
    before = session.scalar(
        base.where(MaintenanceAction.performed_at < action.performed_at)
        .order_by(MaintenanceAction.performed_at.desc()).limit(1)
    )
    after = session.scalar(
        base.where(MaintenanceAction.performed_at > action.performed_at)
        .order_by(MaintenanceAction.performed_at).limit(1)
    )
    return before, after


def _side_mean(values: np.ndarray) -> tuple[float, float, int] | None:
    known = values[~np.isnan(values)]
    if not len(known):
        return None
    var = float(np.var(known, ddof=1)) if len(known) > 1 else math.nan
    return float(np.mean(known)), var, len(known)


def _series(
    group: str, item: dict[str, Any], before: np.ndarray, after: np.ndarray
) -> SeriesRecovery | None:
    values = np.array([math.nan if v is None else v for v in item["value"]], dtype=float)
    b, a = _side_mean(values[before]), _side_mean(values[after])
    if b is None or a is None:
        return None
    (mean_b, var_b, n_b), (mean_a, var_a, n_a) = b, a
    se = math.sqrt(var_b / n_b + var_a / n_a)
    return SeriesRecovery(
        group=group, name=item["name"], unit=item["unit"], before=mean_b, after=mean_a,
        change=mean_a - mean_b, standard_error=None if math.isnan(se) else se,
    )


def recovery(
    session: Session, operator_id: int, action_id: int, *, design_id: int | None = None,
    records: int = RECOVERY_RECORDS, settle: int = health_view.BASELINE_SETTLE_RECORDS,
) -> Recovery:
    """The recovery of one maintenance action of the operator (404 for another's)."""
    action = maintenance.get_action(session, operator_id=operator_id, action_id=action_id)
    previous, following = _neighbours(session, action)
    start = action.performed_at - WINDOW
    end = action.performed_at + WINDOW
    if previous is not None:
        start = max(start, previous)
    if following is not None:
        end = min(end, following)
    trend = engine_trend(
        session, operator_id, action.engine_id, design_id=design_id, start=start, end=end,
        max_points=0, markers=False, health="level",
    )
    at = action.performed_at.timestamp()
    epoch = np.array([datetime.fromisoformat(t).timestamp() for t in trend["time"]], dtype=float)
    before_idx = np.flatnonzero(epoch < at)[-records:]
    after_all = np.flatnonzero(epoch >= at)
    after_idx = after_all[settle:settle + records]

    def result(series: tuple[SeriesRecovery, ...], note: str | None) -> Recovery:
        return Recovery(
            maintenance_action_id=action.id, engine_id=action.engine_id, kind=action.kind,
            performed_at=action.performed_at, design_id=trend["design_id"],
            n_before=len(before_idx), n_after=len(after_idx), series=series, note=note,
        )

    if trend["design_id"] is None:
        return result((), "no design: the engine type has no active design")
    if not len(before_idx):
        return result((), f"no estimates before the action within {WINDOW.days} days")
    if not len(after_idx):
        return result((), f"not settled yet: {len(after_all)} records after the action, "
                          f"the recovery is measured from record {settle + 1} on")
    groups = {g["key"]: g for g in trend["groups"]}
    out = []
    for key, names in MEASURED:
        group = groups.get(key)
        if group is None:
            continue
        for item in group["series"]:
            if names is not None and item["name"] not in names:
                continue
            measured = _series(key, item, before_idx, after_idx)
            if measured is not None:
                out.append(measured)
    return result(tuple(out), None)
