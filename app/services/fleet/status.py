"""Fleet status (every engine with its latest state) and fleet-average deterioration.

The status page reads a fixed number of queries whatever the fleet size, each one row per
engine: engines with their current installation, the active designs, each engine's filter
state with, by key, the estimate it points at (``seq = n_records - 1`` through the primary key
(engine, design, seq)), the one ``RATE_WINDOW`` records back and its EGT window (the median
dEGT of its last records, kept by the pipeline: ``app.services.snapshots.egt``), and the
active events. An engine whose EGT window was not taken at its current filter state has its
last records read instead (none after a pipeline run).

An engine's health is the level its engine page shows (``shown_level``): with the design's
calibration, the calibrated level, and a parameter the design cannot observe null and left out
of the worst and of the rate of change (its raw estimate can be far off: the demo design's
lpc_eff reads tens of percent on engines whose true change is a few).

An engine's severity (``app.services.fleet.severity``) is the worst of its engine type's limit
checks (health change, EGT margin, thrust deficit, rate of change; amber and red) and its active
events (open or acknowledged); its ``state`` says the same in the fleet page's words: red is
``alert``, amber ``watch``, else ``normal`` (``no_data`` without estimates nor events). Engines
come ranked: red, amber, normal, then by how far past (or short of) their amber level.
``WATCH_PERCENT`` is the older rule (a health parameter past 1.5 % and 3 sigma), kept as the
``watch`` flag of ``health_summary`` callers.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import numpy as np
from sqlalchemy import and_, select
from sqlalchemy.orm import Session

from app.errors import InvalidInput
from app.models import (
    Engine,
    EngineModel,
    EngineType,
    EstimatorDesign,
    Operator,
)
from app.models.designs import effective_limits
from app.models.estimates import (
    EgtWindow,
    Estimate,
    EstimateLayout,
    Event,
    FilterState,
    FleetPeriod,
)
from app.services.common import json_numbers_or_null, no_gc_pauses
from app.services.designs.calibration import design_calibration
from app.services.events.service import latest_open_events, open_event_counts
from app.services.fleet import performance, slopes
from app.services.fleet.service import current_placements
from app.services.fleet.severity import LEVELS, LimitValue, rank, severity
from app.services.snapshots import egt, estimator
from estimation import uncertainty
from estimation.engine.deltas import STATUS_EGT_MARGIN, reference_egt
from estimation.engine.schedule import EngineSchedule
from estimation.uncertainty import RATE_WINDOW

WATCH_PERCENT = 1.5
WATCH_SIGMAS = 3.0
# The EGT margin of the status is the median dEGT over an engine's last EGT_WINDOW records
# (``app.services.snapshots.egt``); the rate of change compares the latest health level with
# the one RATE_WINDOW records back, per 100 records.
STATE_OF_LEVEL = {"red": "alert", "amber": "watch", "normal": "normal"}
THRUST_NAMES = ("fn", "thrust", "f_n")


def thrust_index(aux: tuple[str, ...]) -> int | None:
    for j, name in enumerate(aux):
        if name.lower() in THRUST_NAMES:
            return j
    return None


def shown_level(
    layout: EstimateLayout, calib: uncertainty.Calibration | None, h: np.ndarray,
    h_sigma: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The health level and 1-sigma [..., p] that the engine page shows for estimates h [...,
    p] with the filter's h_sigma: with the design's calibration, the calibrated level and its
    honest sigma (``Calibration.level``), a parameter it finds unobservable NaN; without, the
    estimates as stored."""
    if calib is None:
        return h, h_sigma
    on = calib.on(layout.health)
    level, sigma = on.level(h, h_sigma)
    hidden = ~np.asarray(on.observable)
    return np.where(hidden, np.nan, level), np.where(hidden, np.nan, sigma)


