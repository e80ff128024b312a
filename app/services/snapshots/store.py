"""Estimation runs against the database: the engines with records to estimate, where each
run restarts, their records in, and their estimates, events, checkpoints and filter states
out.

After an upload commits, each affected engine's snapshot filter (``estimation.snapshot``,
docs/math.md section 8) continues from its stored state under the engine type's active design. A
record older than the last processed one re-runs the engine from the newest checkpoint before
it: estimates and checkpoints from there on are deleted and recomputed, so a re-run writes the
same rows as an uninterrupted run (the arithmetic per record does not depend on how records are
grouped into runs, and a state restored from JSON is bit-exact). Events detected again are
updated in place (an acknowledgement and comments survive); events not detected again go.
Checkpoints every ``pipeline.CHECKPOINT_EVERY`` records bound a re-run to that many records
before the late one.

The work comes from the estimation backlog (``backlog``): whatever stores snapshots, or changes
what estimates depend on (a maintenance action, a design activation, an engine's type), marks
the engine in its own transaction, and a batch deletes the marks it did with its estimates.

Engines go in batches of up to ``BATCH`` (``estimate_engines``): a batch's records are read at
once (from memory when the upload that stored them committed in this process, else one query;
``estimate_rows``), filtered and derived for all engines per chunk of records, and their
estimate rows streamed into one binary COPY while the filter computes: 0.85-1.1 s for 100,000
records of 100 engines in a job of ``fleethealth serve`` on a two-core machine
(bench/bench_ingest.py). On PostgreSQL a job spreads a pass over engine groups estimated in
parallel by other processes (``catch_up``, ``groups``; docs/jobs.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from datetime import UTC, datetime
from typing import Any

import numpy as np
import pyarrow as pa
from sqlalchemy import Engine as SqlEngine
from sqlalchemy import and_, delete, func, insert, or_, select
from sqlalchemy.orm import Session, defer

from app.db import read_phase
from app.models import Engine, EstimatorDesign, MaintenanceAction, Snapshot
from app.models.base import utcnow
from app.models.estimates import Estimate, Event, FilterCheckpoint, FilterState
from app.models.fleet import BASELINE_RESET_KINDS
from app.services import fresh_records
from app.services.common import no_gc_pauses
from app.services.notifications import outbox
from app.services.snapshots import backlog, buckets, detector, egt, groups, rows
from app.services.snapshots.drifts import FleetDrifts
from app.services.snapshots.estimator import RESET_STD, SnapshotEstimator, estimator_for_design
from app.services.snapshots.run import EngineOutput, EngineRun, PipelineState, run_filters
from estimation.snapshot import SnapshotState


def state_document(state: PipelineState) -> dict[str, Any]:
    """An engine's pipeline state as stored (``FilterState.state``, ``FilterCheckpoint.state``):
    the filter, the shift detector (``detector.document``), the last record's time and the
    wear detector (``detector.wear_document``)."""
    return {"filter": state.filter.to_dict(), "detector": detector.document(state.detector),
            "last_epoch": state.last_epoch, "wear": detector.wear_document(state.wear)}


def state_from_document(d: Mapping[str, Any]) -> PipelineState:
    """A stored pipeline state (``state_document``)."""
    last = d.get("last_epoch")
    return PipelineState(SnapshotState.from_dict(d["filter"]),
                         detector.from_document(d["detector"]),
                         None if last is None else float(last),
                         detector.wear_from_document(d.get("wear")))


def _restart_point(
    session: Session, est: SnapshotEstimator, fs: FilterState | None, earliest: datetime | None
) -> tuple[int, PipelineState, datetime | None]:
    """(seq0, state, after): where the engine's run starts. A run that starts before the
    filter state's end redoes what was stored from ``seq0`` on (``_delete_from``)."""
    if fs is None:
        return 0, PipelineState.initial(est), None
    if earliest is None or fs.last_recorded_at is None or earliest > fs.last_recorded_at:
        return fs.n_records, state_from_document(fs.state), fs.last_recorded_at
    checkpoint = session.scalar(
        select(FilterCheckpoint)
        .where(
            FilterCheckpoint.engine_id == fs.engine_id,
            FilterCheckpoint.design_id == fs.design_id,
            FilterCheckpoint.last_recorded_at < earliest,
        )
        .order_by(FilterCheckpoint.seq.desc())
        .limit(1)
    )
    if checkpoint is None:
        seq0, state, after = 0, PipelineState.initial(est), None
    else:
        seq0, after = checkpoint.seq, checkpoint.last_recorded_at
        state = state_from_document(checkpoint.state)
    return seq0, state, after


