"""The estimation pipeline through the service: a run split over several uploads equals one
uninterrupted run row for row, a late upload re-runs the engine and ends where an in-order
upload ends, nothing is duplicated, a library fault opens an event isolated to it, and a
maintenance action restarts the baseline."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import numpy as np
import pytest
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from app.models import EngineModel, MaintenanceAction, Snapshot
from app.models.estimates import (
    Estimate,
    EstimateLayout,
    Event,
    FilterState,
    FleetPeriod,
)
from app.services.snapshots import backlog, estimator, run, store
from app.services.snapshots.buckets import second_moments
from app.services.snapshots.drifts import FleetDrifts
from estimation import isolation, wear
from estimation.model import LinearModel
from estimation.tuners import svd_vstar
from tests.app.services.trends.test_trends import Fleet, add_aircraft, add_engine, make_fleet
from tests.estimation.models import reference_model
from tests.support.periods import periods_from_estimates, stored_periods

T0 = datetime(2026, 1, 1, tzinfo=UTC)
N = 900
M_TUNERS = 6


def _model() -> LinearModel:
    return reference_model()


def _fleet_with_design(session: Session) -> Fleet:
    fleet = make_fleet(session, "Pipeline Air")
    model = _model()
    row = session.get(EngineModel, fleet.design.engine_model_id)
    assert row is not None
    row.content = model.to_dict()
    fleet.design.result = {"vstar": svd_vstar(model, M_TUNERS).tolist()}
    session.flush()
    return fleet


def _records(seed: int, fault: str | None = None, at: int = 0, jump: np.ndarray | None = None,
             jump_at: int = 0) -> tuple[list[datetime], np.ndarray]:
    """Times and stored sensor values of N snapshots (two per flight) with slow deterioration,
    optionally a library fault from record ``at`` and a health jump from ``jump_at``."""
    model = _model()
    est = estimator.build_estimator(0, model, {"vstar": svd_vstar(model, M_TUNERS).tolist()})
    G_y, _ = model.steady_state_gains()
    rng = np.random.default_rng(seed)
    h = -np.linspace(0.0, 1.0, N)[:, None] * np.ones(model.n_health)
    if fault is not None:
        library = {f.name: f for f in isolation.default_faults()}
        h[at:] += isolation.signature_matrix([library[fault]], model.health_names)[:, 0]
    if jump is not None:
        h[jump_at:] += jump
    dy = h @ G_y.T + rng.normal(size=(N, model.n_sensors)) * model.sensor_noise_std
    y = est.schedule(np.zeros((N, 4))).y_trim * (1.0 + dy / 100.0)
    times = [T0 + timedelta(hours=12 * (i // 2), minutes=30 * (i % 2)) for i in range(N)]
    return times, y


def _store(session: Session, fleet: Fleet, engine_id: int, aircraft_id: int,
           times: list[datetime], y: np.ndarray, idx: range | list[int]) -> datetime:
    """Snapshots idx of the records, stored and marked in the backlog as an upload would;
    their earliest time."""
    earliest = _store_rows(session, fleet, engine_id, aircraft_id, times, y, idx)
    backlog.mark(session, fleet.operator_id, {engine_id: (earliest, len(idx))})
    return earliest


def _store_rows(session: Session, fleet: Fleet, engine_id: int, aircraft_id: int,
                times: list[datetime], y: np.ndarray, idx: range | list[int]) -> datetime:
    """Snapshots idx of the records, stored without a backlog mark; their earliest time."""
    model = _model()
    columns = [s.name.lower() for s in model.sensors]
    session.add_all(
        Snapshot(
            operator_id=fleet.operator_id, engine_id=engine_id, aircraft_id=aircraft_id,
            position=1, upload_id=fleet.upload.id, recorded_at=times[i],
            phase="takeoff" if i % 2 == 0 else "cruise", alt_ft=0.0, mach=0.0, dtamb_k=0.0,
            power_pct=100.0, **{c: float(v) for c, v in zip(columns, y[i], strict=True)},
        )
        for i in idx
    )
    session.flush()
    return min(times[i] for i in idx)


def _rows(session: Session, engine_id: int) -> list[tuple[int, datetime, bytes]]:
    return [
        (seq, t, bytes(blob))
        for seq, t, blob in session.execute(
            select(Estimate.seq, Estimate.recorded_at, Estimate.packed)
            .where(Estimate.engine_id == engine_id)
            .order_by(Estimate.seq)
        ).all()
    ]


def _events(session: Session, engine_id: int) -> list[tuple]:
    return [
        (e.seq, e.detected_at, e.kind, e.fault, e.magnitude, e.statistic, e.wssr)
        for e in session.scalars(
            select(Event).where(Event.engine_id == engine_id).order_by(Event.seq, Event.kind)
        )
    ]


def _shift_events(session: Session, engine_id: int) -> list[tuple]:
    """The shift detector's events (``_events`` without the wear detector's)."""
    return [e for e in _events(session, engine_id) if e[2] != "wear"]


def test_split_and_late_uploads_equal_one_uninterrupted_run(session: Session) -> None:
    fleet = _fleet_with_design(session)
    aircraft = add_aircraft(session, fleet, "F-PIPE")
    times, y = _records(seed=7, fault="HPC", at=500)
    whole, split, late = (add_engine(session, fleet, esn) for esn in ("W1", "S1", "L1"))

    start = _store(session, fleet, whole.id, aircraft.id, times, y, range(N))
    store.estimate_engines(session, fleet.operator_id, {whole.id: start})

    # The same records in three uploads, the pipeline running after each (a restart each time).
    for part in (range(0, 300), range(300, 301), range(301, N)):
        start = _store(session, fleet, split.id, aircraft.id, times, y, part)
        store.estimate_engines(session, fleet.operator_id, {split.id: start})

    # Out of order: the middle arrives last and re-runs the engine from before it.
    for part in (range(0, 250), range(700, N), range(250, 700)):
        start = _store(session, fleet, late.id, aircraft.id, times, y, part)
        summary = store.estimate_engines(session, fleet.operator_id, {late.id: start})
    assert summary["reruns"] == 1

    reference = _rows(session, whole.id)
    assert len(reference) == N
    assert [r[0] for r in reference] == list(range(N))
    assert _rows(session, split.id) == reference
    assert _rows(session, late.id) == reference
    assert _events(session, split.id) == _events(session, whole.id)
    assert _events(session, late.id) == _events(session, whole.id)
    states = {
        fs.engine_id: (fs.n_records, fs.state)
        for fs in session.scalars(select(FilterState))
        if fs.engine_id in (whole.id, split.id, late.id)
    }
    assert states[split.id] == states[whole.id] == states[late.id]

    # The fleet deterioration's periods: the same whichever way the records came, and those
    # of a full scan of the estimates.
    periods = stored_periods(session, whole.id)
    assert stored_periods(session, split.id) == periods
    assert stored_periods(session, late.id) == periods
    layout = EstimateLayout.from_dict(next(
        fs.layout for fs in session.scalars(select(FilterState)) if fs.engine_id == whole.id))
    expected = periods_from_estimates(session, whole.id, layout)
    assert periods.keys() == expected.keys()
    for key, (n, sums) in expected.items():
        assert periods[key][0] == n
        assert np.allclose(np.frombuffer(periods[key][1], "<f8"), sums, rtol=1e-12, atol=1e-9)
    # The fleet's periods: three engines with the same means, however many rewrites it took.
    fleet_periods = {(p.period, p.start): p for p in session.scalars(
        select(FleetPeriod).where(FleetPeriod.design_id == fleet.design.id))}
    assert fleet_periods.keys() == expected.keys()
    for key, (n, sums) in expected.items():
        row = fleet_periods[key]
        assert row.n_engines == 3
        assert np.allclose(np.frombuffer(row.sums, "<f8"), 3 * sums / n, rtol=1e-9, atol=1e-9)
        moments = second_moments(sums / n, len(layout.health))
        assert np.allclose(np.frombuffer(row.squares, "<f8"), 3 * moments, rtol=1e-9, atol=1e-9)

    # Running again with nothing new changes nothing and duplicates nothing.
    store.estimate_engines(session, fleet.operator_id, {whole.id: times[0]})
    assert _rows(session, whole.id) == reference
    count = session.scalar(
        select(func.count()).select_from(Estimate).where(Estimate.engine_id == whole.id)
    )
    assert count == N


def test_a_late_record_restarts_from_the_checkpoint_before_it(
    session: Session, monkeypatch: pytest.MonkeyPatch
) -> None:
    """With a checkpoint every 256 records, records 600-699 arriving last re-run the engine
    from the checkpoint after record 511, and the rows still equal one uninterrupted run."""
    monkeypatch.setattr(run, "CHECKPOINT_EVERY", 256)
    fleet = _fleet_with_design(session)
    aircraft = add_aircraft(session, fleet, "F-CKP")
    times, y = _records(seed=9, fault="HPC", at=500)
    whole, late = add_engine(session, fleet, "CK0"), add_engine(session, fleet, "CK1")
    start = _store(session, fleet, whole.id, aircraft.id, times, y, range(N))
    store.estimate_engines(session, fleet.operator_id, {whole.id: start})
    for part in (range(0, 600), range(700, N), range(600, 700)):
        start = _store(session, fleet, late.id, aircraft.id, times, y, part)
        summary = store.estimate_engines(session, fleet.operator_id, {late.id: start})
    assert summary["reruns"] == 1 and summary["records"] == N - 512
    assert _rows(session, late.id) == _rows(session, whole.id)
    assert _events(session, late.id) == _events(session, whole.id)


@pytest.mark.parametrize(("every", "late"), [(32, range(40, 46)), (256, range(600, 700))])
def test_wear_detector_rerun_from_a_checkpoint_equals_an_uninterrupted_run(
    session: Session, monkeypatch: pytest.MonkeyPatch, every: int, late: range
) -> None:
    """The wear detector's state goes through the checkpoints: late records inside its
    baseline (records 20-49; restart from the checkpoint after record 31, its baseline half
    collected) or after its alert re-run the engine from a checkpoint, and its wear events and
    final state (stored JSON) equal one uninterrupted run's."""
    monkeypatch.setattr(run, "CHECKPOINT_EVERY", every)
    fleet = _fleet_with_design(session)
    aircraft = add_aircraft(session, fleet, f"F-WR{every}")
    times, y = _records(seed=9, fault="HPC", at=500)
    whole = add_engine(session, fleet, f"WR{every}A")
    split = add_engine(session, fleet, f"WR{every}B")
    start = _store(session, fleet, whole.id, aircraft.id, times, y, range(N))
    store.estimate_engines(session, fleet.operator_id, {whole.id: start})
    first = [i for i in range(N) if i not in late]
    for part in (first, list(late)):
        start = _store(session, fleet, split.id, aircraft.id, times, y, part)
        summary = store.estimate_engines(session, fleet.operator_id, {split.id: start})
    assert summary["reruns"] == 1
    assert summary["records"] == N - every * (late[0] // every)
    wear = [e for e in _events(session, whole.id) if e[2] == "wear"]
    assert wear, "the fixture's deterioration should raise a wear event"
    assert _events(session, split.id) == _events(session, whole.id)

    def state(engine_id: int) -> dict:
        fs = session.scalars(select(FilterState).where(FilterState.engine_id == engine_id)).one()
        return fs.state["wear"]

    assert state(split.id) == state(whole.id)


def test_library_fault_opens_an_event_isolated_to_it(session: Session) -> None:
    fleet = _fleet_with_design(session)
    aircraft = add_aircraft(session, fleet, "F-FLT")
    cases = {"HPC": 11, "LPT": 12, None: 13}
    engines = {}
    affected = {}
    for fault, seed in cases.items():
        engine = add_engine(session, fleet, f"F-{fault}")
        times, y = _records(seed=seed, fault=fault, at=450)
        affected[engine.id] = _store(session, fleet, engine.id, aircraft.id, times, y, range(N))
        engines[fault] = engine
    store.estimate_engines(session, fleet.operator_id, affected)
    for fault, engine in engines.items():
        every = session.scalars(select(Event).where(Event.engine_id == engine.id)).all()
        # The shift detector's events (this fixture's uniform deterioration, 1 % of every
        # health parameter in 500 flights, is wear the wear detector may report).
        events = [e for e in every if e.kind != "wear"]
        if fault is None:
            assert events == []  # slow deterioration alone raises no shift
            continue
        assert len(events) == 1
        event = events[0]
        assert event.kind == "isolated_fault" and event.fault == fault
        assert 450 <= event.seq < 450 + 40  # detected within 20 flights of the onset
        assert event.magnitude is not None and 0.7 < event.magnitude < 1.3
        # The isolated fault has the smallest WSSR of all hypotheses.
        assert min(event.wssr, key=event.wssr.get) == fault


def test_maintenance_action_restarts_the_baseline(session: Session) -> None:
    fleet = _fleet_with_design(session)
    aircraft = add_aircraft(session, fleet, "F-MX")
    model = _model()
    # A shop visit restores 2 % of HPC efficiency and flow at record 600.
    jump = np.zeros(model.n_health)
    jump[model.health_index(["hpc_eff", "hpc_flow"])] = 2.0
    times, y = _records(seed=21, jump=jump, jump_at=600)
    without, with_action = add_engine(session, fleet, "MX0"), add_engine(session, fleet, "MX1")
    scoped = add_engine(session, fleet, "MX2")
    session.add(
        MaintenanceAction(operator_id=fleet.operator_id, engine_id=with_action.id,
                          kind="shop_visit", performed_at=times[599] + timedelta(hours=1))
    )
    # A borescope finding records an inspection: it restarts no baseline.
    session.add(
        MaintenanceAction(operator_id=fleet.operator_id, engine_id=scoped.id,
                          kind="borescope_finding", performed_at=times[599] + timedelta(hours=1),
                          notes="HPC blades inspected")
    )
    affected = {
        e.id: _store(session, fleet, e.id, aircraft.id, times, y, range(N))
        for e in (without, with_action, scoped)
    }
    store.estimate_engines(session, fleet.operator_id, affected)
    # Unannounced, the recovery is a shift; after the recorded shop visit it is the new normal.
    assert [e[0] >= 600 for e in _shift_events(session, without.id)] == [True]
    assert _shift_events(session, with_action.id) == []
    assert _shift_events(session, scoped.id) == _shift_events(session, without.id)


def test_catch_up_estimates_exactly_the_snapshots_without_estimates(session: Session) -> None:
    fleet = _fleet_with_design(session)
    aircraft = add_aircraft(session, fleet, "F-CU")
    times, y = _records(seed=31)
    engine = add_engine(session, fleet, "CU1")
    _store(session, fleet, engine.id, aircraft.id, times, y, range(0, 200))
    assert store.pending_work(session, fleet.operator_id) == {engine.id: times[0]}
    first = store.catch_up(session, fleet.operator_id)
    assert (
        first["records"] == 200 and store.pending_work(session, fleet.operator_id) == {}
    )
    _store(session, fleet, engine.id, aircraft.id, times, y, range(200, 260))
    assert store.pending_work(session, fleet.operator_id) == {engine.id: times[200]}
    second = store.catch_up(session, fleet.operator_id)
    assert second["records"] == 60 and second["reruns"] == 0
    assert store.catch_up(session, fleet.operator_id)["records"] == 0
    assert [r[0] for r in _rows(session, engine.id)] == list(range(260))


def test_fleet_diagnostics_summarises_and_queues_estimation(session: Session) -> None:
    from app.jobs.kinds.estimation import FleetDiagnostics, fleet_diagnostics
    from app.models.jobs import Job

    fleet = _fleet_with_design(session)
    aircraft = add_aircraft(session, fleet, "F-DX")
    times, y = _records(seed=41, fault="HPC", at=450)
    engine = add_engine(session, fleet, "DX1")
    _store(session, fleet, engine.id, aircraft.id, times, y, range(0, 800))
    store.catch_up(session, fleet.operator_id)
    summary = fleet_diagnostics(session, FleetDiagnostics(), lambda *a: None,
                                operator_id=fleet.operator_id)
    events = _events(session, engine.id)
    assert summary["n_engines"] == 1 and summary["n_engines_waiting"] == 0
    assert summary["n_open_events"] == len(events)
    assert len(_shift_events(session, engine.id)) == 1
    assert "estimation_job_id" not in summary
    _store(session, fleet, engine.id, aircraft.id, times, y, range(800, N))
    summary = fleet_diagnostics(session, FleetDiagnostics(), lambda *a: None,
                                operator_id=fleet.operator_id)
    assert summary["engines"][0]["snapshots_waiting"] is True
    job = session.get(Job, summary["estimation_job_id"])
    assert job is not None and job.kind == "estimate_engines" and job.status == "queued"


def test_rerun_keeps_what_people_did_with_an_event(session: Session) -> None:
    from app.models.estimates import EventComment

    fleet = _fleet_with_design(session)
    aircraft = add_aircraft(session, fleet, "F-ACK")
    times, y = _records(seed=7, fault="HPC", at=500)
    reference, engine = add_engine(session, fleet, "ACK0"), add_engine(session, fleet, "ACK1")
    start = _store(session, fleet, reference.id, aircraft.id, times, y, range(N))
    store.estimate_engines(session, fleet.operator_id, {reference.id: start})
    start = _store(session, fleet, engine.id, aircraft.id, times, y,
                   [i for i in range(N) if i != 100])
    store.estimate_engines(session, fleet.operator_id, {engine.id: start})
    event = session.scalars(
        select(Event).where(Event.engine_id == engine.id, Event.kind != "wear")).one()
    event.status = "acknowledged"
    session.add(EventComment(event_id=event.id, author="test", body="borescope booked"))
    session.flush()

    late = _store(session, fleet, engine.id, aircraft.id, times, y, [100])
    assert (
        store.estimate_engines(session, fleet.operator_id, {engine.id: late})["reruns"]
        == 1
    )
    session.expire_all()
    kept = session.scalars(
        select(Event).where(Event.engine_id == engine.id, Event.kind != "wear")).one()
    assert kept.id == event.id and kept.status == "acknowledged"
    assert [c.body for c in kept.comments] == ["borescope booked"]
    assert _events(session, engine.id) == _events(session, reference.id)
    assert _rows(session, engine.id) == _rows(session, reference.id)


def test_fleet_direction_is_learnt_from_the_designs_other_engines_stored_drifts(
    session: Session, monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Engines of one design estimated one job after another: each stores its wear drift;
    once five others have one, the next engine's stretch adopts the fleet direction of their
    stored drifts (its own left out), and keeps it when a late record re-runs it from a
    checkpoint (one every 256 records) while the others' drifts have moved on."""
    monkeypatch.setattr(run, "CHECKPOINT_EVERY", 256)
    fleet = _fleet_with_design(session)
    aircraft = add_aircraft(session, fleet, "F-FLEET")
    det = run.wear_detector(estimator.estimator_for_design(session, fleet.design))
    engines = [add_engine(session, fleet, f"FD{i}") for i in range(7)]
    records = {}

    def wear_state(engine_id: int) -> dict:
        fs = session.scalars(select(FilterState).where(FilterState.engine_id == engine_id)).one()
        return fs.state["wear"]

    for i, engine in enumerate(engines):
        times, y = records[engine.id] = _records(seed=40 + i)
        idx = range(N) if i < 6 else [k for k in range(N) if k != 800]
        start = _store(session, fleet, engine.id, aircraft.id, times, y, idx)
        store.estimate_engines(session, fleet.operator_id, {engine.id: start})
        state = wear_state(engine.id)
        assert state["drift"] is not None and len(state["drift"]) == det.H.shape[1]
        assert (state["direction"] is None) == (i < det.settings.fleet_min)
    others = FleetDrifts.read(session, fleet.operator_id).others(fleet.design.id,
                                                                 [engines[6].id])
    assert len(others) == 6
    assert others == [tuple(wear_state(e.id)["drift"]) for e in engines[:6]]
    learnt = wear.fleet_direction(others, det.settings.fleet_min)
    assert learnt is not None
    assert wear_state(engines[6].id)["direction"] == learnt.tolist()
    assert wear_state(engines[5].id)["direction"] == wear.fleet_direction(
        others[:5]).tolist()
    # A late record re-runs the engine from a checkpoint: its stretch keeps its direction,
    # though the fleet's drifts changed meanwhile (one more engine).
    extra = add_engine(session, fleet, "FD7")
    times, y = _records(seed=47, fault="LPT", at=300)
    start = _store(session, fleet, extra.id, aircraft.id, times, y, range(N))
    store.estimate_engines(session, fleet.operator_id, {extra.id: start})
    moved = wear.fleet_direction(
        FleetDrifts.read(session, fleet.operator_id).others(fleet.design.id, [engines[6].id]))
    assert moved is not None and not np.allclose(moved, learnt)
    times, y = records[engines[6].id]
    start = _store(session, fleet, engines[6].id, aircraft.id, times, y, [800])
    summary = store.estimate_engines(session, fleet.operator_id, {engines[6].id: start})
    assert summary["reruns"] == 1 and summary["records"] == N - 768
    assert wear_state(engines[6].id)["direction"] == learnt.tolist()