def shown_aux(
    layout: EstimateLayout, calib: uncertainty.Calibration | None, z: np.ndarray, h: np.ndarray,
) -> np.ndarray:
    """The aux outputs [..., n_aux] that the engine page shows for estimates z with the health
    estimates h: with the design's calibration, calibrated (``Calibration.aux_level``);
    without, as stored."""
    if calib is None:
        return np.asarray(z, float)
    return calib.on(layout.health).aux_level(layout.aux, z, h)


def _worst(h: np.ndarray) -> np.ndarray:
    """Index [n] of the largest |h| of each row [n, p], unobservable (NaN) ones left out; -1
    where every one is."""
    magnitude = np.where(np.isnan(h), -1.0, np.abs(h))
    return np.where(np.all(np.isnan(h), axis=1), -1, np.argmax(magnitude, axis=1))


def _listed(values: np.ndarray) -> list[float | None]:
    return [None if np.isnan(v) else v for v in np.round(values, 4).tolist()]


def health_summary(
    layout: EstimateLayout, values: np.ndarray, recorded_at: datetime, seq: int,
    calib: uncertainty.Calibration | None = None,
) -> dict[str, Any]:
    """Brief of one estimate: the worst health parameter (of the level the engine page shows:
    ``shown_level``) and the thrust deficit.

    The one-engine statement of what ``_summaries`` computes for a whole fleet at once (the
    tests compare the two)."""
    s = layout.slices()
    h, h_sigma = shown_level(layout, calib, values[s["h"]][None], values[s["h_sigma"]][None])
    z = shown_aux(layout, calib, values[s["z"]][None], values[s["h"]][None])[0]
    found = int(_worst(h)[0]) if h.shape[1] else -1
    worst = None if found < 0 else found
    k = thrust_index(layout.aux)
    return {
        "recorded_at": recorded_at,
        "seq": seq,
        "worst_health": None if worst is None else layout.health[worst],
        "worst_health_value": None if worst is None else round(float(h[0, worst]), 4),
        "worst_health_sigma": None if worst is None else round(float(h_sigma[0, worst]), 4),
        "thrust_deficit": None if k is None else round(float(-z[k]), 4),
        "health": dict(zip(layout.health, _listed(h[0]), strict=True)),
        "aux": dict(zip(layout.aux, np.round(z, 4).tolist(), strict=True)),
    }


def _layouts(
    session: Session, operator_id: int, pairs: set[tuple[int, int]]
) -> dict[tuple[int, int], EstimateLayout]:
    """(engine id, design id) -> layout, for the given pairs. A layout comes from its design,
    so one distinct document per design is read and decoded once; a design whose engines
    carry different documents falls back to reading theirs one by one."""
    designs = {design_id for _engine_id, design_id in pairs}
    docs: dict[int, list[Any]] = defaultdict(list)
    for design_id, doc in session.connection().execute(
        select(FilterState.design_id, FilterState.layout)
        .where(FilterState.operator_id == operator_id, FilterState.design_id.in_(designs))
        .distinct()
    ).all():
        docs[design_id].append(doc)
    single = {
        design_id: EstimateLayout.from_dict(found[0])
        for design_id, found in docs.items()
        if len(found) == 1
    }
    out = {pair: single[pair[1]] for pair in pairs if pair[1] in single}
    mixed = designs - set(single)
    if mixed:
        for engine_id, design_id, doc in session.execute(
            select(FilterState.engine_id, FilterState.design_id, FilterState.layout).where(
                FilterState.operator_id == operator_id, FilterState.design_id.in_(mixed)
            )
        ).all():
            if (engine_id, design_id) in pairs:
                out[(engine_id, design_id)] = EstimateLayout.from_dict(doc)
    return out


