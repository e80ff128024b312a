"""Wear as a new user sees it: NASA C-MAPSS FD001 imported with ``import_cmapss`` through the
REST API (which leaves a ready, active design), the estimation job, and the ``wear`` events read
back through the events API; against a naive per-engine signature CUSUM on the same records
(``estimation.wear.signature_cusum``: HPC signature, no alarm before cycle 50) computed here.
And the demo fleet's healthy stretches through the product pipeline: wear events outside the
injected faults per engine-year.

FD001's fault mode is HPC degradation run to failure (shared/data/cmapss/SOURCE.md): every unit
should be alerted before its last cycle and the alert should name HPC, a median lead at least
the naive CUSUM's (the wear detector's fleet CUSUM, its direction learnt from the other units'
drifts, docs/math.md section 13)."""

from __future__ import annotations

import uuid

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy.orm import Session

from app.cli.importers import CMAPSS_START, FD001_TRAIN, import_cmapss
from app.models import EngineType, EstimatorDesign
from app.services.demo import fleet
from app.services.snapshots import detector, estimator, run, store
from app.services.tenancy import service as tenancy
from estimation import wear
from estimation.engine.fleet import fleet_snapshots, plan_fleet
from estimation.engine.schedule import EngineSchedule, build_schedule
from estimation.shift_detector import N_CONFIRM
from estimation.tuners import svd_vstar
from tests.estimation.models import reference_model
from tests.support import detection_replay, fd001_replay
from tests.support.paths import FD001

pytestmark = pytest.mark.long(seconds=35)

# All 100 units (about 8 s an import): the median lead is the issue's figure on the whole
# train set, 121.5 cycles against the naive's 121.5 (the fleet CUSUM's direction learnt from
# the 99 other units). On a subset it need not hold: units 1-10 give 130.5 against the naive
# 132.0 (a direction from 9 others), 1-20 131.0 against 126.5, 1-50 122.0 against 118.5.
UNITS = 100
YEAR_S = 365.25 * 86400.0
# Records of a wear stretch before its CUSUMs arm, and the armed ones a drift averages.
WEAR_ARMED = wear.WearSettings().settle + wear.WearSettings().n_base
DRIFT_TAIL = wear.WearSettings().drift_tail


@pytest.fixture(scope="module")
def default_schedule() -> EngineSchedule:
    """The built-in engine's schedule on its default grid: what a server builds on first use."""
    return build_schedule()


@pytest.fixture
def fd001_product(
    client: TestClient, session: Session, default_schedule: EngineSchedule,
    monkeypatch: pytest.MonkeyPatch,
) -> dict[str, list[int]]:
    """Leads (cycles before failure) of the first wear event of every unit, whether it named
    HPC, and the naive peer's leads on the same records."""
    monkeypatch.setattr(estimator, "builtin_schedule", lambda: default_schedule)
    operator = tenancy.create_operator(session, name=f"FD001 wear {uuid.uuid4().hex[:8]}")
    _row, key = tenancy.issue_api_key(session, operator=operator, role="analyst", name="fd")
    session.commit()
    client.headers["X-API-Key"] = key
    summary = import_cmapss(FD001, client, units=UNITS)
    assert summary.design_created and summary.design_id is not None
    store.catch_up(session, operator.id)  # the estimation job the uploads queued

    page = client.get("/api/v1/events", params={"kind": "wear", "limit": 1000}).json()
    first: dict[str, dict] = {}
    for event in sorted(page["items"], key=lambda e: e["detected_at"]):
        first.setdefault(event["esn"], event)

    # The naive peer on the same records, with the product's own estimator.
    design = session.get(EstimatorDesign, summary.design_id)
    assert design is not None and design.active and design.status == "ready"
    engine_type = session.get(EngineType, design.engine_type_id)
    assert engine_type is not None and engine_type.name == FD001_TRAIN.engine_type
    est = estimator.estimator_for_design(session, design)
    hpc = est.layout.faults.index("HPC")
    ours, naive, named_hpc = [], [], 0
    for engine in fd001_replay.fd001_runs(FD001, est, UNITS):
        last = int(engine.cycle[-1])
        event = first.get(FD001_TRAIN.esn(engine.unit))
        assert event is not None, f"unit {engine.unit}: no wear event"
        cycle = (np.datetime64(event["detected_at"][:19]) - np.datetime64(
            CMAPSS_START.replace(tzinfo=None))).astype("timedelta64[D]").astype(int) + 1
        assert cycle == event["seq"] + 1  # one record a cycle, day c - 1 is cycle c
        assert cycle < last, f"unit {engine.unit}: alerted at cycle {cycle} of {last}"
        ours.append(last - cycle)
        named_hpc += event["fault"] == "HPC"
        dy, var, sig = fd001_replay.sensor_deviations(est, engine.run)
        k = wear.signature_cusum(dy, var, sig[0, :, hpc])
        naive.append(last - int(engine.cycle[k]) if k is not None else 0)
    print(f"\nFD001 first {UNITS} units through the product: wear alerts {len(ours)}/{UNITS}, "
          f"median lead {np.median(ours):.1f} cycles (naive signature CUSUM "
          f"{np.median(naive):.1f}), HPC {100.0 * named_hpc / len(ours):.0f} %")
    return {"ours": ours, "naive": naive, "hpc": [named_hpc]}


