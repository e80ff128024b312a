"""The recovery measured after a wash: the change of the health levels between the records
before it and the settled records after it, bounded by the engine's neighbouring actions;
a borescope finding is recorded but restarts no baseline."""

from __future__ import annotations

from datetime import timedelta

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy.orm import Session

from app.services.fleet import maintenance
from app.services.trends.health import BASELINE_SETTLE_RECORDS
from app.services.trends.recovery import RECOVERY_RECORDS
from tests.app.services.trends.test_trends import (
    LAYOUT,
    T0,
    add_aircraft,
    add_engine,
    add_estimates,
    as_stored,
    make_fleet,
)

API = "/api/v1/maintenance-actions"
N_BEFORE, N_AFTER = 100, 120
STEP = timedelta(hours=6)


def _engine_with_a_step(session: Session, name: str) -> tuple[object, int, np.ndarray, list]:
    """An engine whose hpc_eff sits at -2 % before record N_BEFORE and at -0.5 % from it on
    (with scatter), fan_eff unchanged."""
    fleet = make_fleet(session, name)
    engine = add_engine(session, fleet, "W1")
    rng = np.random.default_rng(7)
    values = rng.normal(scale=0.05, size=(N_BEFORE + N_AFTER, LAYOUT.width))
    h = LAYOUT.slices()["h"]
    values[:, h.start] += np.r_[np.full(N_BEFORE, -2.0), np.full(N_AFTER, -0.5)]
    values[:, h.start + 2] += -1.0
    times = [T0 + i * STEP for i in range(N_BEFORE + N_AFTER)]
    add_estimates(session, fleet, engine, add_aircraft(session, fleet, "W-AAA"), values, times)
    return fleet, engine.id, values, times


def test_wash_recovery_is_the_step_between_the_records_around_it(
    client: TestClient, session: Session
) -> None:
    fleet, engine_id, values, times = _engine_with_a_step(session, "Recovery Air")
    wash_at = times[N_BEFORE] - timedelta(hours=1)
    wash = maintenance.record_action(
        session, operator_id=fleet.operator_id, engine_id=engine_id, kind="water_wash",
        performed_at=wash_at, notes="on-wing wash",
    )
    session.commit()
    h = {"X-API-Key": fleet.key}
    got = client.get(f"{API}/{wash.id}/recovery", headers=h)
    assert got.status_code == 200, got.text
    body = got.json()
    assert body["note"] is None and body["kind"] == "water_wash"
    assert (body["n_before"], body["n_after"]) == (RECOVERY_RECORDS, RECOVERY_RECORDS)
    by_name = {s["name"]: s for s in body["series"]}
    assert set(by_name) == set(LAYOUT.health)  # an imported model: no EGT margin
    hpc = by_name["hpc_eff"]
    col = LAYOUT.slices()["h"].start
    kept = as_stored(values)
    before = kept[N_BEFORE - RECOVERY_RECORDS:N_BEFORE, col]
    after_from = N_BEFORE + BASELINE_SETTLE_RECORDS
    after = kept[after_from:after_from + RECOVERY_RECORDS, col]
    # The trend rounds the stored numbers to 4 decimals.
    assert hpc["before"] == pytest.approx(before.mean(), abs=1e-4)
    assert hpc["after"] == pytest.approx(after.mean(), abs=1e-4)
    assert hpc["change"] == pytest.approx(after.mean() - before.mean(), abs=2e-4)
    assert hpc["change"] == pytest.approx(1.5, abs=0.1)
    se = np.sqrt(before.var(ddof=1) / len(before) + after.var(ddof=1) / len(after))
    assert hpc["standard_error"] == pytest.approx(se, rel=1e-2)
    assert abs(by_name["fan_eff"]["change"]) < 0.1

    # An earlier wash bounds the records before this one.
    maintenance.record_action(
        session, operator_id=fleet.operator_id, engine_id=engine_id, kind="water_wash",
        performed_at=times[N_BEFORE - 5] - timedelta(minutes=1),
    )
    session.commit()
    bounded = client.get(f"{API}/{wash.id}/recovery", headers=h).json()
    assert bounded["n_before"] == 5
    hpc = next(s for s in bounded["series"] if s["name"] == "hpc_eff")
    assert hpc["before"] == pytest.approx(kept[N_BEFORE - 5:N_BEFORE, col].mean(), abs=1e-4)


def test_no_settled_records_yet_is_said_and_another_operator_gets_404(
    client: TestClient, session: Session
) -> None:
    fleet, engine_id, _values, times = _engine_with_a_step(session, "Late Air")
    other = make_fleet(session, "Nosy Air")
    late = maintenance.record_action(
        session, operator_id=fleet.operator_id, engine_id=engine_id, kind="water_wash",
        performed_at=times[-10],
    )
    session.commit()
    body = client.get(f"{API}/{late.id}/recovery", headers={"X-API-Key": fleet.key}).json()
    assert body["series"] == [] and body["n_after"] == 0
    assert body["note"].startswith("not settled yet: 10 records after the action")
    foreign = client.get(f"{API}/{late.id}/recovery", headers={"X-API-Key": other.key})
    assert foreign.status_code == 404


def test_a_borescope_finding_is_recorded_and_restarts_no_baseline(
    client: TestClient, session: Session
) -> None:
    fleet, engine_id, _values, times = _engine_with_a_step(session, "Scope Air")
    session.commit()
    h = {"X-API-Key": fleet.key}
    made = client.post(API, headers=h, json={
        "engine_id": engine_id, "kind": "borescope_finding",
        "performed_at": times[50].isoformat(), "notes": "HPC stage 3 blade tip rub, within limits",
    })
    assert made.status_code == 201, made.text
    assert made.json()["kind"] == "borescope_finding"
    listed = client.get(API, params={"engine_id": engine_id}, headers=h).json()
    assert [m["notes"] for m in listed["items"]] == ["HPC stage 3 blade tip rub, within limits"]
    assert maintenance.baseline_resets(
        session, operator_id=fleet.operator_id, engine_id=engine_id) == []
    bad = client.post(API, headers=h, json={
        "engine_id": engine_id, "kind": "borescope", "performed_at": times[50].isoformat()})
    assert bad.status_code == 422
