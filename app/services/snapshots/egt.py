"""Each engine's EGT window: the median dEGT of its last ``EGT_WINDOW`` records, kept as the
estimates are stored, so that the fleet status reads one row per engine (``egt_windows``)
instead of every engine's last records with their snapshots.

dEGT is a record's measured T48 against the nominal built-in engine's at the record's
condition (``estimator.baseline_trims``), corrected to standard day (theta) and in kelvin; one
record's scatter is ~6 K, hence the median over the window. Only designs of the built-in
engine have it.

An estimation run writes a batch of engines' estimates and filter states, then ``refresh``
takes each of those engines' window again from the stored rows (an index range of at most
``EGT_WINDOW`` estimates per engine, each snapshot by its key): a re-run that rewrote the
window and a run that added one record come out alike. A window keeps the stamp of the filter
state it was taken at (``n_records``, ``last_recorded_at``) and the schedule's fingerprint;
the status uses only windows whose stamp is its filter state's, and reads the others' records
(``recent_records``).
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
from sqlalchemy import ColumnElement, and_, delete, insert, select, true
from sqlalchemy.orm import Session

from app.models import EngineModel, EstimatorDesign, Snapshot
from app.models.estimates import EgtWindow, Estimate, FilterState
from app.services.snapshots.estimator import baseline_trims, builtin_schedule_for_design
from estimation.engine.atmosphere import flight_condition
from estimation.engine.deltas import EGT_WINDOW, egt_delta
from estimation.engine.schedule import EngineSchedule

BATCH = 256  # engines whose windows are taken together by ``rebuild``


def d_egt(conditions: np.ndarray, t48: np.ndarray, schedule: EngineSchedule) -> np.ndarray:
    """dEGT of records at ``conditions`` [n, 4] (alt, mach, dtamb, power) with ``t48`` [n]."""
    cond = np.asarray(conditions, float).reshape(-1, 4)
    base = baseline_trims(cond, schedule)["T48"]
    theta = flight_condition(cond[:, 0], cond[:, 1], cond[:, 2]).theta
    return egt_delta(t48, base, theta)


def recent_records(session: Session, states: ColumnElement[bool]) -> list[Any]:
    """(engine_id, design_id, alt_ft, mach, dtamb_k, power_pct, t48) of the records with a T48
    among the last ``EGT_WINDOW`` estimates of each filter state matching ``states`` (a
    condition on ``filter_states``).

    On PostgreSQL one LATERAL query per filter state reads them as an index range of
    (engine_id, design_id, seq) and looks each snapshot up by its key: a join over whole tables
    made the planner hash-join every estimate and snapshot (4.4-4.9 s at 4.8M estimates,
    1,400 engines, against 0.5-0.6 s)."""
    f, est, snap = FilterState.__table__, Estimate.__table__, Snapshot.__table__
    columns = (est.c.engine_id, est.c.design_id, snap.c.alt_ft, snap.c.mach, snap.c.dtamb_k,
               snap.c.power_pct, snap.c.t48)
    in_window = and_(est.c.engine_id == f.c.engine_id, est.c.design_id == f.c.design_id,
                     est.c.seq >= f.c.n_records - EGT_WINDOW)
    with_snapshot = and_(snap.c.engine_id == est.c.engine_id,
                         snap.c.recorded_at == est.c.recorded_at)
    if session.get_bind().dialect.name == "postgresql":
        # ORDER BY ... LIMIT keeps the planner from flattening the LATERAL into one hash join
        # over whole tables.
        recent = (select(est.c.engine_id, est.c.design_id, est.c.recorded_at)
                  .where(in_window).order_by(est.c.seq.desc()).limit(EGT_WINDOW)
                  .lateral("recent"))
        query = (select(recent.c.engine_id, recent.c.design_id, *columns[2:])
                 .select_from(f.join(recent, true()))
                 .join(snap, and_(snap.c.engine_id == recent.c.engine_id,
                                  snap.c.recorded_at == recent.c.recorded_at))
                 .where(states, snap.c.t48.is_not(None)))
    else:
        query = (select(*columns).select_from(f.join(est, in_window).join(snap, with_snapshot))
                 .where(states, snap.c.t48.is_not(None)))
    return list(session.connection().execute(query).all())


def medians(records: Sequence[Any], schedule: EngineSchedule) -> dict[tuple[int, int], float]:
    """(engine id, design id) -> median dEGT over its ``recent_records``."""
    if not records:
        return {}
    cond = np.array([[r.alt_ft, r.mach, r.dtamb_k, r.power_pct] for r in records], float)
    values = d_egt(cond, np.array([r.t48 for r in records], float), schedule)
    by_pair: dict[tuple[int, int], list[int]] = defaultdict(list)
    for k, r in enumerate(records):
        by_pair[(r.engine_id, r.design_id)].append(k)
    return {pair: float(np.median(values[rows])) for pair, rows in by_pair.items()}


def refresh(session: Session, design_id: int, engine_ids: Iterable[int]) -> None:
    """Take the EGT windows of these engines under ``design_id`` from their stored estimates
    and snapshots (after their estimates and filter states are written). Nothing for a design
    of another engine than the built-in one."""
    ids = sorted(set(engine_ids))
    schedule = builtin_schedule_for_design(session, design_id)
    if schedule is None or not ids:
        return
    states = (FilterState.design_id == design_id) & FilterState.engine_id.in_(ids)
    stamps = session.execute(
        select(FilterState.engine_id, FilterState.n_records, FilterState.last_recorded_at)
        .where(states)
    ).all()
    found = medians(recent_records(session, states), schedule)
    session.execute(delete(EgtWindow).where(EgtWindow.design_id == design_id,
                                            EgtWindow.engine_id.in_(ids)))
    if stamps:
        session.execute(insert(EgtWindow), [
            {"engine_id": engine_id, "design_id": design_id, "n_records": n_records,
             "last_recorded_at": last, "fingerprint": schedule.fingerprint,
             "median": found.get((engine_id, design_id))}
            for engine_id, n_records, last in stamps
        ])


def rebuild(session: Session) -> None:
    """Every built-in design's windows from the stored rows (migration 0021)."""
    designs = session.scalars(
        select(EstimatorDesign.id)
        .join(EngineModel, EngineModel.id == EstimatorDesign.engine_model_id)
        .where(EngineModel.source == "builtin").order_by(EstimatorDesign.id)
    ).all()
    for design_id in designs:
        engines = session.scalars(
            select(FilterState.engine_id).where(FilterState.design_id == design_id)
            .order_by(FilterState.engine_id)
        ).all()
        for start in range(0, len(engines), BATCH):
            refresh(session, design_id, engines[start:start + BATCH])
