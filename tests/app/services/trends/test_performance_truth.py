"""The engineering figures the engine page shows, scored against the fleet simulator's truth.

A small seeded demo-like fleet of the built-in engine (two aircraft and spares: deterioration,
washes, actuator biases, faults, shop visits) goes in through the ingest service and the
pipeline, exactly like an upload, under each of ``DESIGNS`` in turn; the engine trend is read
through the API and each record's figure is compared with the truth of its engine and round,
solved by the steady-state solver at the record's own condition:

- thrust deficit [%] and thrust in % of rated;
- stall margins [margin points] and their change from the nominal engine, T40's change, the
  bypass ratio;
- EGT margin [degC] at the reference (take-off, sea level, ISA+15 K);
- the smoothed deltas dEGT [K, corrected], dWf, dN2, dN1 [%];
- the aux group's outputs in percent of the nominal engine's.

Every one of them is shown with a 1-sigma band, calibrated on fleets of other seeds (the aux
outputs' filter sigma, scale and model error, the trims' error, the deltas' model error:
``designs.calibration.figure_errors``), and each band's coverage is checked: never
overconfident (1-sigma >= 0.5, 2-sigma >= 0.85) and, over the figures, not too wide.

The bounds (``BOUNDS``) are what the figures are good for on the page: a thrust deficit to a
tenth of the 5 % amber limit, an EGT margin to a few kelvin of its 25 degC amber limit
(smoothed T48 noise: 6 K a record), deltas within their smoothed sensor noise plus the lag of
the smoothing; the stall margins to about a point (their error is the design's bias: faults
and actuator biases the tuners do not span, which the calibration's correction of the aux
outputs on the health estimates mostly takes off: ``Calibration.aux_level``). Measured (RMS,
active design / subset m = 8, calibrated on eight fleets): thrust deficit 0.23 / 0.26 %, % of
rated 0.53 / 0.55, stall margins fan 0.06 / 0.08, LPC 0.30 / 0.40, HPC 0.59 / 0.76 points,
T40's change 1.7 / 1.7 K, EGT margin 2.2 degC, dEGT 2.2 K, dWf 0.34 %, dN2 0.07 %, dN1 0.06 %
(with three calibration fleets, too few for the aux correction: LPC 0.66 / 0.83, HPC 1.13 /
1.47 points); 1-sigma coverage 0.55-1.00, 2-sigma >= 0.87 but for m = 8's HPC margin
(``DRAWN``). The tuners are scored where the calibration shows them (V* times the calibrated
level); calibrated on these small fleets it shows none, as it shows none of the levels.
Before the bands were calibrated, thrust in % of rated held the truth within its 1-sigma on
0.19 of the records and the stall margins and deltas had no band. With the aux gains at a
fixed fuel flow, as before ``estimation.engine.power_setting``, the thrust deficit
was off by 1.6 % RMS on a young fleet and fails.
"""

from __future__ import annotations

import io
from datetime import UTC, datetime

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
from fastapi.testclient import TestClient
from sqlalchemy.orm import Session

from app.models import EstimatorDesign
from app.services.demo import fleet as demo
from app.services.demo.simulation_files import snapshot_table
from app.services.designs import calibration, engine_models
from app.services.designs import service as designs
from app.services.fleet import performance
from app.services.fleet import service as fleet_service
from app.services.snapshots import estimator
from app.services.snapshots import store as snapshots_store
from app.services.tenancy import service as tenancy
from app.services.uploads import store as uploads_store
from estimation.engine import deltas
from estimation.engine.atmosphere import flight_condition
from estimation.engine.fleet import FleetPlan, Snapshots
from estimation.engine.schedule import EngineSchedule, build_schedule
from estimation.engine.sensors import AUX_NAMES, SENSOR_NAMES
from estimation.engine.steady import steady_state

pytestmark = pytest.mark.long(seconds=35)