def _delete_from(session: Session, engine_id: int, design_id: int, seq0: int) -> None:
    """Remove what a re-run from ``seq0`` recomputes. Events are not deleted here: the re-run
    updates those it detects again (keeping their status and comments) and deletes the rest
    (``_store``). An alarm pending at the restart point is isolated again by the re-run, so its
    event is redone too."""
    session.execute(
        delete(Estimate).where(
            Estimate.engine_id == engine_id, Estimate.design_id == design_id, Estimate.seq >= seq0
        )
    )
    session.execute(
        delete(FilterCheckpoint).where(
            FilterCheckpoint.engine_id == engine_id,
            FilterCheckpoint.design_id == design_id,
            FilterCheckpoint.seq > seq0,
        )
    )


def _family(kind: str) -> str:
    """The detector an event kind comes from: ``wear`` or the shift detector's."""
    return "wear" if kind == "wear" else "shift"


def _events_to_redo(
    events: Sequence[Event], seq0: int, state: PipelineState
) -> dict[tuple[float, str], Event]:
    """Of one engine's ``events``, those a run from ``seq0`` (state ``state``) recomputes, by
    detection time and detector (an alarm's record keeps its time when a late record shifts
    the sequence numbers; a wear alert and a shift may fall on one record)."""
    pending = state.detector.pending
    pending_seq = None if pending is None else pending.seq
    return {(e.detected_at.timestamp(), _family(e.kind)): e for e in events
            if e.seq >= seq0 or (e.seq == pending_seq and _family(e.kind) == "shift")}


def _by_engine(session: Session, query: Any) -> dict[int, list[Any]]:
    """Rows of ``query`` (its first column an engine id) grouped by that id."""
    out: dict[int, list[Any]] = {}
    for row in session.execute(query).all():
        out.setdefault(int(row[0]), []).append(row)
    return out


def _active_designs(
    session: Session, operator_id: int, engines: Sequence[Engine], design_id: int | None
) -> tuple[dict[int, EstimatorDesign], dict[int, list[Engine]], list[str]]:
    """Designs by id, the engines each one runs (the engine type's active design, or
    ``design_id``), and the ESNs of engines with none."""
    if design_id is not None:
        forced = session.get(EstimatorDesign, design_id)
        by_type = {e.engine_type_id: forced for e in engines}
    else:
        by_type = {
            d.engine_type_id: d
            for d in session.scalars(
                select(EstimatorDesign).where(
                    EstimatorDesign.operator_id == operator_id,
                    EstimatorDesign.active.is_(True),
                )
            )
        }
    designs: dict[int, EstimatorDesign] = {}
    groups: dict[int, list[Engine]] = {}
    skipped = []
    for engine in engines:
        design = by_type.get(engine.engine_type_id)
        if design is None or design.operator_id != operator_id:
            skipped.append(engine.esn)
            continue
        designs[design.id] = design
        groups.setdefault(design.id, []).append(engine)
    return designs, groups, skipped


BATCH = 256  # engines filtered together (and committed together by a job)
# ... and about this many new records at most: a batch's records are in memory at once, and
# the filter's steps over many engines' long backlogs run slower in arrays that big (one batch
# of 2,000,000 records took 12 % more CPU than four of 500,000).
BATCH_RECORDS = 500_000


