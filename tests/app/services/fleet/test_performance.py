"""Engineering units against hand computations from the schedule's trims, and the trend's
performance group for a design of the built-in engine."""

from __future__ import annotations

from datetime import timedelta

import numpy as np
import pytest
from sqlalchemy import select
from sqlalchemy.orm import Session

from app.models import EngineModel, Snapshot
from app.schemas.estimates import EngineTrend
from app.services.fleet import performance
from app.services.snapshots import estimator
from app.services.trends import service as trends
from estimation.engine import deltas
from estimation.engine.atmosphere import flight_condition
from estimation.engine.schedule import EngineSchedule, build_schedule
from tests.app.services.trends.test_trends import (
    LAYOUT,
    T0,
    add_aircraft,
    add_engine,
    add_estimates,
    make_fleet,
)

# Aux names of the built-in engine in the order the pipeline stores them.
AUX = ("Fn", "T40", "SM_fan", "SM_LPC", "SM_HPC", "BPR")


@pytest.fixture(scope="module")
def schedule() -> EngineSchedule:
    return build_schedule({"alt": (0.0, 40000.0), "mach": (0.0, 0.85), "power": (40.0, 100.0)})


def _layout():  # type: ignore[no-untyped-def]
    from app.models.estimates import EstimateLayout

    return EstimateLayout(tuners=("q1",), health=("hpc_eff",), aux=AUX, sensors=("T48",),
                          faults=("HPC",))


def test_units_equal_hand_computation_from_the_trims(schedule: EngineSchedule) -> None:
    # Two records: cruise and take-off (snapshot order alt, mach, dtamb, power).
    cond = np.array([[35000.0, 0.8, 0.0, 80.0], [0.0, 0.2, 10.0, 100.0]])
    trims = schedule.trims_at(cond[:, [0, 1, 3, 2]])
    z = np.zeros((2, len(AUX)))
    z[:, 0] = [-3.0, -17.6]  # thrust 3 % and 17.6 % below the baseline
    z[:, 4] = [-40.0, -10.0]  # HPC stall margin
    z[:, 1] = [1.0, 2.5]  # T40 1 % and 2.5 % above the nominal engine's
    z[:, 5] = [-2.0, 4.0]  # bypass ratio
    base = {"T48": trims["T48"], "Wf": trims["Wf"], "Nc": trims["Nc"], "Nf": trims["Nf"]}
    # Measured: EGT 18 degR above the baseline, Wf +2 %, N2 -1 %, N1 as the baseline.
    measured = {"T48": trims["T48"] + 18.0, "Wf": trims["Wf"] * 1.02, "Nc": trims["Nc"] * 0.99,
                "Nf": trims["Nf"]}
    series = performance.engineering_units(
        schedule, _layout(), z, performance.RecordConditions(cond, measured), 950.0, base
    )
    got = {name: (unit, values) for name, unit, values in series}

    rated = float(schedule.trims_at(np.array([[0.0, 0.0, 100.0, 0.0]]))["Fn"][0])
    fn = trims["Fn"] * np.array([0.97, 0.824])
    np.testing.assert_allclose(got["Fn"][1], fn, rtol=1e-12)
    assert got["Fn"][0] == "lbf" and got["Fn_rated"][0] == "% of rated"
    np.testing.assert_allclose(got["Fn_rated"][1], 100 * fn / rated, rtol=1e-12)
    np.testing.assert_allclose(got["thrust_deficit"][1], [3.0, 17.6])
    # SM_HPC: 40 % of a 24-point margin is 9.6 points.
    np.testing.assert_allclose(got["SM_HPC"][1], trims["SM_HPC"] * np.array([0.6, 0.9]))
    np.testing.assert_allclose(got["SM_HPC_change"][1], -trims["SM_HPC"] * np.array([0.4, 0.1]))
    assert got["SM_HPC"][0] == "pts"
    np.testing.assert_allclose(got["SM_fan_change"][1], 0.0)
    # T40: its change from the nominal engine in K (the trims are degR).
    np.testing.assert_allclose(got["T40_change"][1],
                               trims["T40"] * np.array([0.01, 0.025]) / 1.8, rtol=1e-12)
    assert got["T40_change"][0] == "degC" and got["BPR"][0] == "1"
    np.testing.assert_allclose(got["BPR"][1], trims["BPR"] * np.array([0.98, 1.04]), rtol=1e-12)

    theta = flight_condition(cond[:, 0], cond[:, 1], cond[:, 2]).theta
    d_egt = 18.0 / 1.8 / theta  # K, corrected
    # Smoothing: the first record starts the filter, the second moves a tenth of the way.
    expected = np.array([d_egt[0], d_egt[0] + 0.1 * (d_egt[1] - d_egt[0])])
    np.testing.assert_allclose(got["dEGT"][1], expected)
    np.testing.assert_allclose(got["dWf"][1], 2.0, rtol=1e-9)
    np.testing.assert_allclose(got["dN2"][1], -1.0, rtol=1e-9)
    np.testing.assert_allclose(got["dN1"][1], 0.0, atol=1e-9)
    ref = schedule.trims_at(np.array([[0.0, 0.0, 100.0, 15.0]]))["T48"][0] / 1.8 - 273.15
    theta_ref = (288.15 + 15.0) / 288.15
    np.testing.assert_allclose(got["egt_margin"][1], 950.0 - ref - expected * theta_ref,
                               rtol=1e-9)