SEED = 11
# Small fleets differ: several (six or more also correct the aux outputs).
CALIBRATION_SEEDS = tuple(range(12, 20))
FLIGHTS = 240
REDLINE_C = 1100.0  # the engine type's default EGT redline
SETTLE = 60  # records after an engine's first before its figures are scored (filter start-up)
# RMS error bounds per figure, in the figure's unit.
BOUNDS = {
    "thrust_deficit": 0.6,  # %
    "Fn_rated": 0.8,  # % of rated
    "SM_fan": 0.2,  # margin points
    "SM_LPC": 1.0,
    "SM_HPC": 1.5,
    "egt_margin": 4.0,  # degC
    "dEGT": 3.5,  # K
    "dWf": 0.6,  # %
    "dN2": 0.15,
    "dN1": 0.15,
    "T40_change": 3.5,  # K (the estimated turbine inlet temperature's change from nominal)
    "BPR": 0.05,  # bypass ratio (about 8.5 at take-off)
}
COVERAGE_ONE_SIGMA = (0.5, 0.95)
# The demo's active design, and the browser tests' seed design (subset m = 8), with the
# bounds its fewer tuners allow where they differ (its thrust and HPC margin follow less of
# the health).
DESIGNS = (demo.ACTIVE_DESIGN, ("subset", 8))
LOOSER = {("subset", 8): {"thrust_deficit": 0.8, "SM_LPC": 1.2, "SM_HPC": 2.0}}
COVERAGE_TWO_SIGMA = 0.85
DRAWN_TWO_SIGMA = 0.7
# The figures whose 2-sigma is a draw over this fleet's five engines (held to DRAWN_TWO_SIGMA),
# per design: subset m = 8's calibrated HPC stall margin, 0.6 points RMS here, has one engine off by
# 1.3 points against a 1-sigma of 0.6 (the other four inside 2-sigma on every record): 0.82 of
# the records. On 16 fleets of the demo's size its band holds on 15, 2-sigma >= 0.78
# (bench_uncertainty.py --designs subset:8 --score-aircraft 12).
DRAWN = {("subset", 8): ("SM_HPC", "SM_HPC_change", "aux.SM_HPC")}


@pytest.fixture(scope="module")
def schedule() -> EngineSchedule:
    return build_schedule()


@pytest.fixture(scope="module")
def simulated() -> tuple[FleetPlan, Snapshots]:
    """A demo-like fleet (``calibration.simulate_fleet``: deterioration, washes, faults, shop
    visits) of another seed than the calibration's."""
    return calibration.simulate_fleet(SEED, aircraft=2, flights=FLIGHTS)


def _seed(session: Session, schedule: EngineSchedule, plan: FleetPlan,
          snaps: Snapshots) -> tuple[int, str, dict[str, int], list[int]]:
    """The fleet in the database through the services an upload uses, estimated under the
    first of ``DESIGNS``: (operator id, API key, esn -> engine id, design ids)."""
    op = tenancy.create_operator(session, name="Truth Air")
    _, key = tenancy.issue_api_key(session, operator=op, role="admin", name="admin")
    engine_type = fleet_service.create_engine_type(session, operator_id=op.id, name="built-in")
    p = demo.DESIGN_POINT
    model = schedule.model_at(p["alt"], p["mach"], p["power"])
    row, _ = engine_models.register_builtin_model(
        session, operator_id=op.id, engine_type_id=engine_type.id, name="cruise", model=model)
    sensors = [n for n in model.sensor_names if n != "Wf"]
    design_ids = []
    for method, tuners in DESIGNS:
        design = designs.create_design(session, operator_id=op.id, engine_model_id=row.id,
                                       name=f"{method} {tuners}",
                                       spec=demo.design_spec(method, tuners, sensors))
        designs.run_design(session, design, designs.design_step)
        design_ids.append(design.id)
        # The design's model error calibrated on other simulated fleets (as the demo's
        # first start calibrates its active design, on fewer and smaller fleets here).
        calib = calibration.calibrate(
            estimator.estimator_for_design(session, design),
            [calibration.simulate_fleet(seed, aircraft=2, flights=FLIGHTS)
             for seed in CALIBRATION_SEEDS])
        calibration.store_calibration(session, design, calib)
    designs.activate_design(session, operator_id=op.id, design_id=design_ids[0])
    tails = {t: fleet_service.create_aircraft(session, operator_id=op.id, tail=t).id
             for t in plan.tails}
    ids = {esn: fleet_service.create_engine(session, operator_id=op.id, esn=esn,
                                            engine_type_id=engine_type.id).id
           for esn in plan.esns}
    for inst in plan.installations:
        fleet_service.install(
            session, operator_id=op.id, engine_id=ids[inst.esn], aircraft_id=tails[inst.tail],
            position=inst.position, installed_at=datetime.fromtimestamp(inst.installed_at, UTC),
            removed_at=None if inst.removed_at is None
            else datetime.fromtimestamp(inst.removed_at, UTC))
    table = snapshot_table(snaps)
    table = table.filter(pc.is_in(table["phase"], value_set=pa.array(["takeoff", "cruise"])))
    sink = io.BytesIO()
    pq.write_table(table, sink)
    uploads_store.ingest_snapshots(session, operator_id=op.id, api_key_id=None,
                                   body=sink.getvalue(), content_format="parquet")
    snapshots_store.catch_up(session, op.id)
    return op.id, key, ids, design_ids