def batches(
    engines: Sequence[Engine], new_records: Mapping[int, int | None]
) -> list[list[Engine]]:
    """``engines`` in order, cut into batches of at most ``BATCH`` engines and of about equal
    new records, as few as keep each at about ``BATCH_RECORDS`` or less (no small batch left
    at the end). ``new_records``: an engine's count; unknown when absent or None, and then
    counted as none. An engine goes into the current batch unless its middle record would
    pass the batch's share."""
    counts = [new_records.get(e.id) or 0 for e in engines]
    share = sum(counts) / max(1, math.ceil(sum(counts) / BATCH_RECORDS))
    out: list[list[Engine]] = []
    records = 0
    for engine, n in zip(engines, counts, strict=True):
        if not out or len(out[-1]) >= BATCH or (records and records + n / 2 > share):
            out.append([])
            records = 0
        out[-1].append(engine)
        records += n
    return out


COUNTS = ("engines", "records", "events", "reruns")


def empty_summary() -> dict[str, Any]:
    """The counts of an estimation that estimated nothing (``estimate_engines``')."""
    return {"engines": 0, "records": 0, "events": 0, "reruns": 0, "skipped_no_design": 0}


def estimate_engines(
    session: Session,
    operator_id: int,
    affected: Mapping[int, datetime | None],
    progress: Callable[[float, str], None] | None = None,
    design_id: int | None = None,
    commit: Callable[[], None] | None = None,
    from_backlog: bool = False,
    new_records: Mapping[int, int | None] | None = None,
    drifts: FleetDrifts | None = None,
) -> dict[str, Any]:
    """Bring every affected engine's estimates up to date.

    affected: engine id -> earliest recorded_at of its new records (None: just continue);
    new_records: engine id -> its number of new records, where known (the backlog marks').
    Engines of one design run batched (``batches``): their records are read in one go
    and their estimates written in one go (``estimate_rows``); ``commit`` (a job's) is called
    after each batch so finished engines survive a restart, else all stays in the caller's
    transaction. ``from_backlog``: each batch's restart points come from the engines' backlog
    marks (read once the batch's rows kept in memory are taken, so no kept row is newer than
    the marks), and those marks go with the batch. ``drifts``: the fleet's wear drifts as the
    pass found them (``drifts.FleetDrifts``; None: as stored now), which each batch learns from
    together with the drifts of this call's earlier batches. Returns counts per outcome.
    """
    phases = commit is not None  # a job's reads and computation hold no SQLite write lock
    with read_phase(session, phases):
        engines = session.scalars(
            select(Engine)
            .where(Engine.operator_id == operator_id, Engine.id.in_(list(affected)))
            .order_by(Engine.id)
        ).all()
        designs, by_design, skipped = _active_designs(session, operator_id, engines, design_id)
        if drifts is None:
            drifts = FleetDrifts.read(session, operator_id)
    summary = empty_summary()
    summary["skipped_no_design"] = skipped
    total = sum(len(v) for v in by_design.values()) or 1
    done = 0
    for d_id, group in by_design.items():
        with read_phase(session, phases):
            est = estimator_for_design(session, designs[d_id])
        for batch in batches(group, new_records or {}):
            with no_gc_pauses():
                periods = buckets.BucketCollector(est.layout)
                computed: list[rows.Block] | None = None
                with read_phase(session, phases) as apart:
                    ids = [e.id for e in batch]
                    kept = fresh_records.take(session, ids)
                    marks = backlog.pending(session, operator_id, ids) if from_backlog else None
                    runs, states, redone = _prepare_runs(
                        session, est, operator_id, batch, summary, kept,
                        affected if marks is None else {e: m.earliest for e, m in marks.items()},
                        marks or {},
                    )
                    fleet = drifts.others(est.design_id, ids)
                    if apart:  # computed now, written once the lock is taken
                        computed = []
                        outputs = run_filters(est, runs, sink=computed.append, fleet=fleet)
                for engine_id, seq0 in redone:
                    _delete_from(session, engine_id, est.design_id, seq0)
                with rows.EstimateWriter(
                    session, operator_id=operator_id, design_id=est.design_id,
                    layout=est.layout, stored=periods.stored,
                ) as writer:
                    if computed is None:  # computed while the writer sends (PostgreSQL's COPY)
                        outputs = run_filters(est, runs, sink=writer.add, fleet=fleet)
                    for block in computed or ():
                        writer.add(block)
                _store_batch(session, est, runs, states, outputs)
                drifts = drifts.updated(est.design_id, {
                    run.engine_id: out.state.wear.drift
                    for run, out in zip(runs, outputs, strict=True)})
                egt.refresh(session, est.design_id, [run.engine_id for run in runs])
                if marks is not None:
                    backlog.settle(session, marks.values())
                # Last: the fleet's periods are shared with the engine groups estimated in
                # parallel, and held from here to the commit (``buckets.FleetChange.apply``).
                buckets.refresh(session, operator_id=operator_id, design_id=est.design_id,
                                layout=est.layout, collected=periods)
            for out in outputs:
                summary["records"] += out.n_records
                summary["events"] += len(out.events)
            summary["engines"] += len(runs)
            done += len(batch)
            if commit is not None:
                commit()
            if progress is not None:
                progress(done / total, f"estimated {done} of {total} engines")
    return summary