@dataclass(frozen=True)
class Summary:
    """An engine's latest estimate as ``health_summary`` briefs it, kept as numbers (the dict
    is made for the engines a page shows): the worst health parameter's index, value and
    1-sigma and the thrust deficit rounded as shown, the health and auxiliary values rounded."""

    layout: EstimateLayout
    recorded_at: datetime
    seq: int
    worst: int | None
    worst_value: float | None
    worst_sigma: float | None
    thrust_deficit: float | None
    health: np.ndarray
    aux: np.ndarray
    thrust_sigma: float | None = None  # the thrust deficit's 1-sigma, as the engine page's
    # The health and its 1-sigma as estimated (before the calibration: what the rate of
    # change's sigma is taken from), so the latest estimate is decoded once.
    h_estimated: np.ndarray | None = None
    h_sigma_estimated: np.ndarray | None = None

    @property
    def worst_name(self) -> str | None:
        return None if self.worst is None else self.layout.health[self.worst]

    def as_dict(self) -> dict[str, Any]:
        return {
            "recorded_at": self.recorded_at,
            "seq": self.seq,
            "worst_health": self.worst_name,
            "worst_health_value": self.worst_value,
            "worst_health_sigma": self.worst_sigma,
            "thrust_deficit": self.thrust_deficit,
            "health": dict(zip(self.layout.health, _listed(self.health), strict=True)),
            "aux": dict(zip(self.layout.aux, self.aux.tolist(), strict=True)),
        }


def _summaries(
    rows: list[Any], layouts: dict[tuple[int, int], EstimateLayout],
    calibrations: dict[int, uncertainty.Calibration | None],
) -> list[tuple[Summary | None, bool]]:
    """Per chosen filter-state row (or None): the summary of its latest estimate (None without
    one; ``health_summary``'s numbers, on the level the engine page shows with the design's
    calibration ``calibrations[design_id]``) and whether it is on watch. The blobs of each
    design are decoded with one ``numpy.frombuffer`` and summarised with array operations."""
    out: list[tuple[Summary | None, bool]] = [(None, False)] * len(rows)
    by_layout: dict[tuple[int, int], tuple[EstimateLayout, int, list[int]]] = {}
    for i, row in enumerate(rows):
        if row is not None and row.packed is not None:
            layout = layouts[(row.engine_id, row.design_id)]
            key = (id(layout), row.design_id)
            by_layout.setdefault(key, (layout, row.design_id, []))[2].append(i)
    for layout, design_id, members in by_layout.values():
        values = layout.decode_blobs([rows[i].packed for i in members])
        s = layout.slices()
        h, h_sigma = shown_level(layout, calibrations.get(design_id), values[:, s["h"]],
                                 values[:, s["h_sigma"]])
        calib = calibrations.get(design_id)
        z = shown_aux(layout, calib, values[:, s["z"]], values[:, s["h"]])
        k = thrust_index(layout.aux)
        thrust_sigma = None
        if k is not None:
            z_sigma = values[:, s["z_sigma"]][:, k:k + 1]
            thrust_sigma = (z_sigma if calib is None else calib.aux_sigma(
                (layout.aux[k],), z_sigma, uncertainty.spread(values[:, s["h"]])))[:, 0].tolist()
        n_health = h.shape[1]
        abs_h = np.nan_to_num(np.abs(h))
        # The same tests as ``health_summary`` and the watch rule, row by row.
        watch = np.any((abs_h > WATCH_PERCENT) & (abs_h > WATCH_SIGMAS * np.nan_to_num(h_sigma)),
                       axis=1)
        worst = _worst(h) if n_health else None
        health_rounded, aux_rounded = np.round(h, 4), np.round(z, 4)
        if worst is not None:
            picked = np.arange(len(members))
            worst_values = h[picked, worst].tolist()
            worst_sigmas = h_sigma[picked, worst].tolist()
            worst_list = worst.tolist()
        thrust = None if k is None else (-z[:, k]).tolist()
        for r, i in enumerate(members):
            row = rows[i]
            found = worst is not None and worst_list[r] >= 0
            summary = Summary(
                layout, row.recorded_at, row.seq,
                worst_list[r] if found else None,
                round(worst_values[r], 4) if found else None,
                round(worst_sigmas[r], 4) if found else None,
                None if thrust is None else round(thrust[r], 4),
                health_rounded[r], aux_rounded[r],
                None if thrust_sigma is None else round(thrust_sigma[r], 4),
                values[r, s["h"]], values[r, s["h_sigma"]],
            )
            out[i] = (summary, bool(watch[r]))
    return out