def _truth(schedule: EngineSchedule, plan: FleetPlan, snaps: Snapshots, esn: str,
           times: np.ndarray, est: estimator.SnapshotEstimator) -> dict[str, np.ndarray]:
    """The true figures of engine ``esn`` at its records recorded at ``times`` [s]."""
    keep = np.flatnonzero((snaps.esn == esn)
                          & np.isin(snaps.phase.astype(str), ["takeoff", "cruise"]))
    at = np.round(snaps.recorded_at[keep])
    rows = keep[np.searchsorted(at, times)] if np.all(np.diff(at) > 0) else None
    assert rows is not None and np.all(np.round(snaps.recorded_at[rows]) == times)
    rounds = np.array([int(f.rsplit("-", 1)[1]) - 1 for f in snaps.flight_id[rows]])
    health = plan.health[rounds, plan.esns.index(esn)]
    env = np.stack([snaps.alt_ft[rows], snaps.mach[rows], snaps.dtamb_k[rows]], axis=1)
    power = snaps.power_pct[rows]
    true = steady_state(env, power=power, health=health)
    nominal = steady_state(env, power=power)
    theta = flight_condition(env[:, 0], env[:, 1], env[:, 2]).theta
    ref_alt, ref_mach, ref_power, ref_dt = deltas.EGT_REFERENCE_CONDITION
    ref_env = np.tile([ref_alt, ref_mach, ref_dt], (len(rows), 1))
    at_ref = steady_state(ref_env, power=np.full(len(rows), ref_power), health=health)
    fn = AUX_NAMES.index("Fn")
    rated = performance.type_reference(schedule).rated_thrust_lbf
    out = {
        "thrust_deficit": -100.0 * (true.aux[:, fn] / nominal.aux[:, fn] - 1.0),
        "Fn_rated": 100.0 * true.aux[:, fn] / rated,
        "egt_margin": REDLINE_C - (at_ref.sensors[:, SENSOR_NAMES.index("T48")] / 1.8 - 273.15),
        "dEGT": (true.sensors[:, 7] - nominal.sensors[:, 7]) / theta / 1.8,
    }
    for name in ("SM_fan", "SM_LPC", "SM_HPC", "BPR"):
        out[name] = true.aux[:, AUX_NAMES.index(name)]
    for name in ("SM_fan", "SM_LPC", "SM_HPC"):
        k = AUX_NAMES.index(name)
        out[f"{name}_change"] = true.aux[:, k] - nominal.aux[:, k]
    t40 = AUX_NAMES.index("T40")
    out["T40_change"] = (true.aux[:, t40] - nominal.aux[:, t40]) / 1.8
    for name, sensor in (("dWf", "Wf"), ("dN2", "Nc"), ("dN1", "Nf")):
        k = SENSOR_NAMES.index(sensor)
        out[name] = 100.0 * (true.sensors[:, k] / nominal.sensors[:, k] - 1.0)
    for k, name in enumerate(AUX_NAMES):  # the aux group: percent of the nominal engine's
        out[f"aux.{name}"] = 100.0 * (true.aux[:, k] / nominal.aux[:, k] - 1.0)
    # The tuners: V* h of the true health (in the design's order of health parameters).
    columns = [list(plan.health_names).index(n) for n in est.layout.health]
    tuners = health[:, columns] @ est.vstar.T
    for k, name in enumerate(est.layout.tuners):
        out[f"tuner.{name}"] = tuners[:, k]
    return out