def _prepare_runs(
    session: Session, est: SnapshotEstimator, operator_id: int, batch: Sequence[Engine],
    summary: dict[str, Any], kept: pa.Table | None, affected: Mapping[int, datetime | None],
    marks: Mapping[int, backlog.Mark],
) -> tuple[list[EngineRun], list[FilterState | None], list[tuple[int, int]]]:
    """The runs of a batch of engines under one design: restart points, records, maintenance
    actions and the events a run redoes, each read once for the batch; and (engine id, seq0)
    of the re-runs, whose stored estimates from seq0 on the caller deletes (``_delete_from``)
    before it writes theirs. Reads only.

    ``kept``: the batch's rows uploads kept in memory. An engine that continues from its
    filter state has exactly as many new records as its backlog marks count, when they were
    read after the rows were taken: every record stored since the state was written came
    with a mark not yet settled, and a kept row's mark was committed with it. Equal counts
    then mean the kept rows are all of them."""
    ids = [e.id for e in batch]
    states = {
        fs.engine_id: fs
        for fs in session.scalars(
            select(FilterState)
            .options(defer(FilterState.layout))  # the trends' to read, not the filter's
            .where(FilterState.design_id == est.design_id, FilterState.engine_id.in_(ids))
        )
    }
    starts = {}
    redone: list[tuple[int, int]] = []
    for engine_id in ids:
        fs = states.get(engine_id)
        starts[engine_id] = _restart_point(session, est, fs, affected.get(engine_id))
        if fs is not None and starts[engine_id][0] < fs.n_records:
            summary["reruns"] += 1
            redone.append((engine_id, starts[engine_id][0]))
    expected = {}
    for engine_id in ids:
        fs, mark = states.get(engine_id), marks.get(engine_id)
        if (fs is not None and mark is not None and mark.rows is not None
                and starts[engine_id][0] == fs.n_records):
            expected[engine_id] = mark.rows
    records = rows.load_records(
        session, [(engine_id, starts[engine_id][2]) for engine_id in ids],
        est.sensor_columns, est.input_columns, kept=kept, expected=expected,
    )
    maintenance = _by_engine(
        session,
        select(MaintenanceAction.engine_id, MaintenanceAction.performed_at,
               MaintenanceAction.kind).where(
            MaintenanceAction.engine_id.in_(ids),
            MaintenanceAction.kind.in_(BASELINE_RESET_KINDS),
        ),
    )
    events = _by_engine(
        session,
        select(Event.engine_id, Event).where(
            Event.engine_id.in_(ids), Event.design_id == est.design_id
        ),
    )
    runs, kept = [], []
    for engine_id in ids:
        fs = states.get(engine_id)
        seq0, state, _after = starts[engine_id]
        rec = records[engine_id]
        if len(rec.epoch) == 0 and fs is not None and seq0 == fs.n_records:
            continue
        actions = sorted((row[1].timestamp(), RESET_STD[row[2]])
                         for row in maintenance.get(engine_id, []))
        redo = _events_to_redo([row[1] for row in events.get(engine_id, [])], seq0, state)
        runs.append(EngineRun(engine_id, operator_id, seq0, state, rec.epoch,
                              rec.phase, rec.conditions, rec.y, rec.u,
                              np.array([a[0] for a in actions], dtype=float), redo,
                              np.array([a[1] for a in actions], dtype=float)))
        kept.append(fs)
    return runs, kept, redone


