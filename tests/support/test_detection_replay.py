"""Shift detection and fault isolation on the built-in engine, scored against the simulator.

A seeded simulated fleet (``estimation.engine.fleet``) with abrupt faults of the seed 002
library goes through the pipeline's estimation functions (``tests.support.detection_replay``);
its events are compared with the fault list the simulator made, not with typed-in results.
The faults a detector can be asked to find are chosen by the truth and the physics: the engine
flew with the fault for a few flights, its baseline existed (enough records since its last
start or maintenance) and the fault's sensor signature, through the scheduled gains, has a
noncentrality of at least ``MIN_NONCENTRALITY`` over 20 records (the VBV bias is closed at
take-off and cruise and the VSV bias barely moves a sensor, so those are not among them).

The trims the pipeline uses on the built-in engine are checked against the steady-state solver
point by point, and are independent of which records share a call (re-runs stay bit-identical).
"""

from __future__ import annotations

import numpy as np
import pytest

from app.services.demo import fleet
from app.services.designs.service import design_step
from app.services.snapshots import detector as stored_detector
from app.services.snapshots import run as snapshots_run
from app.services.snapshots.estimator import (
    SnapshotEstimator,
    build_estimator,
    builtin_trim_table,
    exact_nominal_trims,
)
from app.services.snapshots.store import state_document
from estimation.engine.fleet import fleet_snapshots, plan_fleet
from estimation.engine.schedule import EngineSchedule, build_schedule
from estimation.engine.sensors import SENSOR_NAMES
from estimation.engine.steady import steady_state
from estimation.model import LinearModel
from estimation.shift_detector import GAP, N_BASE, PendingAlarm, SensorFit, ShiftState
from tests.support import detection_replay

MIN_FLIGHTS = 3
MIN_NONCENTRALITY = 60.0
TARGET_CORRECT = 0.8  # detected and correctly isolated, of the detectable faults
TARGET_FALSE_ALARMS = 0.5  # per 1000 engine-flights
TARGET_MEDIAN_DELAY = 10  # flights


@pytest.fixture(scope="module")
def schedule() -> EngineSchedule:
    return build_schedule()


@pytest.fixture(scope="module")
def estimator(schedule: EngineSchedule) -> SnapshotEstimator:
    """The demo's active design (all ten health parameters as tuners) on the built-in engine."""
    return fleet.design_estimator(schedule, *fleet.ACTIVE_DESIGN)


def _score(
    est: SnapshotEstimator, size: fleet.DemoSize, seed: int
) -> detection_replay.Score:
    plan_rng, snap_rng = np.random.default_rng(seed).spawn(2)
    plan = plan_fleet(fleet.fleet_config(size), plan_rng)
    snaps = fleet_snapshots(plan, snap_rng)
    engines = detection_replay.engine_runs(plan, snaps, est)
    events = detection_replay.replay(est, engines)
    return detection_replay.score(plan, engines, events, est.layout.faults, est)


def _check_targets(result: detection_replay.Score, min_faults: int) -> None:
    wanted = result.detectable(MIN_FLIGHTS, N_BASE + GAP, MIN_NONCENTRALITY)
    assert len(wanted) >= min_faults, result.report()  # enough faults for the rate to mean much
    correct = [f for f in wanted if f.isolated == f.fault]
    assert len(correct) >= TARGET_CORRECT * len(wanted), result.report()
    assert result.false_alarms_per_1000 <= TARGET_FALSE_ALARMS, result.report()
    delays = [f.delay_flights for f in correct if f.delay_flights is not None]
    assert np.median(delays) <= TARGET_MEDIAN_DELAY, result.report()
    # A wrong name is worse than none: isolations that name a fault name the injected one,
    # unless another fault struck the same engine in the same window.
    wrong = [f for f in wanted if f.isolated not in (f.fault, detection_replay.NONE)]
    assert len(wrong) <= 0.1 * len(wanted), result.report()


def test_the_trim_table_detects_and_isolates_as_the_exact_trims(
    schedule: EngineSchedule,
) -> None:
    """The pipeline's trims (the nominal trim table, not a solve per record) on the fleet of
    the test below: the same targets."""
    table = builtin_trim_table()
    assert table is not None
    est = fleet.design_estimator(schedule, *fleet.ACTIVE_DESIGN, trims=table)
    size = fleet.DemoSize(aircraft=8, flights=400, fault_rate=1.0 / 150.0)
    _check_targets(_score(est, size, seed=11), min_faults=10)


def test_faults_are_detected_and_isolated_on_a_simulated_fleet(
    estimator: SnapshotEstimator,
) -> None:
    size = fleet.DemoSize(aircraft=8, flights=400, fault_rate=1.0 / 150.0)
    _check_targets(_score(estimator, size, seed=11), min_faults=10)