@pytest.mark.skipif(not FD001.exists(), reason=f"no C-MAPSS file at {FD001}")
def test_fd001_import_alerts_every_unit_before_failure_and_names_hpc(
    fd001_product: dict[str, list[int]],
) -> None:
    assert len(fd001_product["ours"]) == UNITS
    assert fd001_product["hpc"][0] >= 0.9 * UNITS


@pytest.mark.skipif(not FD001.exists(), reason=f"no C-MAPSS file at {FD001}")
def test_fd001_import_median_lead_at_least_the_naive_signature_cusum(
    fd001_product: dict[str, list[int]],
) -> None:
    assert np.median(fd001_product["ours"]) >= np.median(fd001_product["naive"])


def test_demo_fleet_healthy_stretches_raise_at_most_one_wear_event_per_engine_year(
    default_schedule: EngineSchedule,
) -> None:
    """The demo fleet (seeded, a third of its aircraft) through ``run.run_filters`` as after
    an upload: wear events on records outside the injected faults' windows (from a fault to
    its engine's removal), per engine-year flown healthy."""
    est = fleet.design_estimator(default_schedule, *fleet.ACTIVE_DESIGN)
    size = fleet.DemoSize(aircraft=4)
    plan_rng, snap_rng = np.random.default_rng(fleet.SEED).spawn(2)
    plan = plan_fleet(fleet.fleet_config(size), plan_rng)
    engines = detection_replay.engine_runs(plan, fleet_snapshots(plan, snap_rng), est)
    false, years = 0, 0.0
    for data, out in zip(engines, run.run_filters(est, [e.run for e in engines]), strict=True):
        t = data.run.epoch
        faulty = np.zeros(len(t), bool)
        for f in plan.faults:
            if f.esn == data.esn:
                end = detection_replay._removal_after(plan, f.esn, f.occurred_at)
                faulty |= (t >= f.occurred_at) & (t <= end)
        healthy = t[~faulty]
        gaps = np.diff(healthy)
        years += float(np.sum(gaps[gaps < 30 * 86400.0])) / YEAR_S
        false += sum(1 for ev in out.events
                     if ev.kind == "wear" and not faulty[np.searchsorted(t, ev.epoch)])
        for ev in out.events:
            if ev.kind == "wear" and ev.fault is not None:
                # The event names the hypotheses its attribution chose from (module faults
                # fitted with a positive magnitude): its fault among them, and where the alert
                # is the engine's own (not the fleet's direction) the best fit of them.
                chosen = ev.shift["wear"]["hypotheses"]
                assert ev.fault in chosen and not set(chosen) & {"Wf", "VSV", "VBV"}
                if ev.shift["wear"]["alert"] != "fleet":
                    assert ev.fault == min(chosen, key=lambda f: ev.wssr[f])
    print(f"\ndemo fleet, {len(engines)} engines: {false} false wear events in {years:.1f} "
          f"healthy engine-years")
    assert years > 4.0
    assert false / years <= 1.0


