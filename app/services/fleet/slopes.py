"""Fleet-average deterioration slope of each health parameter, with its 1-sigma.

Read from the weekly sums the pipeline keeps (``deterioration_buckets``: one row per engine and
week, ``app.services.snapshots.buckets``) and the engines' baseline resets (installations,
shop visits, module changes; a water wash does not reset: its recovery is part of the trend).
Each engine's weeks are split at its resets into pieces (a week holding a reset is left out,
a piece starts ``BASELINE_SETTLE_RECORDS`` records on) and a piece spanning at least
``MIN_SLOPE_YEARS`` gives a least-squares slope; the pieces' slopes are corrected by the
design's calibrated slope correction A (each parameter's error as read from every parameter's
estimated slope), the fleet's slope is their inverse-variance mean divided by the calibrated
gain, its 1-sigma from the calibrated noise and the gain's own standard error, times the
calibrated scale (``estimation.uncertainty``, module docstring). A calibration stored before
the correction has none (A = 0, scale 1): its slopes are as they were. A parameter whose
level or slope the calibration finds unobservable has no number (null) and is listed in
``unobservable``; a design without a calibration (an imported model) shows the plain
inverse-variance mean without a sigma (``"uncalibrated"``); a design calibrated before the
gain's standard error was (``Calibration.slope_sigma_known``) shows its corrected slope without
a sigma (``"recalibrate"``: run its ``calibrate_design`` job again).

The bench (bench/bench_uncertainty.py) scores exactly this arithmetic against the fleet
simulator's truth (``calibration.trend_pieces`` forms the same pieces from the same weekly
means).
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.models import Installation, MaintenanceAction
from app.models.estimates import DeteriorationBucket, EstimateLayout
from app.services.designs.calibration import (
    BASELINE_KINDS,
    BASELINE_SETTLE_RECORDS,
    MIN_SLOPE_YEARS,
    SLOPE_PERIOD,
    design_calibration,
)
from app.services.snapshots.buckets import period_ends
from estimation import uncertainty

UNIT = "%/year"


@dataclass(frozen=True)
class FleetSlopes:
    """One design's fleet-average slopes [p] (percent per year; NaN: not shown)."""

    names: tuple[str, ...]
    slope: np.ndarray
    sigma: np.ndarray  # NaN: uncalibrated, to recalibrate or not shown
    unobservable: tuple[str, ...]
    uncertainty: Literal["calibrated", "uncalibrated", "recalibrate"]
    pieces: int  # engine trends the slopes are taken over
    engines: int

    def to_dict(self) -> dict[str, Any]:
        def number(x: float) -> float | None:
            return round(float(x), 4) if np.isfinite(x) else None

        return {
            "unit": UNIT, "uncertainty": self.uncertainty, "pieces": self.pieces,
            "engines": self.engines, "unobservable": list(self.unobservable),
            "health": [{"name": n, "slope": number(s), "sigma": number(e)}
                       for n, s, e in zip(self.names, self.slope, self.sigma, strict=True)],
        }


def _resets(session: Session, engine_ids: list[int]) -> dict[int, np.ndarray]:
    """Epoch seconds of each engine's installations, shop visits and module changes."""
    out: dict[int, list[float]] = defaultdict(list)
    for engine_id, t in session.execute(
        select(Installation.engine_id, Installation.installed_at)
        .where(Installation.engine_id.in_(engine_ids))
    ):
        out[engine_id].append(t.timestamp())
    for engine_id, t in session.execute(
        select(MaintenanceAction.engine_id, MaintenanceAction.performed_at)
        .where(MaintenanceAction.engine_id.in_(engine_ids),
               MaintenanceAction.kind.in_(BASELINE_KINDS))
    ):
        out[engine_id].append(t.timestamp())
    return {e: np.array(sorted(v), dtype=float) for e, v in out.items()}


def fleet_slopes(
    session: Session, operator_id: int, design_id: int, layout: EstimateLayout,
) -> FleetSlopes:
    """The design's fleet-average deterioration slopes (module docstring)."""
    names = tuple(layout.health)
    p = len(names)
    width = p + len(layout.aux)
    rows = session.execute(
        select(DeteriorationBucket.engine_id, DeteriorationBucket.start, DeteriorationBucket.n,
               DeteriorationBucket.sums)
        .where(DeteriorationBucket.design_id == design_id,
               DeteriorationBucket.period == SLOPE_PERIOD,
               DeteriorationBucket.operator_id == operator_id)
        .order_by(DeteriorationBucket.engine_id, DeteriorationBucket.start)
    ).all()
    per_engine: dict[int, list[Any]] = defaultdict(list)
    for row in rows:
        per_engine[row[0]].append(row)
    resets = _resets(session, list(per_engine)) if per_engine else {}
    slopes, spans = [], []
    for engine_id, weeks in per_engine.items():
        starts = np.fromiter((w[1].timestamp() for w in weeks), float, len(weeks))
        n = np.fromiter((w[2] for w in weeks), float, len(weeks))
        sums = np.frombuffer(b"".join(w[3] for w in weeks), "<f8").reshape(len(weeks), width)
        slope, span = uncertainty.period_pieces(
            starts, period_ends(starts, SLOPE_PERIOD), n, sums[:, :p] / n[:, None],
            resets.get(engine_id, np.zeros(0)), BASELINE_SETTLE_RECORDS, MIN_SLOPE_YEARS)
        slopes.append(slope)
        spans.append(span)
    piece_slopes = np.concatenate(slopes) if slopes else np.empty((0, p))
    piece_spans = np.concatenate(spans) if spans else np.empty(0)
    calib = design_calibration(session, design_id)
    gain, noise, common = np.ones(p), np.full(p, np.nan), np.zeros(p)
    gain_std = np.zeros(p)
    correction, scale = np.zeros((p, p)), np.ones(p)
    hidden = np.zeros(p, bool)
    state: Literal["calibrated", "uncalibrated", "recalibrate"] = "uncalibrated"
    if calib is not None:
        on = calib.on(names)
        gain, noise, common, gain_std = (
            np.asarray(v, float)
            for v in (on.slope_gain, on.slope_noise, on.slope_common, on.slope_gain_std))
        correction, scale = np.asarray(on.slope_correction), np.asarray(on.slope_scale)
        hidden = ~(on.observable & np.isfinite(gain))
        state = "calibrated" if on.slope_sigma_known else "recalibrate"
    slope, sigma = uncertainty.fleet_slope(piece_slopes, piece_spans,
                                           np.where(hidden, 1.0, gain), noise, common, gain_std,
                                           correction, scale)
    return FleetSlopes(
        names=names, slope=np.where(hidden, np.nan, slope),
        sigma=np.where(hidden, np.nan, sigma),
        unobservable=tuple(n for n, h in zip(names, hidden, strict=True) if h),
        uncertainty=state, pieces=len(piece_spans), engines=len(per_engine),
    )