def _limit_values(
    session: Session, operator_id: int, rows: list[Any],
    summaries: list[tuple[Summary | None, bool]], redlines: list[float],
    layouts: dict[tuple[int, int], EstimateLayout],
    calibrations: dict[int, uncertainty.Calibration | None],
) -> list[dict[str, LimitValue]]:
    """Per chosen filter-state row: the values its engine type's limits are checked against."""
    out: list[dict[str, LimitValue]] = [{} for _ in rows]
    builtin = set(session.connection().scalars(
        select(EstimatorDesign.id)
        .join(EngineModel, EngineModel.id == EstimatorDesign.engine_model_id)
        .where(EstimatorDesign.operator_id == operator_id, EngineModel.source == "builtin")
    ).all())
    egt_rows: list[int] = []  # row indices of built-in designs
    rates = _rates(rows, summaries, layouts, calibrations)
    for i, (row, (summary, _watch)) in enumerate(zip(rows, summaries, strict=True)):
        if row is None or summary is None:
            continue
        values = out[i]
        if summary.worst_value is not None:
            values["health_change"] = LimitValue(abs(summary.worst_value), summary.worst_name,
                                                 summary.worst_sigma)
        if summary.thrust_deficit is not None:
            values["thrust_deficit"] = LimitValue(summary.thrust_deficit,
                                                  sigma=summary.thrust_sigma)
        if i in rates:
            values["rate_of_change"] = rates[i]
        if row.design_id in builtin:
            egt_rows.append(i)
    if egt_rows:
        schedule = estimator.builtin_schedule_for_design(session, rows[egt_rows[0]].design_id)
        if schedule is not None:
            ref = performance.type_reference(schedule)
            for i, median in _egt_medians(session, operator_id, rows, egt_rows,
                                          schedule).items():
                margin = redlines[i] - reference_egt(median, ref.egt_reference_c,
                                                     ref.theta_reference)
                calib = calibrations.get(rows[i].design_id)
                out[i]["egt_margin"] = LimitValue(
                    float(margin), sigma=None if calib is None
                    else calib.delta_model_std(STATUS_EGT_MARGIN))
    return out


def _rates(
    rows: list[Any], summaries: list[tuple[Summary | None, bool]],
    layouts: dict[tuple[int, int], EstimateLayout],
    calibrations: dict[int, uncertainty.Calibration | None],
) -> dict[int, LimitValue]:
    """Row index -> its rate of change: the largest change of a health parameter since the
    estimate ``RATE_WINDOW`` records before the latest, per 100 records (for the rows with
    both); computed per layout on arrays."""
    by_layout: dict[tuple[int, int], tuple[EstimateLayout, int, list[int]]] = {}
    for i, (row, (summary, _watch)) in enumerate(zip(rows, summaries, strict=True)):
        if row is None or summary is None or row.old_packed is None:
            continue
        layout = layouts.get((row.engine_id, row.design_id))
        if layout is not None and layout.health:
            key = (id(layout), row.design_id)
            by_layout.setdefault(key, (layout, row.design_id, []))[2].append(i)
    out: dict[int, LimitValue] = {}
    per_100 = 100.0 / RATE_WINDOW
    for layout, design_id, members in by_layout.values():
        old = layout.decode_blobs([rows[i].old_packed for i in members])
        s = layout.slices()
        calib = calibrations.get(design_id)
        h_old, _ = shown_level(layout, calib, old[:, s["h"]], old[:, s["h_sigma"]])
        h_now = np.stack([summary.health for i in members
                          if (summary := summaries[i][0]) is not None])
        change = np.abs(h_now - h_old) * per_100
        worst = _worst(change)
        # The calibrated change's 1-sigma over the window (NaN: not known).
        sigma = np.full_like(change, np.nan)
        if calib is not None:
            now = [summary for i in members if (summary := summaries[i][0]) is not None]
            h_now_est = np.stack([np.asarray(n.h_estimated) for n in now])
            sigma_now = np.stack([np.asarray(n.h_sigma_estimated) for n in now])
            sigma = calib.on(layout.health).rate(h_now_est, old[:, s["h"]], sigma_now,
                                                 old[:, s["h_sigma"]])[1]
        for r, i in enumerate(members):
            k = int(worst[r])
            if k >= 0:
                known = bool(np.isfinite(sigma[r, k]))
                out[i] = LimitValue(float(change[r, k]), layout.health[k],
                                    float(sigma[r, k] * per_100) if known else None)
    return out