def test_smoothing_skips_missing_values() -> None:
    x = np.array([[np.nan], [1.0], [np.nan], [3.0]])
    np.testing.assert_allclose(deltas.smooth(x, 0.5)[:, 0], [np.nan, 1.0, 1.0, 2.0])


def test_trend_of_a_builtin_design_carries_the_performance_group(
    session: Session, schedule: EngineSchedule, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(estimator, "builtin_schedule", lambda: schedule)
    fleet = make_fleet(session, "Units Air")
    model = session.get(EngineModel, fleet.design.engine_model_id)
    assert model is not None
    model.source = "builtin"
    engine, aircraft = add_engine(session, fleet, "U1"), add_aircraft(session, fleet, "F-UNIT")
    n = 6
    values = np.zeros((n, LAYOUT.width))
    values[:, LAYOUT.slices()["z"].start] = -5.0  # LAYOUT.aux[0] is Fn
    add_estimates(session, fleet, engine, aircraft, values,
                  [T0 + timedelta(hours=6 * i) for i in range(n)])
    trim = schedule.trims_at(np.array([[0.0, 0.0, 100.0, 0.0]]))
    for snap in session.scalars(select(Snapshot).where(Snapshot.engine_id == engine.id)):
        snap.t48 = float(trim["T48"][0]) + 9.0  # 5 K above the baseline at sea-level static
    session.flush()

    trend = trends.engine_trend(session, fleet.operator_id, engine.id, max_points=0)
    group = next(g for g in trend["groups"] if g["key"] == "performance")
    series = {s["name"]: s for s in group["series"]}
    # Sea-level static take-off is the rated condition: 5 % deficit is 95 % of rated.
    np.testing.assert_allclose(series["Fn_rated"]["value"], 95.0, atol=1e-3)
    np.testing.assert_allclose(series["Fn"]["value"], 0.95 * trim["Fn"][0], rtol=1e-5)
    assert series["Fn"]["unit"] == "lbf" and series["egt_margin"]["unit"] == "degC"
    # The exact nominal solve and the coarse schedule agree at a grid node within 0.5 K.
    np.testing.assert_allclose(series["dEGT"]["value"], 5.0, atol=0.5)
    levels = {(line["series"], line["level"]): line["value"] for line in group["limits"]}
    assert levels[("egt_margin", "amber")] == 25.0 and levels[("thrust_deficit", "red")] == 10.0
    EngineTrend.model_validate(trend)  # the documented response shape
    header = trends.engine_trend_csv(trend).splitlines()[0].split(",")
    assert "performance.egt_margin[degC]" in header and "performance.Fn[lbf]" in header
    # The decimated trend keeps the group, bucketed.
    small = trends.engine_trend(session, fleet.operator_id, engine.id, max_points=2)
    assert any(g["key"] == "performance" for g in small["groups"])


def test_baseline_trims_are_the_estimations_trims(schedule: EngineSchedule) -> None:
    """The engine page's baselines (EGT margin, the deltas) come from the nominal engine's
    trim table, as the estimation's trims do, within 0.1 percent of the steady-state solve;
    a condition outside the envelope keeps the schedule's interpolation."""
    cond = np.array([[35000.0, 0.8, 0.0, 80.0], [0.0, 0.2, 10.0, 100.0],
                     [80000.0, 0.8, 0.0, 80.0]])
    interpolated = {k: v for k, v in schedule.trims_at(cond[:, [0, 1, 3, 2]]).items()
                    if k in estimator.MEASURED_COLUMNS}
    got = estimator.baseline_trims(cond, schedule)
    table = estimator.builtin_trim_table()
    assert table is not None
    solved = estimator.exact_nominal_trims(cond, interpolated)
    for name in estimator.MEASURED_COLUMNS:
        k = table.names.index(name)
        np.testing.assert_array_equal(got[name][:2], table.trims_at(cond[:2])[:, k])
        np.testing.assert_allclose(got[name][:2], solved[name][:2], rtol=1e-3)
        assert got[name][2] == interpolated[name][2]