@pytest.mark.slow
def test_faults_are_detected_and_isolated_on_a_large_fleet(
    estimator: SnapshotEstimator,
) -> None:
    size = fleet.DemoSize(aircraft=20, flights=730, fault_rate=1.0 / 500.0)
    _check_targets(_score(estimator, size, seed=7), min_faults=30)


def test_no_alarm_on_a_fleet_without_faults(estimator: SnapshotEstimator) -> None:
    size = fleet.DemoSize(aircraft=6, flights=300, fault_rate=0.0)
    result = _score(estimator, size, seed=5)
    assert result.faults == []
    # Deterioration, washes, shop visits and swaps but no fault: nothing to report.
    assert len(result.false_alarms) <= TARGET_FALSE_ALARMS * result.engine_flights / 1000.0


def test_trims_are_the_steady_state_solution_whatever_the_batch(
    schedule: EngineSchedule,
) -> None:
    rng = np.random.default_rng(3)
    n = 40
    conditions = np.column_stack([
        rng.uniform(0.0, 40000.0, n), rng.uniform(0.2, 0.85, n), rng.uniform(-20.0, 20.0, n),
        rng.uniform(70.0, 100.0, n),
    ])
    conditions[-1] = [50000.0, 0.8, 0.0, 90.0]  # outside the envelope: interpolated
    interpolated = schedule.trims_at(conditions[:, [0, 1, 3, 2]])
    whole = exact_nominal_trims(conditions, interpolated)
    # Each record alone, by the solver directly.
    for i in (0, 7, n - 2):
        one = steady_state(conditions[i, :3], power=conditions[i, 3])
        for k, name in enumerate(SENSOR_NAMES):
            assert whole[name][i] == pytest.approx(one.sensors[k], rel=1e-9)
    # A record's trim does not depend on the records beside it: bit-identical in a subset.
    part = exact_nominal_trims(
        conditions[5:12], {k: v[5:12] for k, v in interpolated.items()}
    )
    for name in SENSOR_NAMES:
        assert np.array_equal(part[name], whole[name][5:12])
        assert whole[name][-1] == interpolated[name][-1]
    # The interpolation error the exact trims remove is of the size of a fault's signature.
    worst = max(
        np.max(np.abs(whole[n][:-1] / interpolated[n][:-1] - 1.0)) for n in SENSOR_NAMES
    )
    assert worst > 1e-3


def test_sensor_noise_is_constant_in_sensor_units(estimator: SnapshotEstimator) -> None:
    conditions = np.array([[0.0, 0.0, 0.0, 100.0], [35000.0, 0.8, 0.0, 80.0]])
    g = estimator.schedule(conditions)
    assert g.noise_std is not None
    absolute = g.noise_std * g.y_trim / 100.0
    np.testing.assert_allclose(absolute[0], absolute[1], rtol=1e-12)
    # Pressures at cruise are a fraction of those at sea level: their noise in percent grows.
    p30 = estimator.layout.sensors.index("P30")
    assert g.noise_std[1, p30] > 2.0 * g.noise_std[0, p30]


def test_split_run_on_the_built_in_engine_equals_one_run(
    estimator: SnapshotEstimator,
) -> None:
    """Exact trims and per-record noise keep a run split over uploads bit-identical to one
    uninterrupted run (records grouped differently into solver batches and chunks)."""
    size = fleet.DemoSize(aircraft=1, flights=200, fault_rate=1.0 / 100.0)
    plan_rng, snap_rng = np.random.default_rng(17).spawn(2)
    plan = plan_fleet(fleet.fleet_config(size), plan_rng)
    engine = detection_replay.engine_runs(plan, fleet_snapshots(plan, snap_rng), estimator)[0]
    run = engine.run
    whole = snapshots_run.run_filters(estimator, [run])[0]
    rows, events, state, seq0 = [], [], run.state, 0
    for k0, k1 in ((0, 137), (137, 138), (138, len(run.epoch))):
        part = snapshots_run.EngineRun(
            run.engine_id, run.operator_id, seq0, state,
            run.epoch[k0:k1], run.phase[k0:k1], run.conditions[k0:k1], run.y[k0:k1],
            run.u[k0:k1], run.maintenance,
        )
        out = snapshots_run.run_filters(estimator, [part])[0]
        rows += out.blobs()
        events += out.events
        state, seq0 = out.state, k1
    assert rows == whole.blobs()
    assert events == whole.events
    assert state_document(state) == state_document(whole.state)