def _egt_medians(
    session: Session, operator_id: int, rows: list[Any], indices: list[int],
    schedule: EngineSchedule,
) -> dict[int, float]:
    """Row index -> median dEGT [K, corrected] of its engine's last ``EGT_WINDOW`` records: the
    window the pipeline keeps (``egt_windows``) when it was taken at the row's filter state and
    schedule, else read from the records (one query for all such engines)."""
    out: dict[int, float] = {}
    stale = []
    for i in indices:
        row = rows[i]
        if row.egt_current and row.egt_fingerprint == schedule.fingerprint:
            if row.egt_median is not None:
                out[i] = row.egt_median
        else:
            stale.append(i)
    if stale:
        states = (FilterState.operator_id == operator_id) & FilterState.engine_id.in_(
            sorted({rows[i].engine_id for i in stale}))
        found = egt.medians(egt.recent_records(session, states), schedule)
        for i in stale:
            median = found.get((rows[i].engine_id, rows[i].design_id))
            if median is not None:
                out[i] = median
    return out


def _active_events(
    session: Session, operator_id: int
) -> dict[int, list[tuple[int, str, str, str | None]]]:
    """engine id -> its events not closed: (id, kind, status, fault)."""
    out: dict[int, list[tuple[int, str, str, str | None]]] = defaultdict(list)
    for engine_id, event_id, kind, event_status, fault in session.connection().execute(
        select(Event.engine_id, Event.id, Event.kind, Event.status, Event.fault)
        .where(Event.operator_id == operator_id, Event.status != "closed")
        .order_by(Event.detected_at.desc(), Event.id.desc())
    ).all():
        out[engine_id].append((event_id, kind, event_status, fault))
    return out


def fleet_status(
    session: Session, operator_id: int, *, in_state: str | None = None,
    limit: int | None = None, offset: int = 0,
) -> dict[str, Any]:
    """The operator's engines ranked by severity with current tail/position, type, last data,
    latest health summary and open events (``app.schemas.estimates.FleetStatus``): those in
    ``in_state`` (all when None), ``limit`` of them from ``offset``, with the counts per state of
    the whole fleet. A few small objects per engine and no cycles: the garbage collector waits
    (its full collections cost a fleet of 2,900 engines a third of the read)."""
    with no_gc_pauses():
        return _fleet_status(session, operator_id, in_state, limit, offset)