def _steady_fleet(engines: int, records: int, seed: int) -> tuple[
    estimator.SnapshotEstimator, list[run.EngineRun]
]:
    """Healthy engines of the reference model at one condition (sea-level static, the
    schedule's trim), two records a flight, sensor noise only: nothing to detect."""
    model = reference_model()
    est = estimator.build_estimator(0, model, {"vstar": svd_vstar(model, 6).tolist()})
    trim = est.schedule(np.zeros((records, 4))).y_trim
    rng = np.random.default_rng(seed)
    k = np.arange(records)
    epoch = 1.7e9 + 43200.0 * (k // 2) + 1800.0 * (k % 2)
    runs = []
    for e in range(engines):
        dy = rng.normal(size=(records, model.n_sensors)) * model.sensor_noise_std
        runs.append(run.EngineRun(
            engine_id=e, operator_id=0, seq0=0, state=run.PipelineState.initial(est),
            epoch=epoch, phase=["cruise"] * records, conditions=np.zeros((records, 4)),
            y=trim * (1.0 + dy / 100.0), u=np.full((records, len(est.input_columns)), np.nan),
            maintenance=np.zeros(0)))
    return est, runs


def test_healthy_steady_fleet_raises_at_most_one_wear_alert_per_engine_year() -> None:
    """50 healthy engines x 400 records (two a flight, two flights a day: 0.27 engine-years
    each) at one steady condition through ``run.run_filters`` (``wear_steps``) and
    ``wear_scan`` on the same estimates, deviations and times. The issue's criterion: at most
    1 false wear alert per engine-year. The directional bank is designed for it
    (``false_alerts_per_year``) at each engine's record rate, its threshold calibrated to hold
    that rate from a stretch's start, and a crossing is necessary for a directional alert: at
    most 1 - exp(-T / ARL) of the engines over T armed records, plus three binomial standard
    deviations. Calibrated to hold it over a whole engine-year only (h = 3.24 at this record
    rate) the bank alerted 33 of these 50 engines, 2.4 per engine-year. The limit alert needs
    a whole nominal fault's magnitude, nowhere near on noise. Before the bank's threshold was
    designed at all (h = 2, its baseline taken as exact) 34 of these 50 engines were alerted;
    the naive signature CUSUM alarms on 25 (1.8 per engine-year)."""
    engines, records = 50, 400
    est, runs = _steady_fleet(engines, records, seed=2024)
    cfg = wear.WearSettings()
    T = records - (cfg.settle + cfg.n_base)
    rate = wear.record_rate(runs[0].epoch)
    assert rate == pytest.approx(4 * 365.25, rel=0.01)
    years = engines * (runs[0].epoch[-1] - runs[0].epoch[0]) / YEAR_S
    p = 1.0 - np.exp(-T / wear.bank_arl(cfg, rate))
    allowed = engines * p + 3.0 * np.sqrt(engines * p * (1.0 - p))
    outs = run.run_filters(est, runs)
    product = sum(any(ev.kind == "wear" for ev in out.events) for out in outs)
    det = run.wear_detector(est)
    s = est.layout.slices()
    scanned = 0
    for r, out in zip(runs, outs, strict=True):
        dy, var, sig = fd001_replay.sensor_deviations(est, r)
        cycles = np.cumsum(np.r_[True, np.diff(r.epoch) > run.NEW_FLIGHT_S]).astype(float)
        scan = wear.wear_scan(out.packed.astype(np.float64)[:, s["q"]], det.H, det.W, cycles,
                              candidates=det.candidates, dy=dy, var=var, signatures=sig,
                              epoch=r.epoch)
        scanned += bool(scan.alerts)
    print(f"\nhealthy steady fleet: {product} (product) / {scanned} (scan) of {engines} "
          f"engines alerted in {years:.1f} engine-years; design {engines * p:.1f} "
          f"(+3 sd {allowed:.1f})")
    assert product / years <= 1.0 and scanned / years <= 1.0
    assert product <= allowed
    assert scanned <= allowed


def test_wear_states_stored_before_the_record_rate_read_with_the_nominal_threshold() -> None:
    """A wear state round-trips through its stored document; one stored before the record
    rate was measured (no ``t_rows``, ``bank_h``) reads, and its bank then runs at the
    nominal rate's threshold."""
    st = wear.WearState(cycle=12.0, k=3, x_rows=((0.1, 0.2),), z_rows=((1.0,),),
                        t_rows=(1.7e9, 1.7e9 + 1800.0), bank_h=4.25)
    assert detector.wear_from_document(detector.wear_document(st)) == st
    old = detector.wear_document(st)
    del old["t_rows"], old["bank_h"]
    read = detector.wear_from_document(old)
    assert read.t_rows == () and read.bank_h is None
    assert read == wear.replace_state(st, t_rows=(), bank_h=None)


def test_wear_states_with_a_fleet_direction_round_trip_and_older_ones_read_without() -> None:
    """The fleet CUSUM's part of a wear state (its direction, threshold, latch and the
    engine's drift) round-trips through the stored document; a state stored before it reads
    without one (no fleet CUSUM until the engine's next stretch)."""
    st = wear.WearState(cycle=40.0, k=60, x0=(0.1, -0.2), mu=(0.0, 0.5, 0.25),
                        sd=(1.0, 1.5, 0.75), bank_sum=(3, -2, 7), bank_min=(0, -4, 0),
                        bank_h=6.9, direction=(0.0, 0.6, 0.8), fleet_h=2.83,
                        fleet_crossed=True, drift=(0.01, 0.2, -0.05))
    assert detector.wear_from_document(detector.wear_document(st)) == st
    old = detector.wear_document(st)
    for key in ("direction", "fleet_h", "fleet_crossed", "drift"):
        del old[key]
    read = detector.wear_from_document(old)
    assert read == wear.replace_state(st, direction=None, fleet_h=None, fleet_crossed=False,
                                      drift=None)


@pytest.mark.skipif(not FD001.exists(), reason=f"no C-MAPSS file at {FD001}")
def test_a_run_past_the_wear_budget_goes_in_parts_that_learn_from_the_earlier_ones(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """With the wear input bounded to less than an engine (``run.WEAR_BYTES``), a run goes
    engine by engine: the same estimates, events and states as calling ``run_filters`` on
    each engine in turn with the drifts of those before it; an engine adopts a fleet direction
    once ``fleet_min`` engines before it have a drift (one whose latest stretch began at a
    shift event too near its end has none yet)."""
    est = fd001_replay.fd001_estimator(fd001_replay.fd001_schedule())
    engines = fd001_replay.fd001_runs(FD001, est, 8)
    monkeypatch.setattr(run, "WEAR_BYTES", 1)
    parts = run.run_filters(est, [e.run for e in engines])
    monkeypatch.undo()
    drifts: list[tuple[float, ...]] = []
    for e, out in zip(engines, parts, strict=True):
        (alone,) = run.run_filters(est, [e.run], fleet=list(drifts))
        assert np.array_equal(out.packed, alone.packed, equal_nan=True)
        assert out.events == alone.events
        assert out.state.wear == alone.state.wear
        fleet_min = wear.WearSettings().fleet_min
        assert (out.state.wear.direction is None) == (len(drifts) < fleet_min)
        shifts = [ev.seq for ev in out.events if ev.kind != "wear"]
        assert (out.state.wear.drift is None) == (
            bool(shifts) and len(e.run.epoch) - shifts[-1] - N_CONFIRM < WEAR_ARMED + DRIFT_TAIL)
        if out.state.wear.drift is not None:
            drifts.append(out.state.wear.drift)
    assert len(drifts) < len(engines)  # a unit whose shift event restarted its wear stretch


@pytest.mark.parametrize("biases", [False, True])
def test_wear_hypotheses_by_name_are_the_candidates_of_the_fault_matrix(
    default_schedule: EngineSchedule, biases: bool
) -> None:
    """``wear.wear_hypotheses`` (a stored design's library and health names, what an event's
    confidence reads) names the faults ``wear.health_candidates`` marks on the estimator's
    fault matrix: the module faults, and the actuator biases too where the design estimates
    them as health parameters."""
    method, m = ("svd", 8) if biases else fleet.ACTIVE_DESIGN
    est = fleet.design_estimator(default_schedule, method, m, biases=biases)
    names = est.layout.faults
    mask = wear.health_candidates(est.S_full, len(est.layout.health))
    by_name = wear.wear_hypotheses(list(zip(names, est.fault_shifts, strict=True)),
                                   est.layout.health)
    assert by_name == tuple(n for n, c in zip(names, mask, strict=True) if c)
    assert ("Wf" in by_name) is biases and "HPC" in by_name


def test_an_abrupt_fault_raises_one_event_not_a_wear_alert_on_the_same_step(
    default_schedule: EngineSchedule,
) -> None:
    """The demo fleet's first six aircraft through ``run.run_filters``: while the shift
    detector confirms an alarm the wear detector holds its alerts, and each alarm that becomes
    an event restarts the engine's wear stretch, so the wear detector measures from a baseline
    after the step and does not alert on the same step again (before, three of its four faults
    also raised a wear event 6 to 22 records after the alarm, one named Fan for an HPC
    fault)."""
    est = fleet.design_estimator(default_schedule, *fleet.ACTIVE_DESIGN)
    plan_rng, snap_rng = np.random.default_rng(fleet.SEED).spawn(2)
    plan = plan_fleet(fleet.fleet_config(fleet.DemoSize(aircraft=6)), plan_rng)
    engines = detection_replay.engine_runs(plan, fleet_snapshots(plan, snap_rng), est)
    shifts = 0
    for out in run.run_filters(est, [e.run for e in engines]):
        for ev in out.events:
            if ev.kind == "wear":
                continue
            shifts += 1
            # Held until the isolation, then the new stretch's baseline: no wear alert arms
            # before it is complete.
            assert not [w.seq for w in out.events if w.kind == "wear"
                        and ev.seq <= w.seq < ev.seq + N_CONFIRM + WEAR_ARMED]
            assert out.state.wear.k <= len(out.packed) - ev.seq - N_CONFIRM
    assert shifts >= 3