def _store_batch(
    session: Session, est: SnapshotEstimator, runs: Sequence[EngineRun],
    states: Sequence[FilterState | None], outputs: Sequence[EngineOutput],
) -> None:
    """A batch's checkpoints (one INSERT), then each engine's events and filter state (its
    estimates went in while they were computed)."""
    checkpoints = [
        {"engine_id": run.engine_id, "design_id": est.design_id, "seq": seq,
         "last_recorded_at": datetime.fromtimestamp(epoch, UTC),
         "state": state_document(state)}
        for run, out in zip(runs, outputs, strict=True)
        for seq, epoch, state in out.checkpoints
    ]
    if checkpoints:
        session.execute(insert(FilterCheckpoint), checkpoints)
    raised: list[Event] = []
    for run, fs, out in zip(runs, states, outputs, strict=True):
        raised += _store(session, est, run, fs, out)
    session.flush()
    if raised:
        # Their notifications go in this same transaction; a job sends them after it commits.
        outbox.queue_events(session, raised[0].operator_id, raised)


def _store(
    session: Session, est: SnapshotEstimator, run: EngineRun, fs: FilterState | None,
    out: EngineOutput,
) -> list[Event]:
    """One engine's events (redone ones updated in place) and filter state; the events new
    to it."""
    redo = dict(run.redo)
    fresh = []
    for draft in out.events:
        detection = {
            "detected_at": datetime.fromtimestamp(draft.epoch, UTC), "kind": draft.kind,
            "fault": draft.fault, "magnitude": draft.magnitude, "statistic": draft.statistic,
            "wssr": draft.wssr, "shift": draft.shift,
        }
        existing = redo.pop((draft.epoch, _family(draft.kind)), None)
        if existing is not None:
            # Detected again: keep what people did with it (status, comments).
            for key, value in detection.items():
                setattr(existing, key, value)
            existing.seq = draft.seq
        else:
            fresh.append((draft.seq, detection))
    pending = out.state.detector.pending
    for (epoch, family), stale in redo.items():
        if pending is not None and pending.epoch == epoch and family == "shift":
            continue  # still awaiting its isolation: the next run redoes it
        session.delete(stale)
    if run.redo:
        session.flush()  # stale events go before new ones may take their sequence numbers
    raised = [
        Event(operator_id=run.operator_id, engine_id=run.engine_id, design_id=est.design_id,
              seq=seq, status="open", **detection)
        for seq, detection in fresh
    ]
    session.add_all(raised)
    n_records = run.seq0 + len(run.epoch)
    last_time = (
        datetime.fromtimestamp(float(run.epoch[-1]), UTC) if len(run.epoch)
        else (fs.last_recorded_at if fs is not None and run.seq0 == fs.n_records else None)
    )
    if fs is None:
        # The layout follows from the design, which never changes once used: written once.
        fs = FilterState(operator_id=run.operator_id, engine_id=run.engine_id,
                         design_id=est.design_id, layout=est.layout.to_dict())
        session.add(fs)
    fs.state = state_document(out.state)
    fs.n_records = n_records
    if len(run.epoch) or run.seq0 == 0:
        fs.last_recorded_at = last_time
    fs.updated_at = utcnow()
    return raised