def _score(client: TestClient, key: str, ids: dict[str, int], design_id: int,
           bounds: dict[str, float], schedule: EngineSchedule, plan: FleetPlan,
           snaps: Snapshots, est: estimator.SnapshotEstimator,
           drawn_here: tuple[str, ...] = ()) -> None:
    """Every engine's trend under ``design_id`` (``est``) through the API against the
    truth (``drawn_here``: figures held to ``DRAWN_TWO_SIGMA``, ``DRAWN``)."""
    errors: dict[str, list[np.ndarray]] = {name: [] for name in BOUNDS}
    scaled: dict[str, list[np.ndarray]] = {}  # each banded figure's error over its 1-sigma
    engines = 0
    for esn, engine_id in ids.items():
        trend = client.get(f"/api/v1/engines/{engine_id}/trend",
                           params={"max_points": 0, "design_id": design_id},
                           headers={"X-API-Key": key}).json()
        if not trend["n_records"]:
            continue  # a spare that never flew
        engines += 1
        times = np.array([datetime.fromisoformat(t.replace("Z", "+00:00")).timestamp()
                          for t in trend["time"]])
        group = next(g for g in trend["groups"] if g["key"] == "performance")
        # Calibrated on eight fleets: the stall margins are shown corrected, and say so.
        assert {"SM_LPC", "SM_HPC", "SM_LPC_change"} <= set(group["calibrated_series"]), (
            group["calibrated_series"])
        shown = {s["name"]: s for s in group["series"]}
        truth = _truth(schedule, plan, snaps, esn, np.round(times), est)
        settled = slice(SETTLE, None)
        for name in BOUNDS:
            value = np.array(shown[name]["value"], dtype=float)
            errors[name].append((value - truth[name])[settled])
        deficit = shown["thrust_deficit"]
        # The tuners shown are V* times the calibrated level; the unobservable ones are
        # named and null (on these small calibration fleets, every one: as the health
        # group's levels, none holds the band on each fleet alone).
        tuner_group = next(g for g in trend["groups"] if g["key"] == "tuners")
        hidden = set(tuner_group["unobservable"])
        assert set(tuner_group["calibrated_series"]) == {
            s["name"] for s in tuner_group["series"]} - hidden, tuner_group["calibrated_series"]
        assert all(v is None for s in tuner_group["series"] if s["name"] in hidden
                   for v in s["value"])
        aux = {f"{g['key'].rstrip('s')}.{s['name']}": s for g in trend["groups"]
               if g["key"] in ("aux", "tuners") for s in g["series"]
               if not (g["key"] == "tuners" and s["name"] in hidden)}
        for name, series in {**shown, **aux}.items():
            if name not in truth:
                continue
            assert series["sigma"] is not None, f"{name} is shown without a 1-sigma"
            err = np.array(series["value"], float) - truth[name]
            scaled.setdefault(name, []).append((err / np.array(series["sigma"], float))[settled])
        # Thrust in lbf is the same estimate: its band holds the deficit's in lbf, and the
        # schedule's thrust trim's error besides.
        fn_sigma = np.array(shown["Fn"]["sigma"], float)
        assert np.all(
            fn_sigma / np.array(shown["Fn"]["value"], float)
            >= (1.0 - 1e-3) * np.array(deficit["sigma"], float)
            / (100.0 - np.array(deficit["value"], float)))
    assert engines >= 4
    rms = {name: float(np.sqrt(np.mean(np.concatenate(e) ** 2))) for name, e in errors.items()}
    cover = {}
    for name, z in scaled.items():
        z = np.abs(np.concatenate(z))
        cover[name] = (float(np.mean(z <= 1.0)), float(np.mean(z <= 2.0)))
    report = (", ".join(f"{n} {rms[n]:.2f} (bound {bounds[n]})" for n in bounds)
              + "; 1-sigma / 2-sigma coverage: "
              + ", ".join(f"{n} {a:.2f}/{b:.2f}" for n, (a, b) in cover.items()))
    print(f"\ndesign {design_id}: {report}")
    for name, bound in bounds.items():
        assert rms[name] <= bound, report
    assert set(BOUNDS) <= set(cover), report
    for name, (one, two) in cover.items():
        assert one >= COVERAGE_ONE_SIGMA[0], f"{name}: {report}"
        assert two >= (DRAWN_TWO_SIGMA if name in drawn_here else COVERAGE_TWO_SIGMA), (
            f"{name}: {report}")
    # Calibrated on three fleets of five engines, scored on a fifth: a band may be wide for
    # this one fleet (the stall margins' and bypass ratio's errors differ twofold between such
    # fleets), not for most figures. bench/bench_uncertainty.py scores the demo's calibration
    # on fleets of the demo's size against the issue's 55-85 %.
    assert float(np.median([one for one, _two in cover.values()])) <= COVERAGE_ONE_SIGMA[1], report


def test_engineering_figures_follow_the_simulators_truth(
    session: Session, client: TestClient, schedule: EngineSchedule,
    simulated: tuple[FleetPlan, Snapshots], monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(estimator, "builtin_schedule", lambda: schedule)
    plan, snaps = simulated
    operator_id, key, ids, design_ids = _seed(session, schedule, plan, snaps)
    for k, (design, design_id) in enumerate(zip(DESIGNS, design_ids, strict=True)):
        if k:  # the next design estimated as after its activation
            designs.activate_design(session, operator_id=operator_id, design_id=design_id)
            snapshots_store.catch_up(session, operator_id)
        est = estimator.estimator_for_design(session, session.get(EstimatorDesign, design_id))
        _score(client, key, ids, design_id, {**BOUNDS, **LOOSER.get(design, {})}, schedule,
               plan, snaps, est, DRAWN.get(design, ()))
