"""The trend's ``performance`` group: thrust, stall margins, EGT margin and the deltas in
engineering units (``app.services.fleet.performance``), with the engine type's limit lines.

Only designs of the built-in engine have the schedule the conversion needs; others get no
group. The values are computed per record, then bucketed like every other group (mean, min,
max of consecutive records).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.models import Engine, EngineType
from app.models.estimates import EstimateLayout
from app.services.fleet import performance
from app.services.snapshots import estimator
from estimation import uncertainty

LABEL = "Engineering units: thrust, stall margins, EGT margin, deltas"


def limit_lines(limits: dict[str, Any], nominal_margin_c: float) -> list[dict[str, Any]]:
    """Lines the engine page draws: the EGT margin and thrust-deficit levels, and the dEGT at
    which the margin reaches each EGT-margin level."""
    lines = []
    for level in ("amber", "red"):
        egt = limits["egt_margin"][level]
        lines.append({"series": "egt_margin", "level": level, "value": egt, "unit": "degC"})
        lines.append({"series": "dEGT", "level": level,
                      "value": round(nominal_margin_c - egt, 2), "unit": "degC"})
        lines.append({"series": "thrust_deficit", "level": level,
                      "value": limits["thrust_deficit"][level], "unit": "%"})
    return lines


def performance_group(
    session: Session,
    engine_id: int,
    design_id: int,
    layout: EstimateLayout,
    epoch: np.ndarray,
    values: np.ndarray,
    starts: np.ndarray | None,
    columns_of: Any,
    calibration: uncertainty.Calibration | None = None,
) -> dict[str, Any] | None:
    """The group for records (epoch [n], packed values [n, width]: the aux 1-sigma already
    made honest by ``trends.health.apply``); None when the design's engine has no schedule.
    Each series' 1-sigma is ``performance.engineering_sigma``'s, the measured figures' from
    ``calibration`` (none without it)."""
    schedule = estimator.builtin_schedule_for_design(session, design_id)
    if schedule is None or len(epoch) == 0:
        return None
    engine_type = session.scalar(
        select(EngineType).join(Engine, Engine.engine_type_id == EngineType.id)
        .where(Engine.id == engine_id)
    )
    limits = (engine_type.effective_limits if engine_type is not None
              else EngineType().effective_limits)
    records = performance.record_conditions(session, engine_id, epoch)
    z = np.asarray(values[:, layout.slices()["z"]], dtype=float)
    trims = estimator.schedule_trims(schedule, records.conditions)
    baseline = estimator.baseline_trims(records.conditions, schedule, trims)
    series = performance.engineering_units(
        schedule, layout, z, records, limits["egt_redline_c"], baseline, trims
    )
    if not series:
        return None
    z_sigma = np.asarray(values[:, layout.slices()["z_sigma"]], dtype=float)
    delta_std = value_sigma = None
    if calibration is not None:
        delta_std = {name: std for name in calibration.delta_names
                     if (std := calibration.delta_model_std(name)) is not None}
        value_sigma = calibration.value_sigma(layout.aux, z_sigma)
    sigmas = performance.engineering_sigma(
        schedule, layout, z_sigma, records, delta_std, value_sigma, trims,
    )
    matrix = np.stack([v for _n, _u, v in series], axis=1)
    banded = [j for j, (name, _u, _v) in enumerate(series) if name in sigmas]
    sigma = (np.stack([sigmas[series[j][0]] for j in banded], axis=1) if banded
             else np.empty((len(epoch), 0)))
    rows: dict[str, np.ndarray] = {}
    if starts is None:
        rows["value"] = matrix
        sigma_rows = sigma
    else:
        counts = np.diff(np.append(starts, len(epoch)))
        rows["value"] = np.add.reduceat(matrix, starts, axis=0) / counts[:, None]
        rows["min"] = np.minimum.reduceat(matrix, starts, axis=0)
        rows["max"] = np.maximum.reduceat(matrix, starts, axis=0)
        # A bucket's sigma: that of its mean's records, taken as the mean sigma (the errors of
        # consecutive records are mostly the same design bias, not independent).
        sigma_rows = (np.add.reduceat(sigma, starts, axis=0) / counts[:, None] if banded
                      else sigma[: len(starts)])
    encoded = {key: columns_of(np.ascontiguousarray(m.T)) for key, m in rows.items()}
    sigma_columns = columns_of(np.ascontiguousarray(sigma_rows.T)) if banded else []
    items = []
    for j, (name, unit, _v) in enumerate(series):
        item: dict[str, Any] = {"name": name, "unit": unit, "value": None, "sigma": None,
                                "min": None, "max": None}
        for key, columns in encoded.items():
            item[key] = columns[j]
        if j in banded:
            item["sigma"] = sigma_columns[banded.index(j)]
        items.append(item)
    nominal = performance.nominal_margin_c(schedule, limits["egt_redline_c"])
    return {"key": "performance", "label": LABEL, "series": items,
            "limits": limit_lines(limits, nominal)}