def _fleet_status(
    session: Session, operator_id: int, in_state: str | None, limit: int | None, offset: int,
) -> dict[str, Any]:
    operator = session.get(Operator, operator_id)
    engines = [tuple(r) for r in session.connection().execute(
        select(Engine.id, Engine.esn, Engine.engine_type_id, EngineType.name)
        .join(EngineType, EngineType.id == Engine.engine_type_id)
        .where(Engine.operator_id == operator_id)
        .order_by(Engine.esn)
    ).all()]
    limits_of = {type_id: effective_limits(limits) for type_id, limits in session.connection()
                 .execute(select(EngineType.id, EngineType.limits)
                          .where(EngineType.id.in_({e[2] for e in engines}))).all()}
    installed = current_placements(session, operator_id)
    active: dict[int, int] = {
        type_id: design_id
        for type_id, design_id in session.connection().execute(
            select(EstimatorDesign.engine_type_id, EstimatorDesign.id).where(
                EstimatorDesign.operator_id == operator_id, EstimatorDesign.active.is_(True)
            )
        ).all()
    }
    # Per filter state, by key: the estimate it points at, the one RATE_WINDOW records before
    # it (the rate of change) and its EGT window (``egt_windows``).
    f, est, w = FilterState.__table__, Estimate.__table__, EgtWindow.__table__
    old = est.alias("old")
    latest = session.connection().execute(
        select(
            f.c.engine_id, f.c.design_id, f.c.n_records, f.c.last_recorded_at, est.c.recorded_at,
            est.c.seq, est.c.packed, old.c.packed.label("old_packed"),
            # The window's stamp is its filter state's (NULL without a window).
            and_(w.c.n_records == f.c.n_records,
                 w.c.last_recorded_at.is_not_distinct_from(f.c.last_recorded_at))
            .label("egt_current"),
            w.c.fingerprint.label("egt_fingerprint"), w.c.median.label("egt_median"),
        )
        .outerjoin(est, and_(est.c.engine_id == f.c.engine_id, est.c.design_id == f.c.design_id,
                             est.c.seq == f.c.n_records - 1))
        .outerjoin(old, and_(old.c.engine_id == f.c.engine_id, old.c.design_id == f.c.design_id,
                             old.c.seq == f.c.n_records - 1 - RATE_WINDOW))
        .outerjoin(w, and_(w.c.engine_id == f.c.engine_id, w.c.design_id == f.c.design_id))
        .where(f.c.operator_id == operator_id)
    ).all()
    by_engine: dict[int, dict[int, Any]] = defaultdict(dict)
    for state_row in latest:
        by_engine[state_row.engine_id][state_row.design_id] = state_row
    counts = open_event_counts(session, operator_id)
    newest_events = latest_open_events(session, operator_id)

    # The row each engine shows: its type's active design, else its latest filter state.
    chosen: list[Any] = []
    for engine_id, _esn, type_id, _type_name in engines:
        states = by_engine.get(engine_id, {})
        design_id = active.get(type_id)
        row: Any = states.get(design_id) if design_id is not None else None
        if row is None and states:
            row = max(states.values(), key=lambda r: (r.last_recorded_at is not None,
                                                      r.last_recorded_at, r.design_id))
        chosen.append(row)
    pairs = {(r.engine_id, r.design_id) for r in chosen if r is not None}
    layouts = _layouts(session, operator_id, pairs) if pairs else {}
    calibrations = {design_id: design_calibration(session, design_id)
                    for design_id in {design_id for _engine_id, design_id in pairs}}
    summaries = _summaries(chosen, layouts, calibrations)
    limit_values = _limit_values(
        session, operator_id, chosen, summaries,
        [limits_of[type_id]["egt_redline_c"] for _e, _s, type_id, _n in engines], layouts,
        calibrations,
    )
    active_events = _active_events(session, operator_id)

    # Every engine's state and rank; the page's engines in full after.
    ranked = []
    for k, ((engine_id, esn, type_id, _type_name), (summary, _watch), values) in enumerate(
        zip(engines, summaries, limit_values, strict=True)
    ):
        level, score = rank(limits_of[type_id], values, active_events.get(engine_id, []))
        state = ("no_data" if summary is None and not counts.get(engine_id, 0)
                 else STATE_OF_LEVEL[level])
        shown = None if score == float("-inf") else round(score, 3)
        # Red, amber, normal, no data; within a level the furthest past its limits first.
        key = (-(LEVELS.index(level) if state != "no_data" else -1),
               -(shown if shown is not None else float("-inf")), esn)
        ranked.append((key, state, k))
    ranked.sort()
    per_state = {name: 0 for name in (*STATE_OF_LEVEL.values(), "no_data")}
    for _key, state, _k in ranked:
        per_state[state] += 1
    matching = [(rank_of, state, k) for rank_of, (_key, state, k) in enumerate(ranked, start=1)
                if in_state is None or state == in_state]
    end = None if limit is None else offset + limit
    page = []
    for rank_of, state, k in matching[offset:end]:
        engine_id, esn, type_id, type_name = engines[k]
        row, (summary, _watch), values = chosen[k], summaries[k], limit_values[k]
        n_open = counts.get(engine_id, 0)
        event = newest_events.get(engine_id)
        where = installed.get(engine_id)
        judged = severity(limits_of[type_id], values, active_events.get(engine_id, []))
        page.append(
            {
                "engine_id": engine_id,
                "esn": esn,
                "engine_type": type_name,
                "aircraft_id": None if where is None else where.aircraft_id,
                "tail": None if where is None else where.tail,
                "position": None if where is None else where.position,
                "design_id": None if row is None else row.design_id,
                "last_data": None if row is None else row.last_recorded_at,
                "n_records": 0 if row is None else row.n_records,
                "state": state,
                "severity": None if state == "no_data" else judged.level,
                "severity_score": None if judged.score == float("-inf")
                else round(judged.score, 3),
                "reason": judged.reason,
                "checks": [c.as_dict() for c in judged.checks],
                "health": None if summary is None else summary.as_dict(),
                "open_events": n_open,
                "latest_event": None
                if event is None
                else {
                    "id": event.id,
                    "detected_at": event.detected_at,
                    "kind": event.kind,
                    "fault": event.fault,
                    "magnitude": event.magnitude,
                    "status": event.status,
                },
                "rank": rank_of,
            }
        )
    return {
        "operator": "" if operator is None else operator.name,
        "n_engines": len(ranked),
        "n_open_events": sum(counts.values()),
        "states": per_state,
        "total": len(matching),
        "limit": len(ranked) if limit is None else limit,
        "offset": offset,
        "engines": page,
    }