def test_batched_detector_equals_the_per_record_detector(
    estimator: SnapshotEstimator, monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The detector's batched run (baselines, level statistics and WSSR of a run of records
    at once) gives byte for byte the rows, events, checkpoints and end states of
    ``shift_step`` record by record, on a seeded fleet with faults, washes and swaps."""
    size = fleet.DemoSize(aircraft=3, flights=300, fault_rate=1.0 / 60.0)
    plan_rng, snap_rng = np.random.default_rng(23).spawn(2)
    plan = plan_fleet(fleet.fleet_config(size), plan_rng)
    runs = [e.run for e in detection_replay.engine_runs(plan, fleet_snapshots(plan, snap_rng),
                                                        estimator)]
    batched = snapshots_run.run_filters(estimator, runs)
    monkeypatch.setattr(snapshots_run, "_wssr_filled", snapshots_run._wssr_filled_per_record)
    per_record = snapshots_run.run_filters(estimator, runs)
    assert sum(len(o.events) for o in per_record) >= 2  # alarms and isolations were exercised
    assert sum(len(r.maintenance) for r in runs) >= 2  # and resets
    for a, b in zip(batched, per_record, strict=True):
        assert a.blobs() == b.blobs()
        assert a.events == b.events
        assert [(c.seq, c.epoch, state_document(c.state)) for c in a.checkpoints] == [
            (c.seq, c.epoch, state_document(c.state)) for c in b.checkpoints]
        assert state_document(a.state) == state_document(b.state)


def test_an_actuator_bias_in_the_health_vector_is_one_fault_column(
    schedule: EngineSchedule,
) -> None:
    """With the actuator biases among the design's health parameters, an actuator fault's
    signature comes from its health column alone (not that and its input column again)."""
    p = fleet.DESIGN_POINT
    model = schedule.model_at(p["alt"], p["mach"], p["power"])
    sensors = [n for n in model.sensor_names if n != "Wf"]
    spec = fleet.design_spec("svd", 8, sensors,
                                  fleet.HEALTH + fleet.ACTUATOR_BIASES)
    result = design_step(model, spec)
    embedded = LinearModel.from_dict(result["model"])
    est = build_estimator(0, embedded, result)
    assert est.bias_inputs == ()  # every input's bias is a health parameter here
    health = list(embedded.health_names)
    assert est.S_full.shape[0] == len(health)
    faults = list(est.layout.faults)
    for fault, bias in (("Wf", "wf_bias"), ("VSV", "vsv_bias"), ("VBV", "vbv_bias")):
        column = est.S_full[:, faults.index(fault)]
        assert np.flatnonzero(column).tolist() == [health.index(bias)]
    # Without them in the health vector, the same faults act through the input columns.
    plain = fleet.design_spec("svd", 8, sensors)
    result = design_step(model, plain)
    est = build_estimator(0, LinearModel.from_dict(result["model"]), result)
    assert len(est.bias_inputs) == len(embedded.input_names)
    assert est.S_full.shape[0] == len(fleet.HEALTH) + len(est.bias_inputs)


def test_a_detector_state_round_trips_bit_for_bit_and_old_states_still_read() -> None:
    """The history is stored as its float64 bytes (base64); states written before, with the
    history as lists of numbers, read the same."""
    import json

    rng = np.random.default_rng(3)
    history = (rng.normal(size=(45, 6)) * 10.0 ** rng.integers(-300, 300, (45, 6))).tolist()
    history[0][0], history[1][1] = -0.0, 5e-324
    history = tuple(map(tuple, history))
    pending = PendingAlarm(4, 7.5, 21.0, 3, (0.5, -1.0), ((2.0,),),
                           SensorFit((1.0,), (-0.25,), 3.0, 7))
    state = ShiftState(history, 1.25, pending, 6.5, 12, 80)
    stored = json.loads(json.dumps(stored_detector.document(state)))
    back = stored_detector.from_document(stored)
    assert [[x.hex() for x in q] for q in back.history] == [[x.hex() for x in q] for q in history]
    assert (back.S, back.pending, back.s_mean, back.s_count, back.warm) == (
        1.25, pending, 6.5, 12, 80)
    old = dict(stored, history=[list(q) for q in history])
    assert stored_detector.from_document(old).history == history
    assert stored_detector.from_document(stored_detector.document(ShiftState())).history == ()
    # A pending alarm written before its covariance and sensor fit were kept.
    older = dict(stored, pending={"seq": 4, "epoch": 7.5, "statistic": 21.0, "wait": 3,
                                  "baseline": [0.5, -1.0]})
    assert stored_detector.from_document(older).pending == PendingAlarm(
        4, 7.5, 21.0, 3, (0.5, -1.0))
