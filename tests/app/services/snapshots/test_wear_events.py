"""Wear as a new user sees it: NASA C-MAPSS FD001 imported with ``import_cmapss`` through the
REST API (which leaves a ready, active design), the estimation job, and the ``wear`` events read
back through the events API; against a naive per-engine signature CUSUM on the same records
(``estimation.wear.signature_cusum``: HPC signature, no alarm before cycle 50) computed here.
And the demo fleet's healthy stretches through the product pipeline: wear events outside the
injected faults per engine-year.

FD001's fault mode is HPC degradation run to failure (shared/data/cmapss/SOURCE.md): every unit
should be alerted before its last cycle and the alert should name HPC."""

from __future__ import annotations

import uuid

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy.orm import Session

from app.cli.importers import CMAPSS_START, ENGINE_TYPE, esn_of, import_cmapss
from app.models import EngineType, EstimatorDesign
from app.services.demo import fleet
from app.services.snapshots import estimator, run, store
from app.services.tenancy import service as tenancy
from estimation import wear
from estimation.engine.fleet import fleet_snapshots, plan_fleet
from estimation.engine.schedule import EngineSchedule, build_schedule
from tests.support import detection_replay, fd001_replay
from tests.support.paths import FD001

# All 100 units (~40 s a database): the median lead is the issue's figure on the whole train
# set. On a subset it need not hold: units 1-10 give 92.5 cycles against the naive 132.
UNITS = 100
YEAR_S = 365.25 * 86400.0


@pytest.fixture(scope="module")
def default_schedule() -> EngineSchedule:
    """The built-in engine's schedule on its default grid: what a server builds on first use."""
    return build_schedule()


@pytest.mark.skipif(not FD001.exists(), reason=f"no C-MAPSS file at {FD001}")
def test_fd001_import_alerts_every_unit_before_failure_and_names_hpc(
    client: TestClient, session: Session, default_schedule: EngineSchedule,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
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
    assert engine_type is not None and engine_type.name == ENGINE_TYPE
    est = estimator.estimator_for_design(session, design)
    hpc = est.layout.faults.index("HPC")
    ours, naive, named_hpc = [], [], 0
    for engine in fd001_replay.fd001_runs(FD001, est, UNITS):
        last = int(engine.cycle[-1])
        event = first.get(esn_of(engine.unit))
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
    assert len(ours) == UNITS
    assert named_hpc >= 0.9 * UNITS
    assert np.median(ours) >= np.median(naive)


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
    print(f"\ndemo fleet, {len(engines)} engines: {false} false wear events in {years:.1f} "
          f"healthy engine-years")
    assert years > 4.0
    assert false / years <= 1.0