def _series(
    names: tuple[str, ...], units: list[str] | None, mean: np.ndarray, spread: np.ndarray,
    offset: int,
) -> list[dict[str, Any]]:
    unit_list = units or ["%"] * len(names)
    return [
        {
            "name": name,
            "unit": unit_list[j],
            "mean": json_numbers_or_null(mean[:, offset + j]),
            "sigma": json_numbers_or_null(spread[:, offset + j]),
        }
        for j, name in enumerate(names)
    ]


def _active_layouts(
    session: Session, operator_id: int
) -> list[tuple[int, str, EstimateLayout]]:
    """(design id, engine type name, estimate layout) of each active design with estimates,
    by engine type name."""
    designs = session.execute(
        select(EstimatorDesign.id, EngineType.name)
        .join(EngineType, EngineType.id == EstimatorDesign.engine_type_id)
        .where(EstimatorDesign.operator_id == operator_id, EstimatorDesign.active.is_(True))
        .order_by(EngineType.name)
    ).all()
    out = []
    for design_id, type_name in designs:
        layout_doc = session.scalar(
            select(FilterState.layout).where(FilterState.design_id == design_id).limit(1)
        )
        if layout_doc is not None:
            out.append((design_id, type_name, EstimateLayout.from_dict(layout_doc)))
    return out


def fleet_deterioration_slopes(session: Session, operator_id: int) -> dict[str, Any]:
    """The fleet-average deterioration slope of each health parameter per active design, with
    its 1-sigma; null where unobservable (``app.services.fleet.slopes``)."""
    return {"groups": [
        {"engine_type": type_name, "design_id": design_id,
         **slopes.fleet_slopes(session, operator_id, design_id, layout).to_dict()}
        for design_id, type_name, layout in _active_layouts(session, operator_id)
    ]}