def pending_work(
    session: Session, operator_id: int, engine_ids: Sequence[int] | None = None
) -> dict[int, datetime]:
    """Engines with snapshots that have no estimate under their type's active design, and the
    earliest such snapshot of each: what the pipeline has still to do (or redo), found from
    the stored rows themselves (``audit`` checks the backlog with it).

    Per engine, from its filter state: the first record after the last processed one (an
    index lookup), and the count of records up to it against the records processed; only
    an engine with a late record (more records than processed up to the last one) is searched
    for its earliest unestimated record.
    """
    active = (
        select(EstimatorDesign.id, EstimatorDesign.engine_type_id)
        .where(EstimatorDesign.operator_id == operator_id, EstimatorDesign.active.is_(True))
        .subquery()
    )
    fs = FilterState.__table__
    snap = Snapshot.__table__
    after_last = or_(fs.c.last_recorded_at.is_(None), snap.c.recorded_at > fs.c.last_recorded_at)
    first_new = (
        select(func.min(snap.c.recorded_at))
        .where(snap.c.engine_id == Engine.id, after_last)
        .scalar_subquery()
    )
    up_to_last = (
        select(func.count())
        .select_from(snap)
        .where(snap.c.engine_id == Engine.id, snap.c.recorded_at <= fs.c.last_recorded_at)
        .scalar_subquery()
    )
    query = (
        select(Engine.id, active.c.id, fs.c.n_records, first_new, up_to_last)
        .join(active, active.c.engine_type_id == Engine.engine_type_id)
        .outerjoin(fs, and_(fs.c.engine_id == Engine.id, fs.c.design_id == active.c.id))
        .where(Engine.operator_id == operator_id)
    )
    if engine_ids is not None:
        query = query.where(Engine.id.in_(list(engine_ids)))
    out = {}
    for engine_id, d_id, n_records, new, counted in session.execute(query).all():
        if n_records is not None and counted is not None and counted > n_records:
            out[int(engine_id)] = _earliest_unestimated(session, engine_id, d_id)
        elif new is not None:
            out[int(engine_id)] = new
    return out


def _earliest_unestimated(session: Session, engine_id: int, design_id: int) -> datetime:
    """The engine's earliest snapshot without an estimate under the design."""
    estimated = select(Estimate.recorded_at).where(
        Estimate.engine_id == engine_id, Estimate.design_id == design_id
    )
    earliest = session.scalar(
        select(func.min(Snapshot.recorded_at)).where(
            Snapshot.engine_id == engine_id, Snapshot.recorded_at.not_in(estimated)
        )
    )
    assert earliest is not None, "more snapshots than estimates, yet none without one"
    return earliest


def audit(session: Session, operator_id: int) -> dict[int, datetime]:
    """Check the backlog against the stored rows: engines with unestimated snapshots but no
    mark (rows stored by a path that did not mark them) are marked. Returns every engine with
    unestimated snapshots and the earliest of them (the fleet diagnostics' "waiting")."""
    behind = pending_work(session, operator_id)
    marked = backlog.pending(session, operator_id, behind)
    missing = {e: (t, None) for e, t in behind.items() if e not in marked}
    backlog.mark(session, operator_id, missing)
    return behind


def estimate_group(
    session: Session, operator_id: int, engine_ids: Sequence[int], *, wait: bool,
    commit: Callable[[], None], progress: Callable[[float, str], None] | None = None,
    leftover_of: Mapping[int, backlog.Mark] | None = None, drifts: FleetDrifts | None = None,
) -> dict[str, Any]:
    """Estimate the backlog of those of ``engine_ids`` whose locks this process gets
    (``groups.engine_locks``: all, waiting for each, or those free now), committing batch by
    batch; the counts, zero when another process had done them.

    ``leftover_of``: the backlog of a pass (``_spread``): only the engines that still have a
    mark of it (a group no other process started, or what one left undone) are estimated.
    An engine another process estimated in the pass is left with what was marked since (an
    upload stored meanwhile) for the next pass, whose groups spread it over the processes,
    instead of estimating it in this process alone while the others idle.

    ``drifts``: the fleet's wear drifts as the pass found them (``drifts.FleetDrifts``), the
    same for every group of the pass whichever commits first (None: as stored now)."""
    bind = session.get_bind()
    engine = bind if isinstance(bind, SqlEngine) else bind.engine
    with groups.engine_locks(engine, engine_ids, wait=wait) as held:
        work = backlog.pending(session, operator_id, held) if held else {}
        if leftover_of is not None:
            work = {e: m for e, m in work.items()
                    if e in leftover_of and not set(m.ids).isdisjoint(leftover_of[e].ids)}
        if not work:
            commit()  # end the read: no transaction left open while the others write
            return empty_summary()
        return estimate_engines(
            session, operator_id, {e: m.earliest for e, m in work.items()}, progress,
            commit=commit, from_backlog=True,
            new_records={e: m.rows for e, m in work.items()}, drifts=drifts,
        )