def fleet_deterioration(
    session: Session, operator_id: int, bucket: str = "month"
) -> dict[str, Any]:
    """Fleet-average health and auxiliary estimates per week or month, per active design.

    Each engine first counts once per bucket (the mean of its estimates there), then the
    fleet mean and spread are taken over engines, so a busy engine does not dominate. Read
    from the sums the pipeline keeps (``fleet_periods``): one row per period, whatever the
    number of engines and estimates. The health values are the level the engine pages show:
    with the design's calibration, its correction applied to each engine's period mean (the
    fleet periods keep the second moments that the curved correction and the spread need:
    ``uncertainty.fleet_level``), a parameter it cannot observe null. The slopes are
    ``fleet_deterioration_slopes``.
    """
    if bucket not in ("week", "month"):
        raise InvalidInput(
            "bucket must be week or month",
            details=[{"row": None, "column": "bucket", "reason": f"unknown bucket {bucket!r}"}],
        )
    groups = []
    for design_id, type_name, layout in _active_layouts(session, operator_id):
        rows = session.execute(
            select(FleetPeriod.start, FleetPeriod.n_engines, FleetPeriod.sums,
                   FleetPeriod.squares)
            .where(FleetPeriod.design_id == design_id, FleetPeriod.period == bucket,
                   FleetPeriod.operator_id == operator_id)
            .order_by(FleetPeriod.start)
        ).all()
        if not rows:
            continue
        p = len(layout.health)
        width = p + len(layout.aux)
        buckets = np.fromiter((r[0].timestamp() for r in rows), float, len(rows))
        n_engines = np.fromiter((r[1] for r in rows), np.int64, len(rows))
        sums = np.frombuffer(b"".join(r[2] for r in rows), "<f8").reshape(len(rows), width)
        squares = np.frombuffer(b"".join(r[3] for r in rows), "<f8").reshape(len(rows), -1)
        # Each engine counts once per period (the mean of its estimates there); the fleet's
        # mean and spread are over engines. The health values: the level the engine pages
        # show (the design's calibration on the engines' means; as estimated without one).
        mean = sums / n_engines[:, None]
        moments = squares / n_engines[:, None]
        pairs = p * (p + 1) // 2
        calib = design_calibration(session, design_id)
        on = None if calib is None else calib.on(layout.health)
        correction = np.zeros((p, 1 + p)) if on is None else np.asarray(on.level_correction)
        health, health_spread = uncertainty.fleet_level(mean[:, :p], moments[:, :pairs],
                                                        correction)
        # The aux outputs: calibrated as the engine pages show them, their spread over
        # engines through the engines' aux-by-health moments.
        n_aux = len(layout.aux)
        cross = (moments[:, pairs + n_aux:].reshape(len(rows), n_aux, p)
                 if moments.shape[1] == pairs + n_aux + n_aux * p else None)
        aux, aux_spread = uncertainty.fleet_outputs(
            mean[:, p:], moments[:, pairs:pairs + n_aux], cross, mean[:, :p],
            moments[:, :pairs], None if on is None else on.aux_rows(layout.aux))
        # A parameter the design's calibration finds unobservable: nulls, named (as the
        # engine trend's health group has it), not a fleet average of what it cannot see.
        hidden = np.zeros(p, bool) if on is None else ~np.asarray(on.observable, bool)
        health[:, hidden] = np.nan
        health_spread[:, hidden] = np.nan
        mean = np.concatenate([health, aux], axis=1)
        spread = np.concatenate([health_spread, aux_spread], axis=1)
        units = layout.units
        groups.append(
            {
                "engine_type": type_name,
                "design_id": design_id,
                "time": [
                    datetime.fromtimestamp(t, UTC).isoformat().replace("+00:00", "Z")
                    for t in buckets
                ],
                "n_engines": n_engines.tolist(),
                "health": _series(layout.health, units.get("health"), mean, spread, 0),
                "aux": _series(layout.aux, units.get("aux"), mean, spread, p),
                "unobservable": [n for n, off in zip(layout.health, hidden, strict=True) if off],
                "level": "estimated" if on is None else "calibrated",
            }
        )
    return {"bucket": bucket, "groups": groups}