def run_group(session: Session, operator_id: int, engine_ids: Sequence[int],
              drifts: FleetDrifts | None = None) -> dict[str, Any]:
    """An engine group in a worker (a pool process, a Celery task), in the worker's own
    session: those of its engines no other process holds; ``drifts``: the pass's (None, a
    message sent without them: as stored now)."""
    return estimate_group(session, operator_id, engine_ids, wait=False, commit=session.commit,
                          drifts=drifts)


def _spread(
    session: Session, operator_id: int, work: Mapping[int, backlog.Mark],
    launcher: groups.Launcher, progress: Callable[[float, str], None] | None,
    commit: Callable[[], None], drifts: FleetDrifts,
) -> dict[str, Any]:
    """One pass over the backlog in engine groups (``groups``): every group but the first goes
    to ``launcher``; this process estimates the first, then whatever group no one started, from
    the last backwards, then waits for the groups still running elsewhere and estimates what
    they left (a worker that died). Only the pass's ``work`` is done here: what is marked
    meanwhile on engines another process estimated is the next pass's (``estimate_group``'s
    ``leftover_of``). Every group learns from the fleet's wear drifts as the pass found them,
    ``drifts``. Returns the counts of what this process estimated."""
    parts = groups.split(work, groups.GROUPS_PER_WORKER * launcher.workers)
    launcher.launch(operator_id, parts[1:], drifts)
    totals = empty_summary()
    order = [(p, False) for p in [parts[0], *reversed(parts[1:])]]
    order += [(p, True) for p in parts[1:]]
    for done, (part, wait) in enumerate(order, start=1):
        result = estimate_group(session, operator_id, part, wait=wait, commit=commit,
                                leftover_of=work, drifts=drifts)
        for key in COUNTS:
            totals[key] += result[key]
        if progress is not None:
            progress(done / len(order), f"{len(parts)} engine groups: {done} of {len(order)} "
                     "steps")
    totals["groups"] = len(parts)
    return totals


def catch_up(
    session: Session,
    operator_id: int,
    progress: Callable[[float, str], None] | None = None,
    commit: Callable[[], None] | None = None,
    max_passes: int = 10,
) -> dict[str, Any]:
    """Estimate every engine of the operator's backlog until none is left (records that
    arrive meanwhile are marked and picked up by the next pass). Idempotent: a second call
    finds nothing.

    A job (``commit`` given) on PostgreSQL with a launcher configured (``groups``) spreads
    each pass over engine groups estimated in parallel (``_spread``); its counts are then those
    of the engines it estimated itself, and ``groups`` the groups of its last pass."""
    totals: dict[str, Any] = {"engines": 0, "records": 0, "events": 0, "reruns": 0, "passes": 0}
    launcher = groups.launcher_for(session) if commit is not None else None
    previous: dict[int, backlog.Mark] | None = None
    for _ in range(max_passes):
        with read_phase(session, commit is not None):
            work = backlog.pending(session, operator_id)
            drifts = FleetDrifts.read(session, operator_id) if work else FleetDrifts()
        if not work or work == previous:
            break  # nothing left, or nothing any process could estimate (no ready design)
        previous = work
        spread = launcher is not None and commit is not None and len(work) > 1
        if spread:
            assert launcher is not None and commit is not None
            result = _spread(session, operator_id, work, launcher, progress, commit, drifts)
            totals["groups"] = result["groups"]
        else:
            result = estimate_engines(
                session, operator_id, {e: m.earliest for e, m in work.items()}, progress,
                commit=commit, from_backlog=True,
                new_records={e: m.rows for e, m in work.items()}, drifts=drifts,
            )
        totals["passes"] += 1
        for key in COUNTS:
            totals[key] += result[key]
        if not spread and result["records"] == 0:
            break  # nothing could be estimated (no ready design): stop rather than spin
    # Marks and rows uploads kept that no pass took, of engines with no work left (without
    # an active design: an activation marks them again; or estimated already). An engine
    # marked since the last pass keeps its rows for the job its upload queued.
    backlog.drop_undesigned(session, operator_id)
    waiting = backlog.pending(session, operator_id)
    fresh_records.discard(session, [
        e for e in session.scalars(select(Engine.id).where(Engine.operator_id == operator_id))
        if e not in waiting
    ])
    return totals
